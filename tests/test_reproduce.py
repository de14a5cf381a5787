"""``nue reproduce``: the quick recipe end to end through the command line, killed after three stages (an
injected failure) and rerun — no finished stage is redone, and the rest completes to RESULTS.md; a rerun
with another recipe is refused; the recipes are the documented ones (v5 trains as the v5 checkpoints
were trained); the estimate adds up; a model's training seeds differ in the training seed only (the quick
recipe trains NUE twice), v7 is v6 with seeds, and the estimate counts every seed."""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import os
from pathlib import Path

import pytest

import torch

from nue.cli import main
from nue.errors import ConfigError
from nue.evaluate.report import load_records
from nue.evaluate.results_md import is_earlier_recipe
from nue.evaluate.table import build_table, canonical_method, seed_run_name, split_seed
from nue.policy.checkpoint import load_checkpoint, load_policy
from nue.policy.config import ABLATION_PRESETS, get_model_config
from nue.recipe import TABLE_I_MODELS, StepPlan, estimate, format_estimate, training_seed
from nue.recipes import RECIPES, get_recipe
from nue.reproduce import FAIL_AFTER_STAGE_ENV, RunFolders, plan_stages, reproduce, train_config
from nue.reproduce_marker import HousesSummary, StageMarker, TrainRunSummary
from nue.reproduce_train import collect_configs, run_training
from nue.train.collect import CollectSummary

EPISODES = Path(__file__).resolve().parents[1] / "episodes"
pytestmark = pytest.mark.timeout(600)  # the quick run takes ~35 s of CPU; a loaded machine stretches the wall clock
KILLED_AFTER = ("scenes", "collect", "collect/train_diverse", "train/nue")


def _nue(*args) -> tuple[int, str]:
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), pytest.raises(SystemExit) as stop:
        main([str(a) for a in args])
    return stop.value.code, buf.getvalue()


def _finished(folders: RunFolders, stage: str) -> None:
    """Leave the marker of a finished ``scenes``, ``collect`` or ``train/<run>`` stage (made-up numbers)."""
    summary = {"scenes": HousesSummary(["train_00"]), "collect": CollectSummary(1, 10, 100, 10.0, 1.0, "abcd")}.get(
        stage, TrainRunSummary(best=f"runs/{stage.removeprefix('train/')}/best.pt", seconds=1.0))
    folders.marker(stage).write_text(json.dumps(StageMarker(stage, 1.0, "2026-12-05 00:00 UTC", summary).to_dict()))


