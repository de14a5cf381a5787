"""The estimate of a resumed run at the machine's measured rates (:mod:`nue.reproduce_calibrate`): factors computed
by hand from made-up stage markers, selection and evaluation records."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from nue.recipe import CostModel, estimate
from nue.recipes import get_recipe
from nue.reproduce import RunFolders, remaining_estimate
from nue.reproduce_calibrate import Calibration, calibration
from nue.reproduce_marker import StageMarker, TrainRunSummary

V12 = get_recipe("v12")
C = CostModel()
NUE_TRAIN_S = 4000 * 64 / (98.0 * 1.37)  # v12's 256,000 samples at the eager lean-memory NUE rate
NUE_STEP_S = 13.3 / 1.70 / 350  # the NUE family's modelled seconds an episode step (lean memory)
FR_STEP_S = 3.4 / 350


def _trained(folders: RunFolders, name: str, model: str, train_seconds: float | None, steps: int = 4000) -> None:
    folders.marker(f"train/{name}").parent.mkdir(parents=True, exist_ok=True)
    summary = TrainRunSummary(best=f"runs/{name}/best.pt", seconds=1.0, steps=steps, train_seconds=train_seconds,
                              model=model, seed=0)
    folders.marker(f"train/{name}").write_text(json.dumps(StageMarker(f"train/{name}", 1.0, "2026-12-07 00:00 UTC",
                                                                      summary).to_dict()))


def _records(path: Path, rows: list[tuple[str, int, float]], torn: bool = False) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    text = "".join(json.dumps({"method": m, "steps": n, "wall_time": w, "success": True}) + "\n" for m, n, w in rows)
    path.write_text(text + ('{"method": "nue", "ste' if torn else ""))


def test_nothing_measured_changes_nothing(tmp_path):
    folders = RunFolders(tmp_path, Path(), Path())
    empty = calibration(V12, folders)
    assert empty == Calibration() and empty.cost_model() == C and empty.describe() == ""
    _trained(folders, "nue", "nue_gru_lean", None)  # a marker written before the trainer's time was recorded
    assert calibration(V12, folders) == Calibration()
    assert calibration(V12.replace(train_minutes=30.0), folders).train == ()  # a time budget fixes training time


def test_factors_are_medians_over_runs_and_unmeasured_entries_take_the_pooled_one(tmp_path):
    """nue: runs at 2x and 4x the modelled training time (median 3x); fr at 0.5x; Nav-A3C, not measured, takes the
    median of all three runs (2x). Steps: nue's selection at 1.5x (a torn last line skipped), fr's evaluation records
    at 0.8x; the experts' episodes take the pooled median (of 1.5 and 0.8: 1.15)."""
    folders = RunFolders(tmp_path, Path(), Path())
    _trained(folders, "nue", "nue_gru_lean", 2 * NUE_TRAIN_S)
    _trained(folders, "nue@s1", "nue_gru_lean", 4 * NUE_TRAIN_S)
    _trained(folders, "fr", "fr", 0.5 * 4000 * 64 / 200.0)
    _records(folders.run("nue") / "selection.jsonl", [("nue", 100, 1.5 * 100 * NUE_STEP_S),
                                                      ("nue", 300, 1.5 * 300 * NUE_STEP_S)], torn=True)
    _records(folders.records("eval/val252"), [("fr", 200, 0.8 * 200 * FR_STEP_S), ("expert", 50, 99.0),
                                              ("fr", 600, 0.8 * 600 * FR_STEP_S)])
    cal = calibration(V12, folders)
    assert [(f.key, pytest.approx(f.ratio)) for f in cal.train] == [("fr", 0.5), ("nue", 3.0)]
    assert [(f.key, pytest.approx(f.ratio), f.episodes) for f in cal.steps] == [("fr", 0.8, 2), ("nue", 1.5, 2)]
    cost = cal.cost_model()
    rates = dict(cost.samples_per_s)
    assert rates["nue"] == pytest.approx(98.0 / 3) and rates["fr"] == pytest.approx(400.0)
    assert rates["nav_a3c"] == pytest.approx(232.0 / 2)
    eval_s = dict(cost.eval_s_per_episode)
    assert eval_s["nue"] == pytest.approx(13.3 * 1.5) and eval_s["expert"] == pytest.approx(0.2 * 1.15)
    assert dict(cost.select_s_per_episode)["fr"] == pytest.approx(1.7 * 0.8)
    line = cal.describe()
    assert "training time fr x0.50 (1 run), nue x3.00 (2 runs)" in line
    assert "episode steps fr x0.80 (1 run, 2 episodes), nue x1.50 (1 run, 2 episodes)" in line

    # The remaining estimate at those rates: the training stage's next NUE-family run (e.g. nue@s2 alone on one
    # worker) costs 3x the modelled training plus its selection (2 x 21 episodes) at 1.5x.
    one = estimate(V12, 1, cost=cost, runs=["nue@s2"])[3]
    assert one.stage == "train"
    assert one.seconds == pytest.approx(C.train_overhead_s + 3 * NUE_TRAIN_S + 42 * 11.5 / 1.70 * 1.5)
    left = {s.stage: s for s in remaining_estimate(V12, folders, 2, cost=cost)}
    plain = {s.stage: s for s in remaining_estimate(V12, folders, 2)}
    assert left["eval/val252+swap"].seconds == pytest.approx(
        plain["eval/val252+swap"].seconds + (1.15 - 1) * (plain["eval/val252+swap"].seconds - 3 * C.eval_overhead_s / 2))


def test_a_run_part_way_through_training_is_costed_for_what_it_has_left(tmp_path):
    """nue@s2's last.pt at step 1,000 of 4,000: a quarter of its training done, so alone on one worker it costs 3/4
    of the modelled training plus its whole selection; fr@s2's last.pt at the final step counts it as trained (only
    its selection is left, not costed)."""
    import torch

    folders = RunFolders(tmp_path, Path(), Path())
    for name in ("nue@s2", "fr@s2"):
        folders.run(name).mkdir(parents=True)
    torch.save({"step": 1000}, folders.run("nue@s2") / "last.pt")
    torch.save({"step": 4000}, folders.run("fr@s2") / "last.pt")
    (one,) = [s for s in estimate(V12, 1, runs=["nue@s2"], trained={"nue@s2": 0.25}) if s.stage == "train"]
    assert one.seconds == pytest.approx(C.train_overhead_s + 0.75 * NUE_TRAIN_S + 42 * 11.5 / 1.70)
    assert "trained already: nue@s2 25%" in one.detail
    left = {s.stage: s for s in remaining_estimate(V12, folders, 2)}["train"]
    others = [r.name for r in V12.training_runs() if r.name != "fr@s2"]
    assert left.seconds == pytest.approx(
        {s.stage: s for s in estimate(V12, 2, runs=others, trained={"nue@s2": 0.25})}["train"].seconds)
    assert "23 runs" in left.detail and "nue@s2 25%" in left.detail and "fr@s2" not in left.detail
