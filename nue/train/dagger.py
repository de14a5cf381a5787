"""DAgger (beyond the paper): roll out the current policy (mixed with the expert's actions with
probability beta), label every visited state with the expert's action, aggregate, retrain.

Round 0 is behaviour cloning on the expert's demonstrations. Round r >= 1 collects the training
episodes again with beta = beta0 ** r (the NeRF memory online, as always), caps policy control at
``max_factor`` x the expert's step count for the episode (then the expert finishes it), and
continues training from the previous round's weights on all data so far. Each round's collection
and run folder are resumable like ``nue collect`` and ``nue train``.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

from nue.train.bc import TrainConfig, TrainResult, train
from nue.train.collect import CollectConfig, collect


@dataclass(frozen=True)
class DaggerConfig:
    """DAgger schedule."""

    rounds: int = 2
    """DAgger rounds after the behaviour-cloning round 0."""
    beta0: float = 0.5
    """Expert-action probability in round r is beta0 ** r."""
    max_factor: float = 3.0
    """Policy control stops at this multiple of the expert's step count; the expert finishes."""
    steps_per_round: int = 1000
    """Optimiser steps of each retraining round."""


def run_dagger(train_cfg: TrainConfig, collect_cfg: CollectConfig, dagger: DaggerConfig, scenes_root,
               workers: int = 1, ray_address: str | None = None, progress: bool = True) -> list[dict]:
    """Run behaviour cloning then ``dagger.rounds`` DAgger rounds; returns one summary dict per round."""
    out = Path(train_cfg.out)
    expert_data = train_cfg.data.split(",")[0]
    t0 = time.perf_counter()
    res: TrainResult = train(train_cfg.replace(out=str(out / "round_0")), resume=True, progress=progress)
    rounds = [{"round": 0, "best": str(res.best), "data": train_cfg.data, "seconds": time.perf_counter() - t0}]
    roots = [train_cfg.data]
    for r in range(1, dagger.rounds + 1):
        t0 = time.perf_counter()
        beta = dagger.beta0**r
        agent = (("kind", "dagger"), ("checkpoint", str(res.best)), ("beta", beta),
                 ("expert_steps_from", expert_data), ("max_factor", dagger.max_factor))
        data_dir = Path(expert_data).parent / f"{Path(expert_data).name}_dagger_r{r}"
        summary = collect(data_dir, dataclasses.replace(collect_cfg, agent=agent, heldout_per_bin=0), scenes_root,
                          workers=workers, ray_address=ray_address, progress=progress)
        roots.append(str(data_dir))
        res = train(train_cfg.replace(data=",".join(roots), out=str(out / f"round_{r}"), init_from=str(res.best),
                                      steps=dagger.steps_per_round, warmup=0), resume=True, progress=progress)
        rounds.append({"round": r, "beta": beta, "best": str(res.best), "data": ",".join(roots),
                       "collected": summary, "seconds": time.perf_counter() - t0})
    return rounds


def collect_config_from_manifest(manifest: dict, scene_dirs=(), device: str = "cpu") -> CollectConfig:
    """The collection config that reproduces an expert collection's training episodes."""
    names = list(manifest["scenes"])
    houses: tuple[int, ...] = ()
    if not scene_dirs:
        prefix = f"{manifest['split']}_"
        if not all(n.startswith(prefix) and n[len(prefix):].isdigit() for n in names):
            from nue.errors import DataError

            raise DataError("manifest.json", "scenes are not generated houses: pass their folders with --scene")
        houses = tuple(int(n[len(prefix):]) for n in names)
    return CollectConfig(task=manifest["task"], memory=manifest["memory"]["name"], split=manifest["split"],
                         houses=houses, scene_dirs=tuple(str(d) for d in scene_dirs),
                         episodes_per_bin=manifest["episodes_per_bin"], heldout_per_bin=0, seed=manifest["seed"],
                         device=device)