def _stamps(folder: Path) -> dict[str, int]:
    return {str(p.relative_to(folder)): p.stat().st_mtime_ns for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """The quick recipe, stopped after three stages, then rerun to the end."""
    root = tmp_path_factory.mktemp("reproduce")
    args = ["reproduce", "--quick", "--out", root / "run", "--scenes-root", root / "scenes", "--episodes-root", EPISODES]
    os.environ[FAIL_AFTER_STAGE_ENV] = str(len(KILLED_AFTER))
    try:
        first = _nue(*args)
    finally:
        del os.environ[FAIL_AFTER_STAGE_ENV]
    out = root / "run"
    before = {part: _stamps(out / part) for part in ("demos", "demos_train_diverse", "runs/nue", "stages")}
    second = _nue(*args)
    return out, first, second, before, args


def test_quick_run_prints_its_estimate_and_reaches_results(run):
    out, first, second, _, _ = run
    code, text = first
    assert code == 3  # the injected failure: "stopped"
    assert text.startswith("nue reproduce: recipe 'quick'") and "estimated wall-clock" in text
    assert text.index("  total ") < text.index("[1/")  # the whole estimate before the first stage
    code, text = second
    assert code == 0, text
    stages = plan_stages(RECIPES["quick"])
    assert all(RunFolders(out, Path(), Path()).marker(s).is_file() for s in stages)
    records = {name: load_records(out / "records" / f"{name}.jsonl") for name in ("val252", "val_plain", "val252+swap",
                                                                                "val_plain+swap", "val252+sling",
                                                                                "val_plain+sling")}
    methods = {*TABLE_I_MODELS, "nue@s1", "expert"}  # the quick recipe trains NUE with 2 seeds
    assert {r.method for r in records["val252"]} == methods == {r.method for r in records["val_plain"]}
    assert {r.scene for r in records["val252"]} == {"val_00"} and {r.scene for r in records["val_plain"]} == {"val_plain_00"}
    swapped = {"nue+swap", "nue@s1+swap"}
    assert {r.method for r in records["val252+swap"]} == swapped == {r.method for r in records["val_plain+swap"]}
    assert {r.scene for r in records["val_plain+swap"]} == {"val_plain_00"}
    wrapped = {"sling+nue", "sling+nue@s1"}  # the quick recipe's SLING row, every seed, on both sets
    assert {r.method for r in records["val252+sling"]} == wrapped == {r.method for r in records["val_plain+sling"]}
    assert all(r.extra["last_mile"]["match_calls"] >= 1 for r in records["val252+sling"])
    results = (out / "RESULTS.md").read_text()
    assert "## Table I: ours next to the paper" in results and "nue reproduce --recipe quick" in results
    assert "## Table I on `val`" in results and "## Table I on `val_plain`" in results
    # the quick run's val252 episodes are val's, and of two equal sets the further one is pooled (named, not
    # "Table I's episodes"); in a full run val lies inside val252 and the section is "`val252` + `val_plain`"
    assert "## Pooled: `val` + `val_plain`\n" in results
    assert "## Generalisation to held-out styles\n" in results  # val_plain is a held-out style family
    from nue.train.hardware import machine_summary  # each marker says where its stage finished

    assert f"| stage machines | where the call that finished each stage ran, stages: {machine_summary()} " in results
    # each evaluation stage's runs counted from its records (its marker times only the call that finished it)
    for name, recs in records.items():
        assert f"eval/{name} " in results and f" ({len(recs)} run" in results.split(f"eval/{name} ")[1].split(";")[0]
    for table in ("val252", "val", "val_plain"):
        assert (out / "report" / table / "table.md").is_file() and (out / "report" / table / "coverage.png").is_file()
    assert json.loads((out / "recipe.json").read_text())["recipe"] == RECIPES["quick"].to_dict()
    # the exploration benchmark: 2 houses x 3 bins x 1 start, both seeds of NUE and the two references, 5 steps each
    explored = load_records(out / "records" / "explore" / "val252.jsonl")
    assert {r.method for r in explored} == {"nue", "nue@s1", "expert-explore", "random"} and len(explored) == 24
    assert {r.scene for r in explored} == {"val_00", "val_01"} and all(len(r.extra["coverage"]) == 5 for r in explored)
    assert (out / "report" / "explore_val252.png").read_bytes()[:4] == b"\x89PNG"  # its figure
    assert "## Exploration benchmark from `val252`'s starts" in results and "explore/val252 " in results
    # two collections (quick's train_00 and train_diverse_00, 3 episodes each), and every model trained on both
    assert "| demonstrations | 6 episodes, " in results
    assert {json.loads((out / d / "manifest.json").read_text())["split"] for d in ("demos", "demos_train_diverse")} == {
        "train", "train_diverse"}
    assert train_config(RECIPES["quick"], "nue", RunFolders(out, Path(), Path())).data == f"{out / 'demos'},{out / 'demos_train_diverse'}"


def test_a_killed_run_resumes_without_redoing_a_stage(run):
    out, _, (_, text), before, _ = run
    for stage in KILLED_AFTER:
        assert f"{stage}: finished in an earlier call" in text
        assert f"  {stage}: done" not in text
    assert "  train/abl_none: done" in text and "  report: done" in text
    estimate_lines = text[: text.index("[1/")].splitlines()
    assert any(line.split()[:2] == ["collect", "done"] for line in estimate_lines)  # the rerun estimates what is left
    assert "1 trained earlier" in text and estimate_lines[-2].endswith("left to run")
    # ... at the rates the first call measured: its one training run (NUE), its records timed no episode steps
    assert estimate_lines[-1].startswith("  calibrated to this run's measured costs") and "nue x" in estimate_lines[-1]
    assert "training time nue x" in estimate_lines[-1] and "(1 run)" in estimate_lines[-1]
    for part, stamps in before.items():  # collected episodes, the finished model's run folder, the stage markers
        now = _stamps(out / part)
        assert {k: now[k] for k in stamps} == stamps, part


def test_estimate_only_prints_what_is_left_of_a_run_and_refuses_another_recipe(run):
    out, _, _, _, args = run
    code, text = _nue(*args, "--estimate")
    lines = text.splitlines()
    assert lines[-1].startswith("  calibrated to this run's measured costs"), text  # from its finished work
    assert code == 0 and all(line.split()[1] == "done" for line in lines[1:-2]), text
    assert lines[-2].split()[:3] == ["total", "0", "s"]
    code, _ = _nue("reproduce", "--recipe", "v6", "--out", out, "--estimate")
    assert code == 2


def test_a_recipe_with_dagger_rounds_trains_through_them(run, tmp_path):
    """The training stage of a recipe with a DAgger round, on the quick run's demonstrations: behaviour cloning
    (round 0), then the policy drives the recipe's training episodes with the expert labelling, and round 1
    retrains on both; the stage's best checkpoint is round 1's."""
    out = run[0]
    recipe = get_recipe("quick").replace(name="quick_dagger", models=("fr",), swap_maps=(), last_mile=(), explore_models=(), dagger_rounds=1,
                                         dagger_beta=0.5, dagger_steps=2, dagger_episodes_per_bin=1)
    folders = RunFolders(tmp_path / "run", out.parent / "scenes", EPISODES)
    folders.out.mkdir()
    for demos in ("demos", "demos_train_diverse"):
        (folders.out / demos).symlink_to(out / demos, target_is_directory=True)
    done = {}
    run_training(recipe, folders, ["train/fr"], workers=1, ray_address=None, device="cpu", progress=False,
                  finish=lambda stage, seconds, result: done.update({stage: result}))
    rounds = done["train/fr"].rounds
    assert [r.round for r in rounds] == [0, 1] and rounds[1].beta == 0.5
    assert rounds[1].collected.episodes == 3  # 1 house x 3 bins x the first episode
    assert Path(done["train/fr"].best) == rounds[1].best and "round_1" in str(rounds[1].best)
    assert rounds[1].best.is_file() and rounds[1].data.endswith("data_r1")


def test_a_rerun_with_another_recipe_is_refused(run):
    out, _, _, _, args = run
    with pytest.raises(ConfigError, match="noise"):
        reproduce(get_recipe("quick").replace(noise=0.1), out, echo=lambda s: None)
    code, _ = _nue(*[a for a in args if a != "--quick"])  # the default recipe, v12, into the quick run's folder
    assert code == 2
    assert json.loads((out / "recipe.json").read_text())["recipe"]["name"] == "quick"


def test_v3_is_the_documented_recipe_for_every_model():
    v3 = get_recipe("v3")
    assert (v3.expert, v3.noise, v3.episodes_per_bin, v3.heldout_per_bin) == ("explore", 0.3, 6, 1)
    assert (v3.train_minutes, v3.batch_size, v3.precision, v3.map_dropout) == (34.0, 64, "auto", 0.2)
    assert (v3.select, v3.select_candidates, v3.budget_clock) == ("closed_loop", 3, "cpu")
    assert v3.models == TABLE_I_MODELS and len(TABLE_I_MODELS) == 8
    assert v3.step_plan("nue") == v3.step_plan("abl_fu") == StepPlan(12_000, 750)
    assert v3.step_plan("fr") == StepPlan(30_000, 1_500)
    assert v3.batch_for("nav_a3c") == 8 and v3.samples_per_step("nav_a3c") == 64 == v3.samples_per_step("nue")
    by_samples = v3.replace(train_samples=640_000)
    assert by_samples.train_steps("nue") == by_samples.train_steps("nav_a3c") == 10_000
    with pytest.raises(ConfigError):
        v3.replace(models=("nue", "no_such_model"))
    with pytest.raises(ConfigError):
        get_recipe("no_such_recipe")


@pytest.mark.parametrize("model", ["nue", "fr", "nav_a3c", "abl_none"])
def test_v5_trains_as_the_v5_checkpoints_were_trained(model):
    """Every training setting of the v5 checkpoints (``results/v5/checkpoints/<model>_v5.pt``, shipped until the v6
    run replaced them; stored in the file) is what the v5 preset gives that model, but for the paths, which belong
    to the run."""
    _, header = load_policy(EPISODES.parent / "results" / "v5" / "checkpoints" / f"{model}_v5.pt")
    folders = RunFolders(Path("/nowhere"), Path("data/scenes"), Path("episodes"))
    ours = dataclasses.asdict(train_config(get_recipe("v5"), model, folders))
    paths = {"data", "out", "select_episodes", "select_scenes_root"}
    stored = {k: v for k, v in header.train_config.items() if k in ours and k not in paths}
    # trained in bf16 on a CPU with AVX512-BF16; the recipe says auto (bf16 there, fp32 where bf16 is emulated).
    # Their budget was wall-clock on a quiet machine (budget_clock is newer than them, so not stored); v5 counts
    # CPU time, which is the same there and stays the same on a busy machine.
    assert (stored.pop("precision"), ours["precision"]) == ("bf16", "auto")
    assert len(stored) >= 20 and stored == {k: ours[k] for k in stored}
    assert header.manifest_hash == "cc12e17f2c5e6ce1"  # the exploring expert's demonstrations (v3 collect command)
    v5, v3 = get_recipe("v5"), get_recipe("v3")
    assert (v5.expert, v5.noise, v5.episodes_per_bin, v5.heldout_per_bin) == (v3.expert, v3.noise, 6, 1)
    v6 = get_recipe("v6")
    assert v6 == v5.replace(name="v6", train_minutes=0.0, train_samples=256_000)
    assert {m: v6.train_steps(m) for m in ("nue", "fr", "nav_a3c")} == {"nue": 4000, "fr": 4000, "nav_a3c": 4000}
    assert train_config(v6, "nue", folders).time_budget_s == 0 and train_config(v6, "nav_a3c", folders).steps == 4000


@pytest.mark.parametrize("model", TABLE_I_MODELS)
def test_the_v6_run_trained_every_model_as_the_recipe_says(model):
    """The committed `nue reproduce` run (``results/reproduce/run``): every training setting stored in each
    model's ``best.pt`` is what v6 gives that model with ``--compile`` (how the run was started), paths aside,
    it trained in fp32, and every model saw the same 4,000 steps of 64 samples of the same demonstrations."""
    _, header = load_policy(EPISODES.parent / "results" / "reproduce" / "run" / "runs" / model / "best.pt")
    folders = RunFolders(Path("/nowhere"), Path("data/scenes"), Path("episodes"))
    ours = dataclasses.asdict(train_config(get_recipe("v6"), model, folders, compile=True))
    ours.pop("goal_weight"), ours.pop("goal_balance")  # recorded only by models with the exploitation head (none of v6's)
    assert ours.pop("exploit_weight") == 1.0  # recorded only when not 1
    paths = {"data", "out", "select_episodes", "select_scenes_root"}
    stored = {k: v for k, v in header.train_config.items() if k not in paths}
    assert stored.pop("precision_resolved") == "fp32"  # precision auto on a CPU without native bf16
    assert stored == {k: v for k, v in ours.items() if k not in paths}
    assert stored["steps"] * stored["batch_size"] * (8 if model == "nav_a3c" else 1) == 256_000
    assert header.manifest_hash == "cc12e17f2c5e6ce1"


def test_the_estimate_covers_every_stage_and_scales_with_workers():
    v3 = get_recipe("v3")
    one, two = estimate(v3, 1), estimate(v3, 2)
    assert [s.stage for s in one] == ["scenes", "collect", "train", "eval/val252", "eval/val252+swap", "eval/val_plain",
                                      "eval/val_plain+swap",
                                      "report"]
    by = {s.stage: s.seconds for s in two}
    assert 20 * 60 < by["collect"] < 35 * 60  # the v3/v5 collect command measured 27.7 min on 2 workers at 20da927
    assert by["train"] >= 4 * 34 * 60  # 8 models x 34 min, two at a time
    assert sum(s.seconds for s in two) < sum(s.seconds for s in one)
    assert format_estimate(two).splitlines()[-1].split()[0] == "total"


def test_a_resumed_run_estimates_only_what_is_left(tmp_path):
    """Finished stages count 0, training only the models not trained yet, an evaluation stage the share of its
    (episode, method) runs not recorded yet."""
    from nue.reproduce import remaining_estimate

    v6 = get_recipe("v6")
    folders = RunFolders(tmp_path, Path(), Path())
    fresh = {s.stage: s for s in remaining_estimate(v6, folders, 2)}
    assert fresh == {s.stage: s for s in estimate(v6, 2)}  # nothing done yet: the whole estimate
    folders.marker("collect").parent.mkdir(parents=True)
    for stage in ["scenes", "collect", *[f"train/{m}" for m in v6.models[:6]]]:
        _finished(folders, stage)
    runs = 252 * (len(v6.models) + len(v6.experts))
    folders.records("eval/val252").parent.mkdir()
    folders.records("eval/val252").write_text("{}\n" * (runs // 4))  # a quarter of the runs recorded
    left = {s.stage: s for s in remaining_estimate(v6, folders, 2)}
    assert left["scenes"].done and left["collect"].done and left["scenes"].seconds == left["collect"].seconds == 0
    two_models = {s.stage: s for s in estimate(v6, 2, runs=v6.models[6:])}["train"].seconds
    assert not left["train"].done and left["train"].seconds == two_models < fresh["train"].seconds
    assert "6 trained earlier" in left["train"].detail
    assert left["eval/val252"].seconds == pytest.approx(0.75 * fresh["eval/val252"].seconds)
    assert f"{runs // 4:,} of {runs:,} runs recorded" in left["eval/val252"].detail
    assert left["eval/val_plain"] == fresh["eval/val_plain"]
    text = format_estimate(list(left.values()))
    assert text.splitlines()[0].split()[:2] == ["scenes", "done"] and text.endswith("left to run")


def test_a_compiled_run_estimates_shorter_training_by_the_measured_speedup():
    from nue.recipe import CostModel

    v6, cost = get_recipe("v6"), CostModel()
    eager = {s.stage: s for s in estimate(v6, 1)}
    compiled = {s.stage: s for s in estimate(v6, 1, compiled=True)}
    assert "(compiled)" in compiled["train"].detail and "(compiled)" not in eager["train"].detail
    assert compiled["collect"].seconds == eager["collect"].seconds  # only training runs compiled
    # one worker: the models' times add up, each kind faster by its measured factor
    samples = 256_000
    saved = sum(samples / dict(cost.samples_per_s)[k] * (1 - 1 / dict(cost.compiled_speedup)[k])
                for k in ["nue"] * 6 + ["fr", "nav_a3c"])
    assert abs((eager["train"].seconds - compiled["train"].seconds) - saved) < 1.0


def test_two_seeds_of_a_quick_run_differ_in_the_training_seed_only(run):
    """The quick recipe trains NUE with 2 seeds (runs ``nue`` and ``nue@s1``): the same demonstrations (one folder, one
    manifest hash) and every training setting the same but the seed and the run folder; different weights; their
    records pair episode by episode (the same episodes with the same per-episode seeds and run settings), in the
    swapped-maps control too; the report pools them into one row of 2 seeds."""
    out = run[0]
    quick = get_recipe("quick")
    runs = {r.name: r for r in quick.training_runs()}
    assert (runs["nue"].seed, runs["nue@s1"].seed) == (0, training_seed(0, 1)) and training_seed(0, 1) != 0
    headers = {name: load_policy(out / "runs" / name / "best.pt")[1] for name in ("nue", "nue@s1")}
    a, b = (dict(headers[n].train_config) for n in ("nue", "nue@s1"))
    assert (a.pop("seed"), b.pop("seed")) == (0, training_seed(0, 1))
    assert (a.pop("out"), b.pop("out")) == (str(out / "runs" / "nue"), str(out / "runs" / "nue@s1"))
    assert a == b and a["data"] == f"{out / 'demos'},{out / 'demos_train_diverse'}"  # quick's two collections
    assert headers["nue"].manifest_hash == headers["nue@s1"].manifest_hash and headers["nue"].model == headers["nue@s1"].model
    w0, w1 = (load_checkpoint(out / "runs" / n / "best.pt")["model_state"] for n in ("nue", "nue@s1"))
    assert w0.keys() == w1.keys() and any(not torch.equal(w0[k], w1[k]) for k in w0)
    markers = {n: json.loads((out / "stages" / f"train__{n}.json").read_text())["summary"] for n in ("nue", "nue@s1")}
    assert [(m["model"], m["seed"]) for m in markers.values()] == [("nue", 0), ("nue", training_seed(0, 1))]
    for stage, pair in (("val252", ("nue", "nue@s1")), ("val_plain", ("nue", "nue@s1")),
                        ("val252+swap", ("nue+swap", "nue@s1+swap"))):
        recs = load_records(out / "records" / f"{stage}.jsonl")
        sides = []
        for method in pair:
            mine = sorted((r for r in recs if r.method == method), key=lambda r: (r.scene, r.episode_id))
            sides.append([(r.scene, r.episode_id, r.extra["seed"], {k: v for k, v in r.extra["settings"].items()
                                                                    if k != "agent"}) for r in mine])
        assert sides[0] == sides[1] and len(sides[0]) == 1, stage
    (nue,) = [row for row in build_table(load_records(out / "records" / "val252.jsonl")) if row.method == "nue"]
    assert nue.runs == ("nue", "nue@s1") and nue.seeds == 2 and nue.cells["total"].spread.episodes == (1, 1)
    assert "| NUE (full) | 1 x 2 |" in (out / "RESULTS.md").read_text()


def test_a_seed_index_gives_a_run_name_and_a_training_seed():
    """Seed 0 is the model itself with the recipe's seed (a single-seed recipe trains as before); seed k >= 1 is
    ``<model>@s<k>`` with the first word of SeedSequence([seed, k]) modulo 2**31 (pinned: stable across processes)."""
    assert (training_seed(0, 0), training_seed(7, 0)) == (0, 7)
    assert (training_seed(0, 1), training_seed(0, 2)) == (1817441348, 993632895)
    assert len({training_seed(s, k) for s in range(3) for k in range(1, 4)}) == 9
    assert all(0 <= training_seed(s, k) < 2**31 for s in range(3) for k in range(4))
    assert (seed_run_name("nue", 0), seed_run_name("abl_fu", 2)) == ("nue", "abl_fu@s2")
    assert split_seed("abl_fu@s2") == ("abl_fu", 2) and split_seed("nue@s1+swap") == ("nue+swap", 1)
    assert split_seed("nue") == ("nue", 0) and split_seed("nue_v5a+swap") == ("nue_v5a+swap", 0)
    assert split_seed("nue@s0") == ("nue@s0", 0)  # seed 0 is never suffixed
    assert canonical_method("nue@s1") == "nue@s1" and canonical_method(split_seed("NUE (full)@s1")[0]) == "nue"
    assert not is_earlier_recipe("nue@s1") and not is_earlier_recipe("abl_fu@s2+swap")
    assert is_earlier_recipe("nue_v5a") and is_earlier_recipe("nue_v6@s1+swap")


def test_the_default_recipe_is_v12_the_recurrent_nue_in_both_house_sets(tmp_path):
    """Issue 43's choice: without --recipe `nue reproduce` runs v12, issue 37's v10 (the recurrent NUE, its recurrent
    ablations, 3 seeds for the compared rows) trained in both house sets and evaluated on both held-out style
    families; the command's default is nue.recipes.DEFAULT_RECIPE."""
    import inspect

    from nue.cli_reproduce import reproduce_cmd
    from nue.recipes import DEFAULT_RECIPE

    assert DEFAULT_RECIPE == "v12" and inspect.signature(reproduce_cmd).parameters["recipe"].default.default == DEFAULT_RECIPE
    v12 = get_recipe(DEFAULT_RECIPE)
    assert v12.memory == "lean" and dict(v12.rows)["nue_gru_lean"] == "nue" and get_model_config("nue_gru_lean").recurrent
    assert dict(v12.train_seeds)["nue_gru_lean"] == 3 and dict(v12.train_seeds)["abl_at_cbam_gru_lean"] == 3
    assert [c.split for c in v12.collections()] == ["train", "train_diverse"] and v12.select_set == "select_diverse"
    assert v12.eval_sets == ("val252", "val_plain", "val_pale") and v12.explore_sets == ("val252",)
    code, out = _nue("reproduce", "--out", str(tmp_path / "none"), "--workers", "2", "--estimate")
    assert code == 0 and out.startswith("recipe 'v12', 2 worker(s):") and "24 runs (models x seeds)" in out
    assert "collect/train_diverse" in out and "eval/val_pale " in out and "explore/val252" in out


def test_v7_is_v6_with_three_seeds_for_four_models_and_v6_is_unchanged():
    v6, v7 = get_recipe("v6"), get_recipe("v7")
    assert v6.train_seeds == () and v6.training_runs() == v6.training_runs(v6.models)
    assert [r.name for r in v6.training_runs()] == list(v6.models) and all(r.seed == 0 for r in v6.training_runs())
    assert v7 == v6.replace(name="v7", train_seeds=(("nue", 3), ("abl_at_cbam", 3), ("abl_none", 3), ("fr", 3)))
    no_fu, all_off, full = (get_model_config(m) for m in ("abl_at_cbam", "abl_none", "nue"))  # the ablations' switches
    assert {"abl_at_cbam", "abl_none"} <= set(ABLATION_PRESETS) and full.use_uncertainty and full.use_aux and full.use_cbam
    assert (no_fu.use_uncertainty, no_fu.use_aux, no_fu.use_cbam) == (False, True, True)  # NUE without f_u
    assert (all_off.use_uncertainty, all_off.use_aux, all_off.use_cbam) == (False, False, False)
    names = [r.name for r in v7.training_runs()]
    assert names[:8] == list(v6.models)  # every model's seed 0 first: v6's runs, with v6's seeds
    assert names[8:] == ["nue@s1", "abl_none@s1", "abl_at_cbam@s1", "fr@s1", "nue@s2", "abl_none@s2", "abl_at_cbam@s2",
                         "fr@s2"]
    assert [r.seed for r in v7.training_runs()] == [0] * 8 + [training_seed(0, 1)] * 4 + [training_seed(0, 2)] * 4
    assert plan_stages(v7)[2:18] == [f"train/{n}" for n in names] and plan_stages(v7)[18] == "eval/val252"
    assert (v7.seeds_of("nue"), v7.seeds_of("nav_a3c")) == (3, 1)
    folders = RunFolders(Path("/run"), Path("data/scenes"), Path("episodes"))
    seed0, seed2 = (dataclasses.asdict(train_config(v7, n, folders)) for n in ("abl_at_cbam", "abl_at_cbam@s2"))
    assert seed0 == dataclasses.asdict(train_config(v6, "abl_at_cbam", folders))  # seed 0 trains as in v6
    assert (seed2.pop("seed"), seed2.pop("out")) == (training_seed(0, 2), "/run/runs/abl_at_cbam@s2")
    assert {k: v for k, v in seed0.items() if k not in ("seed", "out")} == seed2
    with pytest.raises(ConfigError):
        train_config(v7, "nav_a3c@s1", folders)  # one seed only
    with pytest.raises(ConfigError):
        v6.replace(train_seeds=(("nue", 0),))
    with pytest.raises(ConfigError):
        v6.replace(train_seeds=(("nue", 2), ("nue", 3)))
    with pytest.raises(ConfigError):
        v6.replace(train_seeds=(("no_such_model", 2),))
    assert v7.replace(models=("fr",), swap_maps=()).training_runs()[-1].name == "fr@s2"  # untrained models: ignored
    assert "training seeds: nue x3, abl_at_cbam x3, abl_none x3, fr x3 (16 runs; the others once)" in v7.summary()
    assert "training seeds" not in v6.summary()


def test_the_estimate_counts_every_seed_s_training_selection_and_evaluation():
    """v7 - v6, one worker: 8 more training jobs (3 NUE-family + FR, twice), each with its closed-loop selection;
    8 more methods per evaluation set; 3 swapped-maps runs of NUE instead of 1."""
    from nue.recipe import CostModel

    v6, v7, c = get_recipe("v6"), get_recipe("v7"), CostModel()
    six, seven = ({s.stage: s for s in estimate(r, 1)} for r in (v6, v7))
    job_nue = 10.0 + 256_000 / 98.0 + 2 * 21 * 11.5  # overhead + samples / rate + 2 candidates x 21 episodes
    job_fr = 10.0 + 256_000 / 200.0 + 2 * 21 * 1.7
    assert seven["train"].seconds - six["train"].seconds == pytest.approx(2 * (3 * job_nue + job_fr))
    assert "16 runs (models x seeds)" in seven["train"].detail and "8 models" in six["train"].detail
    for name in ("val252", "val_plain"):
        extra = 252 * 2 * (3 * 13.3 + 3.4) + 8 * 5.0
        assert seven[f"eval/{name}"].seconds - six[f"eval/{name}"].seconds == pytest.approx(extra)
        assert "18 methods" in seven[f"eval/{name}"].detail
        assert seven[f"eval/{name}+swap"].seconds == pytest.approx(3 * six[f"eval/{name}+swap"].seconds)
    assert (seven["collect"], seven["scenes"]) == (six["collect"], six["scenes"])
    assert c.train_overhead_s == 10.0 and dict(c.samples_per_s)["nue"] == 98.0  # the numbers used above
    code, text = _nue("reproduce", "--recipe", "v7", "--estimate", "--workers", 2, "--out", "/nonexistent/run")
    assert code == 0 and "16 runs (models x seeds)" in text and "18 methods" in text


def test_the_sling_rows_are_a_stage_of_their_own_with_their_cost():
    """v8 = v7 + SLING on NUE (3 seeds), FR (3 seeds) and Nav-A3C: 7 wrapped runs per set, each costing its model's
    episode plus the wrapper's; a model the recipe does not train is refused; recipes without it keep their dict."""
    from nue.recipe import CostModel

    v7, v8, c = get_recipe("v7"), get_recipe("v8"), CostModel()
    assert "last_mile" not in v7.to_dict() and v8.to_dict()["last_mile"] == ["nue", "fr", "nav_a3c"]
    after_swap = [s for st in plan_stages(v7) for s in ([st, st.replace("+swap", "+sling")] if st.endswith("+swap") else [st])]
    assert plan_stages(v8) == after_swap and "eval/val_plain+sling" in after_swap
    by = {s.stage: s for s in estimate(v8, 1)}
    sling = dict(c.eval_s_per_episode)["sling"]
    expected = 252 * (3 * (13.3 + sling) + 3 * (3.4 + sling) + (3.9 + sling)) + 7 * 5.0
    assert by["eval/val252+sling"].seconds == pytest.approx(expected)
    assert "7 runs with SLING" in by["eval/val_plain+sling"].detail
    assert "SLING last mile: nue, fr, nav_a3c" in v8.summary() and "SLING" not in v7.summary()
    with pytest.raises(ConfigError, match="last_mile"):
        v7.replace(last_mile=("vgm",))


def test_the_lean_memory_shortens_only_the_map_reading_models_by_the_measured_factors():
    """v9 (the lean memory): a NUE-family episode costs 13.3 / 1.70 s, its training 256,000 / (98 x 1.37) s and its
    selection episode 11.5 / 1.70 s; FR, Nav-A3C and the experts cost what they cost under ``fast``."""
    from nue.recipe import CostModel

    v8, v9, c = get_recipe("v8"), get_recipe("v9"), CostModel()
    assert v9.memory == "lean" and all(m.endswith("_lean") or m in ("fr", "nav_a3c", "vgm", "nrns") for m in v9.models)
    assert dict(c.memory_speedup)["lean"] == 1.70 and dict(c.map_train_speedup)["lean"] == 1.37
    v8_rows = tuple(m for m in v9.models if m not in ("vgm", "nrns"))
    one = {s.stage: s for s in estimate(v9.replace(models=v8_rows, train_seeds=(), last_mile=(), swap_maps=()), 1)}
    ref = {s.stage: s for s in estimate(v8.replace(train_seeds=(), last_mile=(), swap_maps=()), 1)}
    nue_eval = 252 * 6 * (13.3 - 13.3 / 1.70)
    assert ref["eval/val252"].seconds - one["eval/val252"].seconds == pytest.approx(nue_eval)
    nue_train = 6 * (256_000 / 98.0 * (1 - 1 / 1.37) + 2 * 21 * (11.5 - 11.5 / 1.70))
    assert ref["train"].seconds - one["train"].seconds == pytest.approx(nue_train)
    two = {s.stage: s for s in estimate(v9, 2)}
    assert "24 runs (models x seeds)" in two["train"].detail and "9 runs with SLING" in two["eval/val252+sling"].detail


def test_v9_trains_the_memory_baselines_like_every_row_and_costs_them(tmp_path):
    """VGM and NRNS are v9 rows with 3 seeds on the same demonstrations and samples; NRNS is selected by held-out
    distance error (it has no actions to run in closed loop); their training and evaluation enter the estimate at
    the cost model's rates (256,000 samples / rate; NRNS without selection episodes)."""
    from nue.recipe import CostModel

    v9, c = get_recipe("v9"), CostModel()
    assert v9.seeds_of("vgm") == v9.seeds_of("nrns") == 3 and {"vgm", "nrns"} <= set(v9.models)
    folders = RunFolders(tmp_path, tmp_path / "scenes", tmp_path / "episodes")
    nrns, vgm = train_config(v9, "nrns@s2", folders), train_config(v9, "vgm", folders)
    assert nrns.select == "accuracy" and vgm.select == "closed_loop" and nrns.eval_every == vgm.eval_every == 1_500
    assert nrns.steps * nrns.batch_size == 256_000 and vgm.steps * vgm.batch_size * vgm.seq_len == 256_000
    assert nrns.map_dropout == vgm.map_dropout == 0.0 and nrns.out.endswith("nrns@s2")
    base = v9.replace(models=("fr",), train_seeds=(), last_mile=(), swap_maps=(), experts=())
    fr = {s.stage: s.seconds for s in estimate(base, 1)}
    for model, select_s in (("nrns", 0.0), ("vgm", 4.2 * 2 * 21)):
        both = {s.stage: s.seconds for s in estimate(base.replace(models=("fr", model)), 1)}
        rate = dict(c.samples_per_s)[model]
        assert both["train"] - fr["train"] == pytest.approx(c.train_overhead_s + 256_000 / rate + select_s)
        assert both["eval/val252"] - fr["eval/val252"] == pytest.approx(
            252 * dict(c.eval_s_per_episode)[model] + c.eval_overhead_s)


def test_v10_is_v9_with_the_recurrent_nue_and_ablations(tmp_path):
    """v10 swaps each NUE-family row of v9 for its GRU twin (same seeds, swapped-maps and SLING rows on the recurrent
    NUE) and keeps the baselines; a recurrent row trains 8 sequences of 8 steps, the same 256,000 samples."""
    v9, v10 = get_recipe("v9"), get_recipe("v10")
    twin = {m: m.replace("_lean", "_gru_lean") if m.startswith(("nue", "abl_")) else m for m in v9.models}
    assert v10.models == tuple(twin[m] for m in v9.models)
    assert {twin[m]: n for m, n in v9.train_seeds} == dict(v10.train_seeds)
    assert v10.swap_maps == ("nue_gru_lean",) and v10.last_mile == ("nue_gru_lean", "fr", "nav_a3c")
    assert v10.replace(name="v9", models=v9.models, train_seeds=v9.train_seeds, swap_maps=v9.swap_maps,
                       last_mile=v9.last_mile, rows=v9.rows) == v9
    assert [r.name for r in v10.training_runs()][:8] == ["nue", *ABLATION_PRESETS, "fr", "nav_a3c"]
    assert v10.training_run("abl_none@s1").model == "abl_none_gru_lean"
    folders = RunFolders(tmp_path, tmp_path / "scenes", tmp_path / "episodes")
    cfg = train_config(v10, "abl_at_cbam@s2", folders)
    assert cfg.model == "abl_at_cbam_gru_lean" and cfg.out.endswith("abl_at_cbam@s2")
    assert cfg.batch_size == 8 and cfg.steps * cfg.batch_size * cfg.seq_len == 256_000 and cfg.map_dropout == 0.2
    assert "24 runs (models x seeds)" in {s.stage: s for s in estimate(v10, 2)}["train"].detail
    assert "nue_gru_lean as nue" in v10.summary() and "rows" not in get_recipe("v8").to_dict()
    with pytest.raises(ConfigError, match="same Table I row"):
        v10.replace(models=(*v10.models, "nue"))
    with pytest.raises(ConfigError, match="not a Table I row key"):
        v10.replace(rows=(("nue_gru_lean", "nue_gru"),))


def test_a_recipe_collects_in_the_layout_of_its_map_reading_models():
    """The demonstrations store the maps at the recipe memory's size, through a model that reads them: v6 with
    ``nue``, v9 ``nue_lean``, v10 ``nue_gru_lean``; a baselines-only recipe on ``lean`` the first preset that does.
    (Before, every recipe collected as ``nue``, and ``lean`` recipes stopped at the collection: 45 x 60 != 30 x 40.)"""
    from nue.nerf.config import get_memory
    from nue.reproduce_train import collect_config, collection_model

    assert [collection_model(get_recipe(n)) for n in ("v6", "v9", "v10")] == ["nue", "nue_lean", "nue_gru_lean"]
    assert collection_model(get_recipe("v9").replace(models=("fr", "nrns"), swap_maps=(), last_mile=())) == "nue_lean"
    for name in ("v6", "v9", "v10"):
        recipe = get_recipe(name)
        cfg, memory = get_model_config(collect_config(recipe).model), get_memory(recipe.memory)
        assert tuple(cfg.map_size) == (memory.map_height, memory.map_width)
        assert all(tuple(get_model_config(m).map_size) == tuple(cfg.map_size) for m in recipe.models
                   if get_model_config(m).uses_memory_maps)


def test_a_run_started_before_train_seeds_existed_resumes_and_refuses_seeds(tmp_path):
    """A recipe.json written before a field was added (here ``train_seeds``) counts it at its default: the same
    recipe resumes, one with seeds is refused."""
    from nue.reproduce import check_recipe

    quick = get_recipe("quick").replace(train_seeds=())
    check_recipe(tmp_path, quick)
    stored = json.loads((tmp_path / "recipe.json").read_text())
    del stored["recipe"]["train_seeds"]
    (tmp_path / "recipe.json").write_text(json.dumps(stored))
    check_recipe(tmp_path, quick)
    with pytest.raises(ConfigError, match="train_seeds"):
        check_recipe(tmp_path, get_recipe("quick"))
    committed = EPISODES.parent / "results" / "reproduce" / "run"  # the v6 run, started before train_seeds existed
    assert "train_seeds" not in json.loads((committed / "recipe.json").read_text())["recipe"]
    check_recipe(committed, get_recipe("v6"))  # reads only: the file exists


def test_a_resumed_seeded_run_estimates_the_seeds_left(tmp_path):
    """v7 with every model's seed 0 trained: the 8 seed runs are left, and an evaluation stage counts 18 methods."""
    from nue.reproduce import remaining_estimate

    v7 = get_recipe("v7")
    folders = RunFolders(tmp_path, Path(), Path())
    folders.marker("collect").parent.mkdir(parents=True)
    for stage in ["scenes", "collect", *[f"train/{m}" for m in v7.models]]:
        _finished(folders, stage)
    folders.records("eval/val252").parent.mkdir()
    folders.records("eval/val252").write_text("{}\n" * (252 * 18 // 2))
    left = {s.stage: s for s in remaining_estimate(v7, folders, 2)}
    seeds = [r.name for r in v7.training_runs() if r.seed_index]
    assert left["train"].seconds == {s.stage: s for s in estimate(v7, 2, runs=seeds)}["train"].seconds > 0
    assert "8 runs (models x seeds)" in left["train"].detail and "8 trained earlier" in left["train"].detail
    assert "2,268 of 4,536 runs recorded" in left["eval/val252"].detail


def test_train_split_selects_the_collection_houses_and_keeps_old_recipe_dicts():
    from nue.errors import ConfigError
    from nue.recipes import get_recipe
    from nue.reproduce import _houses as houses_needed
    from nue.reproduce_train import collect_config
    from nue.scene.generator import SPLITS

    v6 = get_recipe("v6")
    assert "train_split" not in v6.to_dict() and collect_config(v6).split == "train"
    with pytest.raises(ConfigError, match="select_set 'select' is not a selection set of the 'train_diverse' houses"):
        v6.replace(train_split="train_diverse")  # would select in houses it did not train in
    diverse = v6.replace(train_split="train_diverse", select_set="select_diverse")
    assert diverse.to_dict()["train_split"] == "train_diverse" and collect_config(diverse).split == "train_diverse"
    assert diverse.to_dict()["select_set"] == "select_diverse" and "select_set" not in v6.to_dict()
    from nue.reproduce import RunFolders
    from nue.reproduce_train import train_config

    folders = RunFolders(Path("/run"), Path("data/scenes"), Path("episodes"))
    assert train_config(v6, "nue", folders).select_episodes == "episodes/select"
    assert train_config(get_recipe("v11"), "nue", folders).select_episodes == "episodes/select_diverse"
    assert collect_config(get_recipe("v11")).split == "train_diverse"
    needed = houses_needed(diverse)
    assert sum(s == "train_diverse" for s, _ in needed) == len(SPLITS["train_diverse"])
    assert not any(s == "train" for s, _ in needed)
    for split in ("nowhere", "val", "val_pale"):  # a model never learns from a validation split
        with pytest.raises(ConfigError, match="train_split"):
            v6.replace(train_split=split)
    with pytest.raises(ConfigError, match="eval_sets: 'select' is in training houses"):
        v6.replace(eval_sets=("val252", "select"))


def test_v12_trains_every_model_on_both_house_sets_and_costs_both_collections():
    """``also_train``: v12 is v10 plus v11's collection (21 ``train`` houses x 3 bins x 7 and 42 ``train_diverse`` x 3
    x 4 = 441 + 504 episodes); both are stages, both folders are every model's data, and the estimate counts both."""
    from nue.recipe import Collection
    from nue.reproduce import _houses as houses_needed
    from nue.reproduce_train import collect_configs
    from nue.scene.generator import SPLITS

    v10, v12 = get_recipe("v10"), get_recipe("v12")
    assert [c.split for c in collect_configs(v12)] == ["train", "train_diverse"]
    assert [(c.episodes_per_bin, c.heldout_per_bin) for c in collect_configs(v12)] == [(6, 1), (3, 1)]
    assert plan_stages(v12)[:3] == ["scenes", "collect", "collect/train_diverse"]
    assert "collect/train_diverse" not in plan_stages(v10) and "also_train" not in v10.to_dict()
    assert v12.to_dict()["also_train"] == [{"split": "train_diverse", "episodes_per_bin": 3, "heldout_per_bin": 1,
                                            "houses": []}]
    folders = RunFolders(Path("/run"), Path("data/scenes"), Path("episodes"))
    assert train_config(v12, "nue", folders).data == "/run/demos,/run/demos_train_diverse"
    assert train_config(v10, "nue", folders).data == "/run/demos"
    assert train_config(v12, "nue", folders).select_episodes == "episodes/select_diverse"
    needed = houses_needed(v12)
    assert sum(s == "train" for s, _ in needed) == 21 and sum(s == "train_diverse" for s, _ in needed) == 42
    by10 = {s.stage: s for s in estimate(v10)}
    by12 = {s.stage: s for s in estimate(v12)}
    assert by12["collect"].seconds == by10["collect"].seconds
    assert by12["collect/train_diverse"].seconds == pytest.approx(by10["collect"].seconds * 504 / 441)
    assert "504 episodes" in by12["collect/train_diverse"].detail
    assert "in 21 training houses and 3 + 1 held-out episodes per bin in 42 train_diverse houses" in v12.summary()
    bad = [(Collection("train", 3, 1),), (Collection("val", 3, 1),), (Collection("train_diverse", 0, 1),),
           (Collection("train_diverse", 3, 1), Collection("train_diverse", 1, 0))]
    for also in bad:  # the main split again, a validation split, no episodes, a split twice
        with pytest.raises(ConfigError, match="also_train"):
            v10.replace(also_train=also)
    assert len(SPLITS["train_diverse"]) == 42


def test_the_exploration_benchmark_is_a_stage_of_its_own_with_its_cost(tmp_path):
    """``explore_sets``: v12 runs every model's every seed and the two references from 42 of val252's starts (14
    houses x 3 bins x 1) for 800 steps; the stage is costed per step, and what a resumed run has recorded is left out;
    recipes without it keep their stages and their stored dicts."""
    from nue.recipe import CostModel
    from nue.reproduce import remaining_estimate

    v10, v12, c = get_recipe("v10"), get_recipe("v12"), CostModel()
    assert plan_stages(v12)[-2:] == ["explore/val252", "report"] and not any(s.startswith("explore/") for s in plan_stages(v10))
    assert "explore_sets" not in v10.to_dict() and v12.to_dict()["explore_models"] == list(v12.models)
    (stage,) = [s for s in estimate(v12) if s.stage.startswith("explore/")]
    runs = v12.training_runs(v12.models)
    per_start = 800 / c.eval_steps_per_episode * (
        sum(dict(c.eval_s_per_episode)["nue" if r.model.startswith(("nue", "abl")) else r.model]
            / (1.70 if r.model.startswith(("nue", "abl")) else 1.0) for r in runs)
        + dict(c.eval_s_per_episode)["expert-explore"] + dict(c.eval_s_per_episode)["nav_a3c"])
    assert stage.seconds == pytest.approx(42 * per_start + (len(runs) + 2) * c.eval_overhead_s)
    assert stage.detail.startswith(f"42 starts x {len(runs) + 2} methods x 800 steps")
    folders = RunFolders(tmp_path, Path("data/scenes"), EPISODES)
    folders.records("explore/val252").parent.mkdir(parents=True)
    folders.records("explore/val252").write_text("{}\n" * 42 * 13)  # half of the 42 x 26 runs
    (left,) = [s for s in remaining_estimate(v12, folders) if s.stage == "explore/val252"]
    assert left.seconds == pytest.approx(stage.seconds / 2) and "546 of 1,092 runs recorded" in left.detail
    for bad in ({"explore_models": ("nue_gru_lean",)}, {"explore_sets": ("select",)},
                {"explore_sets": ("val252",), "explore_houses": (3,)}, {"explore_sets": ("val252",), "explore_steps": 0}):
        with pytest.raises(ConfigError, match="explore"):
            v10.replace(**bad)


def test_adopted_collections_and_a_training_run_resume_and_other_settings_are_refused(run, tmp_path, capsys):
    """``nue reproduce --adopt``: the quick run's two collections and a finished training run, put into a new run
    folder, are what its stages make there: collecting writes no episode, the training run resumes at its last step
    (0 steps, the same best.pt after its selection resumes from its records) and the estimate counts it trained. A run
    adopted under another seed's name, a collection under another stage and an unknown name are refused before
    anything is moved; the command line refuses a malformed --adopt with one line (exit 2)."""
    from nue.errors import DataError
    from nue.reproduce import remaining_estimate
    from nue.reproduce_adopt import Adoption, adopt
    from nue.selection import select_run
    from nue.train.bc import train
    from nue.train.collect import collect

    out = run[0]
    quick = get_recipe("quick")
    new = RunFolders(tmp_path / "new", out.parent / "scenes", EPISODES)
    good = [Adoption("collect", out / "demos"), Adoption("collect/train_diverse", out / "demos_train_diverse"),
            Adoption("nue", out / "runs" / "nue")]
    with pytest.raises(DataError, match=r"other settings than run nue@s1 .*seed 0 -> 1817441348"):
        adopt(quick, new, [*good[:2], Adoption("nue@s1", out / "runs" / "nue")])
    with pytest.raises(DataError, match="holds collection .* but stage collect of recipe 'quick' makes"):
        adopt(quick, new, [Adoption("collect", out / "demos_train_diverse")])
    with pytest.raises(ConfigError, match="no stage or training run 'vgm'"):
        adopt(quick, new, [Adoption("vgm", out / "runs" / "nue")])
    assert not (tmp_path / "new").exists()  # nothing moved

    lines = adopt(quick, new, good)
    assert [line.split(":")[0] for line in lines] == ["adopt collect", "adopt collect/train_diverse", "adopt nue"]
    assert os.path.samefile(new.run("nue") / "last.pt", out / "runs" / "nue" / "last.pt")  # linked, not copied
    one = next((out / "demos").rglob("*.nue"))
    assert os.path.samefile(new.demos / one.relative_to(out / "demos"), one)
    assert "exists, kept" in adopt(quick, new, good[2:])[0]
    left = {s.stage: s for s in remaining_estimate(quick, new)}
    assert "1 trained earlier" in left["train"].detail
    for stage in ("collect", "collect/train_diverse"):  # every episode there: nothing left to collect
        assert left[stage].seconds == 0 and "3 of 3 episodes collected" in left[stage].detail, left[stage]

    episodes = {k: v for k, v in _stamps(new.demos).items() if k.endswith(".nue")}
    collect(new.demos, collect_configs(quick)[0], new.scenes_root, progress=False)
    assert {k: v for k, v in _stamps(new.demos).items() if k.endswith(".nue")} == episodes and episodes
    res = train(train_config(quick, "nue", new), resume=True, progress=False, select=select_run)
    assert res.steps_this_call == 0
    assert (new.run("nue") / "best.pt").read_bytes() == (out / "runs" / "nue" / "best.pt").read_bytes()

    capsys.readouterr()
    for bad in (["--adopt", "nue"], ["--adopt", "nue=x", "--estimate"]):
        code, _ = _nue("reproduce", "--quick", "--out", tmp_path / "cli", *bad)
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(err) == 1 and "--adopt" in err[0], err
