"""Closed-loop model selection: pick the checkpoint that navigates best, not the one that imitates best.

Held-out action accuracy does not track closed-loop success here (a policy can predict the expert's
next action well by copying its own history through the memory maps and still drive into walls), so
``nue train --select closed_loop`` keeps a snapshot at every evaluation and, after training, runs the
last ``candidates`` of them through the shared agent loop on a fixed set of episodes in the
*training* houses (``episodes/select``: one episode per training house, easy / medium / hard in turn —
21 episodes, 7 per bin — generated with seed 31337, disjoint from the demonstrations' seeds; never the
14 validation houses), with a 400-step limit. The winner — highest SR, then SPL, then
fewer collisions per episode, then the later step — is copied to ``best.pt``. The records are kept in
``selection.jsonl`` (resumable like ``nue eval``) and the table in ``selection.json``.

Selection runs episodes through :mod:`nue.evaluate.runner`, so it sits above both training and evaluation:
:func:`nue.train.bc.train` calls it through the selector it is given (:func:`select_run`), ``nue select`` directly.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from nue.errors import DataError
from nue.evaluate.metrics import summarize
from nue.evaluate.runner import EvalConfig, run_eval
from nue.output_lock import hold_output
from nue.sim.record import EpisodeRecord
from nue.train.bc import TrainConfig


@dataclass(frozen=True)
class SelectConfig:
    """Closed-loop selection of a run's snapshots."""

    episodes_dir: str = "episodes/select"
    """Episode files of training houses (``train_<NN>.json``)."""
    scenes_root: str = "data/scenes"
    """Where the houses are (generated from their fixed seeds if missing)."""
    candidates: int = 3
    """How many of the last snapshots compete."""
    workers: int = 1
    """Worker processes of the closed-loop runs."""
    max_episodes: int = 0
    """Use only the first N episodes of each house (0 = all)."""
    max_steps: int = 400
    """Step limit of the selection runs (below the task's 800: a candidate that needs more is not the one to
    pick, and a stuck policy costs half as much); 0 = the task's own."""
    device: str = "cpu"
    """Device of policy and memory."""


@dataclass(frozen=True)
class CandidateScore:
    """Closed-loop result of one snapshot on the selection episodes."""

    name: str
    path: str
    step: int
    n: int
    sr: float
    spl: float
    collisions: float

    def key(self) -> tuple:
        """Sort key: higher SR, then SPL, then fewer collisions, then the later step."""
        return (self.sr, self.spl, -self.collisions, self.step)


def pick_best(records: dict[str, list[EpisodeRecord]], paths: dict[str, str], steps: dict[str, int]) -> list[CandidateScore]:
    """Score each candidate's records; returned best first. Candidates must have run the same episodes."""
    episodes = {name: {(r.scene, r.episode_id) for r in recs} for name, recs in records.items()}
    first = next(iter(episodes.values()), set())
    for name, eps in episodes.items():
        if eps != first:
            raise DataError(None, f"selection: candidate {name} ran other episodes than the rest")
    scores = []
    for name, recs in records.items():
        s = summarize(recs)
        scores.append(CandidateScore(name, paths[name], steps[name], s.n, s.sr, s.spl, s.collisions))
    return sorted(scores, key=CandidateScore.key, reverse=True)


def snapshots(run_dir: Path) -> list[Path]:
    """The run's snapshots (``snapshots/step_NNNNNN.pt``), oldest first."""
    return sorted((Path(run_dir) / "snapshots").glob("step_*.pt"))


def select_checkpoint(run_dir, cfg: SelectConfig = SelectConfig(), progress: bool = True) -> list[CandidateScore]:
    """Run the last ``cfg.candidates`` snapshots of ``run_dir`` in closed loop, copy the best to ``best.pt``;
    the run folder is held by this process meanwhile (:func:`~nue.output_lock.hold_output`)."""
    with hold_output(run_dir):
        return _select(Path(run_dir), cfg, progress)


def select_run(run_dir, cfg: TrainConfig, progress: bool = True) -> list[CandidateScore]:
    """Closed-loop selection of a training run with the ``select_*`` settings of its config (the
    :data:`~nue.train.bc.Selector` that :func:`nue.train.bc.train` and DAgger rounds are given)."""
    return select_checkpoint(run_dir, SelectConfig(episodes_dir=cfg.select_episodes, scenes_root=cfg.select_scenes_root,
                                                   candidates=cfg.select_candidates, workers=cfg.select_workers,
                                                   device=cfg.device), progress=progress)


def _select(run_dir: Path, cfg: SelectConfig, progress: bool) -> list[CandidateScore]:
    cands = snapshots(run_dir)[-max(cfg.candidates, 1):]
    if not cands:
        raise DataError(run_dir / "snapshots", "no snapshots to select from (train with --select closed_loop)")
    names = {p.stem: str(p) for p in cands}
    steps = {p.stem: int(p.stem.split("_")[1]) for p in cands}
    out = run_dir / "selection.jsonl"
    t0 = time.perf_counter()
    ecfg = EvalConfig(episodes_dir=cfg.episodes_dir, scenes_root=cfg.scenes_root, split="train", coverage=False,
                      max_episodes=cfg.max_episodes, max_steps=cfg.max_steps, device=cfg.device)
    run_eval([f"{n}={p}" for n, p in names.items()], out, ecfg, workers=cfg.workers, progress=progress)
    records: dict[str, list[EpisodeRecord]] = {n: [] for n in names}
    for line in out.read_text().splitlines():
        if line.strip():
            rec = EpisodeRecord.from_dict(json.loads(line))
            if rec.method in records:
                records[rec.method].append(rec)
    ranked = pick_best(records, names, steps)
    _copy_atomic(Path(ranked[0].path), run_dir / "best.pt")
    summary = {"selected": ranked[0].name, "seconds": time.perf_counter() - t0, "config": asdict(cfg),
               "candidates": [asdict(c) for c in ranked]}
    (run_dir / "selection.json").write_text(json.dumps(summary, indent=1) + "\n")
    return ranked


def _copy_atomic(src: Path, dst: Path) -> None:
    fd, tmp = tempfile.mkstemp(dir=dst.parent, prefix=f".{dst.name}.", suffix=".tmp")
    os.close(fd)
    try:
        shutil.copyfile(src, tmp)
        os.replace(tmp, dst)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
