"""The evaluation stages of ``nue reproduce`` and the records they leave for the report: ``eval/<set>`` (every training
run and expert on a set), ``eval/<set>+swap`` and ``eval/<set>+sling`` (the extra rows, :data:`EXTRA_ROWS`), and
``explore/<set>`` (the exploration benchmark from a set's starts, :mod:`nue.evaluate.exploration`). Each calls the
library function of its command (``nue eval``, ``nue explore``) on the run's best checkpoints, resumes from its records
file, and returns its :class:`~nue.reproduce_marker.EvalStageSummary`.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Callable, Sequence

from nue.errors import DataError
from nue.evaluate.exploration import ExploreConfig, run_explore
from nue.evaluate.report import load_records
from nue.evaluate.runner import EvalConfig, episode_files, run_eval
from nue.policy.last_mile import SLING_PREFIX
from nue.recipe import Recipe
from nue.reproduce_marker import EvalStageSummary, RunFolders, stage_done
from nue.sim.episode_sets import get_episode_set

EXTRA_ROWS: dict[str, Callable[[Recipe], tuple[str, ...]]] = {
    "swap": lambda r: r.swap_maps,
    "sling": lambda r: r.last_mile,
}
"""Evaluation stages after ``eval/<set>``, by suffix: the models (every seed) each runs."""

EXPLORE_REFERENCES: tuple[str, ...] = ("expert-explore", "random")
"""Rows the exploration benchmark runs beside the recipe's ``explore_models``."""


def episodes_dir(folders: RunFolders, set_name: str, houses: Sequence[int] = (), copy: str = "") -> Path:
    """A set's episode folder: the committed one, or (``houses`` given) a copy of those houses' files in the run
    folder, ``OUT/episodes/<copy or set>``."""
    source = folders.episodes_root / set_name
    if not houses:
        return source
    spec = get_episode_set(set_name)
    target = folders.out / "episodes" / (copy or set_name)
    target.mkdir(parents=True, exist_ok=True)
    for i in houses:
        name = f"{spec.split}_{i:02d}.json"
        if not (target / name).is_file() or (target / name).read_bytes() != (source / name).read_bytes():
            shutil.copyfile(source / name, target / name)
    return target


def eval_episodes_dir(recipe: Recipe, folders: RunFolders, set_name: str) -> Path:
    """A set's evaluation episodes: the committed folder, or a copy of the recipe's ``eval_houses`` of it."""
    return episodes_dir(folders, set_name, recipe.eval_houses)


def run_methods(recipe: Recipe, folders: RunFolders, models) -> list[str]:
    """``<run>=<best checkpoint>`` of every training run (every seed) of ``models``."""
    out = []
    for r in recipe.training_runs(models):
        marker = stage_done(folders, f"train/{r.name}")
        if marker is None:
            raise DataError(folders.marker(f"train/{r.name}"), f"training run {r.name} has not finished in this run")
        out.append(f"{r.name}={marker.train_run().best}")
    return out


def run_eval_stage(recipe: Recipe, folders: RunFolders, stage: str, workers, ray_address, device,
                   progress) -> EvalStageSummary:
    """``eval/<set>[+swap|+sling]``: ``nue eval`` of the stage's methods into ``OUT/records/<set>[+...].jsonl``."""
    name = stage.removeprefix("eval/")
    set_name, _, suffix = name.partition("+")
    swap = suffix == "swap"
    spec = get_episode_set(set_name)
    methods = run_methods(recipe, folders, EXTRA_ROWS[suffix](recipe) if suffix else recipe.models)
    if suffix == "sling":
        methods = [f"{SLING_PREFIX}{m}" for m in methods]
    if not suffix:
        methods += list(recipe.experts)
    cfg = EvalConfig(episodes_dir=str(eval_episodes_dir(recipe, folders, set_name)), scenes_root=str(folders.scenes_root),
                     split=spec.split, task=recipe.task, seed=recipe.seed, device=device, swap_maps=swap,
                     max_episodes=recipe.eval_max_episodes, max_steps=recipe.eval_max_steps)
    out = run_eval(methods, folders.records(stage), cfg, workers=workers, ray_address=ray_address, progress=progress)
    return EvalStageSummary(str(out), set_name, methods)


def run_explore_stage(recipe: Recipe, folders: RunFolders, stage: str, workers, ray_address, device,
                      progress) -> EvalStageSummary:
    """``explore/<set>``: ``nue explore`` of every seed of ``explore_models`` and the references from the set's
    starts (``explore_houses``, ``explore_per_bin``) into ``OUT/records/explore/<set>.jsonl``."""
    set_name = stage.removeprefix("explore/")
    methods = run_methods(recipe, folders, recipe.explore_models) + list(EXPLORE_REFERENCES)
    starts = episodes_dir(folders, set_name, recipe.explore_houses, copy=f"explore_{set_name}")
    cfg = ExploreConfig(episodes_dir=str(starts), scenes_root=str(folders.scenes_root),
                        split=get_episode_set(set_name).split, task=recipe.task, seed=recipe.seed, device=device,
                        steps=recipe.explore_steps, per_bin=recipe.explore_per_bin)
    out = run_explore(methods, folders.records(stage), cfg, workers=workers, ray_address=ray_address, progress=progress)
    return EvalStageSummary(str(out), set_name, methods)


# --- records for the report -----------------------------------------------------------------------------
def subset(records, episodes_dir: Path) -> list:
    """The records of the episodes in ``episodes_dir``'s files (the smaller set a larger one extends)."""
    keys = set()
    for f in episode_files(episodes_dir):
        scene = f.name.removesuffix(".json")
        keys |= {(scene, e["episode_id"]) for e in json.loads(f.read_text())["episodes"]}
    return [r for r in records if (r.scene, r.episode_id) in keys]


def report_tables(recipe: Recipe, folders: RunFolders) -> dict[str, list]:
    """Records per reported table: every evaluation set with its swapped-maps and SLING rows, and each smaller
    set a set extends, taken from the larger set's records."""
    tables: dict[str, list] = {}
    for name in recipe.eval_sets:
        recs = load_records(folders.records(f"eval/{name}"))
        spec = get_episode_set(name)
        if spec.extends and (folders.episodes_root / spec.extends).is_dir():
            tables[spec.extends] = subset(recs, folders.episodes_root / spec.extends)
        for suffix, models in EXTRA_ROWS.items():
            if models(recipe):
                recs = recs + load_records(folders.records(f"eval/{name}+{suffix}"))
        tables[name] = recs
    return tables


def explore_records(recipe: Recipe, folders: RunFolders) -> dict[str, list]:
    """The exploration benchmark's records per set of starts (RESULTS.md's exploration sections)."""
    return {name: load_records(folders.records(f"explore/{name}")) for name in recipe.explore_sets}
