"""The training stage of ``nue reproduce``: one job per training run of the recipe (every seed of every model,
:meth:`nue.recipe.Recipe.training_runs`), each ``nue train --resume`` into ``OUT/runs/<run>`` with closed-loop
selection (and DAgger rounds if the recipe has them), side by side on worker processes or Ray tasks.

A model's seeds differ in the training seed only (``TrainConfig.seed``, :func:`nue.recipe.training_seed`) and in
their run folder: the same demonstrations, budget, selection episodes and everything else of the recipe.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

from nue.errors import ConfigError
from nue.jobs import Job, run_jobs
from nue.nerf.config import get_memory
from nue.policy.config import MODEL_PRESETS, get_model_config
from nue.recipe import Recipe
from nue.reproduce_marker import StageSummary, TrainRunSummary
from nue.selection import select_run
from nue.train.bc import TrainConfig, train
from nue.train.collect import CollectConfig
from nue.train.dagger import DaggerConfig, run_dagger

if TYPE_CHECKING:
    from nue.reproduce_marker import RunFolders


@dataclass(frozen=True)
class TrainJob:
    """One training run, as it travels to a worker."""

    train: TrainConfig
    """Behaviour cloning (round 0 with DAgger)."""
    collect: CollectConfig
    """The demonstrations' collection (DAgger re-collects its episodes with the policy driving)."""
    dagger: DaggerConfig | None
    """DAgger schedule, or None for plain behaviour cloning."""
    scenes_root: str
    """Where the training houses are."""
    progress: bool
    """Show the training progress bar (single process only)."""


def collection_model(recipe: Recipe) -> str:
    """The model preset whose input layout a recipe's demonstrations store: its first model that reads the memory's
    maps at the memory preset's size (``nue`` for ``fast``, ``nue_gru_lean`` in v10), else the first preset that does
    (a recipe of baselines only); every map-reading model of a recipe reads the same layout."""
    memory = get_memory(recipe.memory)
    size = (memory.map_height, memory.map_width)
    for name in (*recipe.models, *MODEL_PRESETS):
        cfg = get_model_config(name)
        if cfg.uses_memory_maps and tuple(cfg.map_size) == size:
            return name
    raise ConfigError("recipe", f"no model preset reads the {recipe.memory!r} memory's {size} maps")


def collect_configs(recipe: Recipe, device: str = "cpu") -> tuple[CollectConfig, ...]:
    """The demonstrations of a recipe (shared by all its training runs), one collection per training split
    (:meth:`~nue.recipe.Recipe.collections`, ``train_split``'s first), in the layout of :func:`collection_model`."""
    return tuple(CollectConfig(task=recipe.task, memory=recipe.memory, model=collection_model(recipe), split=c.split,
                               houses=c.houses, episodes_per_bin=c.episodes_per_bin, heldout_per_bin=c.heldout_per_bin,
                               seed=recipe.seed, device=device, expert=recipe.expert, noise=recipe.noise)
                 for c in recipe.collections())


def collect_config(recipe: Recipe, device: str = "cpu") -> CollectConfig:
    """The ``train_split`` collection of a recipe (the one DAgger rounds revisit)."""
    return collect_configs(recipe, device)[0]


def train_config(recipe: Recipe, run: str, folders: "RunFolders", device: str = "cpu", compile: bool = False) -> TrainConfig:
    """``nue train`` of one training run under a recipe (budget, batch, precision, map dropout, selection): ``run`` is
    a model (its seed 0) or one of its seeds (``nue@s1``, :meth:`~nue.recipe.Recipe.training_run`), which sets the
    run folder and the training seed. NRNS's distance network has no actions to run in closed loop: it is always
    selected by held-out distance error (``select="accuracy"``); ``compile`` is how it runs (``nue train --compile``), not part of the recipe."""
    r = recipe.training_run(run)
    model = r.model
    cfg = get_model_config(model)
    return TrainConfig(
        data=",".join(str(folders.demos_of(c.split, i == 0)) for i, c in enumerate(recipe.collections())),
        out=str(folders.run(r.name)), model=model, steps=recipe.train_steps(model),
        batch_size=recipe.batch_for(model), seq_len=recipe.seq_len, lr=recipe.lr, warmup=recipe.warmup,
        time_budget_s=60 * recipe.train_minutes, budget_clock=recipe.budget_clock, eval_every=recipe.step_plan(model).eval_every, seed=r.seed,
        device=device, precision=recipe.precision, compile=compile, map_dropout=recipe.map_dropout if cfg.uses_memory_maps else 0.0,
        select="accuracy" if cfg.kind == "nrns" else recipe.select, select_episodes=str(folders.episodes_root / recipe.select_set),
        select_candidates=recipe.select_candidates, select_scenes_root=str(folders.scenes_root))


def train_model(job: Job) -> TrainRunSummary:
    """Worker: one training run (resuming its run folder); its best checkpoint, steps, model and training seed. One
    torch thread, as every job of ``run_jobs``."""
    p: TrainJob = job.payload
    t0 = time.perf_counter()
    if p.dagger is None:
        res = train(p.train, resume=True, progress=p.progress, select=select_run)
        return TrainRunSummary(best=str(res.best), steps=res.step, train_seconds=res.elapsed_s, model=p.train.model,
                               seed=p.train.seed, seconds=time.perf_counter() - t0)
    rounds = run_dagger(p.train, p.collect, p.dagger, p.scenes_root, workers=1, progress=p.progress, select=select_run)
    return TrainRunSummary(best=str(rounds[-1].best), rounds=rounds, model=p.train.model, seed=p.train.seed,
                           seconds=time.perf_counter() - t0)


def run_training(recipe: Recipe, folders: "RunFolders", stages: list[str], workers: int, ray_address, device, progress,
                 finish: Callable[[str, float, StageSummary], None], compile: bool = False) -> None:
    """The training runs of ``stages`` (``train/<run>``) side by side on ``workers`` processes (or Ray tasks), one
    torch thread each; ``finish(stage, seconds, summary)`` as each ends."""
    dagger = None
    if recipe.dagger_rounds:
        dagger = DaggerConfig(rounds=recipe.dagger_rounds, beta0=recipe.dagger_beta, steps_per_round=recipe.dagger_steps,
                              episodes_per_bin=recipe.dagger_episodes_per_bin, round_budget_s=60 * recipe.train_minutes)
    single = workers <= 1 and not ray_address
    jobs = [Job(stage, TrainJob(train_config(recipe, stage.removeprefix("train/"), folders, device, compile),
                                collect_config(recipe, device), dagger, str(folders.scenes_root), progress and single))
            for stage in stages]

    def on_result(job: Job, result: TrainRunSummary) -> None:
        finish(job.key, result.seconds, result)

    run_jobs(jobs, train_model, on_result, workers=workers, ray_address=ray_address, desc="train", progress=progress)
