"""DAgger (beyond the paper): roll out the current policy (mixed with the expert's actions with
probability beta), label every visited state with the expert's action, aggregate, retrain.

Round 0 is behaviour cloning on the expert's demonstrations (or a given checkpoint: ``start_from``).
Round r >= 1 collects the training episodes again (all, or the first k per bin) with
beta = beta0 ** r (the NeRF memory online, with the collection's own memory config), caps policy
control at ``max_factor`` x the expert's step count for the episode (then the expert finishes it),
and continues training from the previous round's weights on all data so far. With a time budget
per round, the rollouts count against it: retraining gets what the collection left, so DAgger and
plain behaviour cloning can be compared at equal compute. Each round's collection and run folder
are resumable like ``nue collect`` and ``nue train``. ``nue dagger`` runs it.
"""

from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass
from pathlib import Path

from nue.errors import DataError
from nue.output_lock import hold_output
from nue.train.bc import Selector, TrainConfig, TrainResult, train
from nue.train.collect import CollectConfig, CollectSummary, collect
from nue.train.collect_job import AgentSpec
from nue.policy.config import MODEL_PRESETS, get_model_config
from nue.sim.task import get_task
from nue.train.manifest import CollectionManifest, DataLayout


@dataclass(frozen=True)
class DaggerConfig:
    """DAgger schedule."""

    rounds: int = 2
    """DAgger rounds after the behaviour-cloning round 0."""
    beta0: float = 0.5
    """Expert-action probability of round 1; round r uses its r-th power (beta0 ** r)."""
    max_factor: float = 3.0
    """Policy control stops at this multiple of the expert's step count; the expert finishes."""
    steps_per_round: int = 1000
    """Optimiser steps of each retraining round."""
    episodes_per_bin: int = 0
    """Roll out only the first k training episodes per bin per house in each round (0 = all of them)."""
    round_budget_s: float = 0.0
    """Wall-clock budget of each round r >= 1, rollouts included; retraining stops when it is spent
    (0 = no limit: ``steps_per_round`` steps)."""
    start_from: str = ""
    """Skip round 0 and start from this checkpoint (e.g. a finished behaviour-cloning run)."""


@dataclass(frozen=True)
class DaggerRound:
    """One round of :func:`run_dagger`: its best checkpoint and what it trained on; ``dagger.json`` (and a reproduce
    training stage's ``rounds``) holds the rounds' :meth:`to_dict`."""

    round: int
    """0 = behaviour cloning (or the given start), r >= 1 = DAgger round r."""
    best: Path
    """The round's best checkpoint (the given one for a round 0 started from a checkpoint)."""
    data: str
    """The collection folders it trained on, comma-separated (the expert's first, then each round's rollouts)."""
    seconds: float
    """Wall time of the round (rollouts included)."""
    given: bool = False
    """Round 0 was not trained: ``DaggerConfig.start_from`` gave its checkpoint."""
    beta: float | None = None
    """Rounds >= 1: probability that the expert's action is executed instead of the policy's."""
    collected: CollectSummary | None = None
    """Rounds >= 1: the collection of the round's rollouts."""
    rollout_seconds: float | None = None
    """Rounds >= 1: wall time of the rollouts (the first run's, kept across a resume)."""
    train_steps: int | None = None
    """Rounds >= 1: optimiser steps of the round's run, in total."""

    def to_dict(self) -> dict:
        """The JSON form: round 0 without the DAgger entries (``given`` only when true)."""
        if self.round == 0:
            d: dict = {"round": 0, "best": str(self.best), "data": self.data, "seconds": self.seconds}
            return {**d, "given": True} if self.given else d
        return {"round": self.round, "beta": self.beta, "best": str(self.best), "data": self.data,
                "collected": self.collected.to_dict() if self.collected is not None else None,
                "rollout_seconds": self.rollout_seconds, "train_steps": self.train_steps, "seconds": self.seconds}

    @classmethod
    def from_dict(cls, d: dict) -> "DaggerRound":
        """The round of its JSON form."""
        collected = d.get("collected")
        return cls(round=d["round"], best=Path(d["best"]), data=d["data"], seconds=d["seconds"],
                   given=bool(d.get("given", False)), beta=d.get("beta"),
                   collected=CollectSummary.from_dict(collected) if collected is not None else None,
                   rollout_seconds=d.get("rollout_seconds"), train_steps=d.get("train_steps"))


def run_dagger(train_cfg: TrainConfig, collect_cfg: CollectConfig, dagger: DaggerConfig, scenes_root,
               workers: int = 1, ray_address: str | None = None, progress: bool = True,
               select: Selector | None = None) -> list[DaggerRound]:
    """Run behaviour cloning then ``dagger.rounds`` DAgger rounds; returns each round's :class:`DaggerRound`. The run
    folder is held by this process meanwhile (:func:`~nue.output_lock.hold_output`). ``select``: each round's
    closed-loop selection, as :func:`~nue.train.bc.train` takes it."""
    with hold_output(train_cfg.out):
        return _run_dagger(train_cfg, collect_cfg, dagger, scenes_root, workers, ray_address, progress, select)


def _run_dagger(train_cfg: TrainConfig, collect_cfg: CollectConfig, dagger: DaggerConfig, scenes_root, workers: int,
                ray_address: str | None, progress: bool, select: Selector | None) -> list[DaggerRound]:
    out = Path(train_cfg.out)
    expert_data = train_cfg.data.split(",")[0]
    t0 = time.perf_counter()
    if dagger.start_from:
        best = Path(dagger.start_from)
        rounds = [DaggerRound(0, best, train_cfg.data, 0.0, given=True)]
    else:
        best = train(train_cfg.replace(out=str(out / "round_0")), resume=True, progress=progress,
                     select=select).best
        rounds = [DaggerRound(0, best, train_cfg.data, time.perf_counter() - t0)]
    roots = [train_cfg.data]
    for r in range(1, dagger.rounds + 1):
        t0 = time.perf_counter()
        beta = dagger.beta0**r
        agent = AgentSpec.dagger(best, beta, expert_steps_from=expert_data, max_factor=dagger.max_factor)
        data_dir = out / f"data_r{r}"
        summary = collect(data_dir, dataclasses.replace(collect_cfg, agent=agent, heldout_per_bin=0,
                                                        subsample_per_bin=dagger.episodes_per_bin),
                          scenes_root, workers=workers, ray_address=ray_address, progress=progress)
        timing = out / f"round_{r}_rollout.json"  # the first run's rollout time survives a resume
        if not timing.is_file():
            timing.write_text(json.dumps({"rollout_seconds": time.perf_counter() - t0}) + "\n")
        rollout_s = json.loads(timing.read_text())["rollout_seconds"]
        roots.append(str(data_dir))
        budget = max(dagger.round_budget_s - rollout_s, 1.0) if dagger.round_budget_s > 0 else train_cfg.time_budget_s
        res: TrainResult = train(train_cfg.replace(data=",".join(roots), out=str(out / f"round_{r}"),
                                                   init_from=str(best), steps=dagger.steps_per_round, warmup=0,
                                                   time_budget_s=budget), resume=True, progress=progress,
                                 select=select)
        best = res.best
        rounds.append(DaggerRound(r, best, ",".join(roots), time.perf_counter() - t0, beta=beta, collected=summary,
                                  rollout_seconds=rollout_s, train_steps=res.step))
    return rounds


def layout_model(manifest: CollectionManifest, preferred: str, where="manifest.json") -> str:
    """The model preset whose input layout a collection stores (``CollectConfig.model`` of its rollouts): ``preferred``
    (the model DAgger trains) when it reads that layout, else the first preset that reads the collection's maps
    (``nue_lean`` for a ``lean`` collection), so a policy that reads no maps can be rolled out on any collection."""
    task = get_task(manifest.task)
    if DataLayout.of(get_model_config(preferred).for_task(task)) == manifest.model_layout:
        return preferred
    for name, cfg in MODEL_PRESETS.items():
        if cfg.uses_memory_maps and DataLayout.of(cfg.for_task(task)) == manifest.model_layout:
            return name
    raise DataError(where, f"no model preset reads this collection's layout {manifest.model_layout.to_dict()}")


def collect_config_from_manifest(manifest: CollectionManifest, scene_dirs=(), device: str = "cpu",
                                 where="manifest.json", model: str = "nue") -> CollectConfig:
    """The collection config that reproduces an expert collection's training episodes, in the collection's layout
    (:func:`layout_model`, preferring ``model``; ``where`` names the manifest in errors)."""
    houses: tuple[int, ...] = ()
    if not scene_dirs:
        prefix = f"{manifest.split}_"
        if not all(n.startswith(prefix) and n[len(prefix):].isdigit() for n in manifest.scenes):
            raise DataError(where, "scenes are not generated houses: pass their folders with --scene")
        houses = tuple(int(n[len(prefix):]) for n in manifest.scenes)
    return CollectConfig(task=manifest.task, memory=manifest.memory, split=manifest.split,
                         model=layout_model(manifest, model, where),
                         houses=houses, scene_dirs=tuple(str(d) for d in scene_dirs),
                         episodes_per_bin=manifest.episodes_per_bin, heldout_per_bin=0, seed=manifest.seed,
                         device=device, expert=manifest.expert, noise=manifest.noise)
