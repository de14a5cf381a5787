"""``nue reproduce --adopt NAME=FOLDER``: work made outside a run — a demonstration collection, a training run — put
into the run folder when it is exactly what the run's own stage would make, so the stage resumes it instead of
making it again.

``NAME`` is ``collect`` or ``collect/<split>`` (a collection stage) or a training run of the recipe (``nue``,
``nue@s1``). A collection is adopted when its manifest is the one the stage plans (task, memory, layout, houses and
their content, episodes per bin, seed, expert, noise); a training run when every setting stored in its ``last.pt``
that changes what is trained equals the stage's (:func:`nue.policy.checkpoint.resume_mismatches`, the check of
``nue train --resume``) and its data are the run's collections (their manifest hashes). Anything else is refused
before a stage starts (:class:`~nue.errors.DataError`, one line). Checkpoints and episode files are hard-linked
where the file system allows (they are only ever replaced, never written in place), everything else is copied; the source is
left as it was, and a source another process is writing is refused. The adopted stage then runs as on a resume: a finished collection writes nothing, a finished
training run repeats only its closed-loop selection, whose records it already holds.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import torch

from nue.errors import ConfigError, DataError
from nue.output_lock import hold_output
from nue.policy.checkpoint import load_checkpoint, resume_mismatches
from nue.recipe import Recipe
from nue.reproduce_marker import RunFolders
from nue.reproduce_train import collect_configs, train_config
from nue.train.collect import plan_collection
from nue.train.hardware import resolve_precision
from nue.train.manifest import manifest_path, read_manifest


@dataclass(frozen=True)
class Adoption:
    """One ``--adopt NAME=FOLDER``."""

    name: str
    """``collect``, ``collect/<split>`` or a training run (``nue``, ``nue@s1``)."""
    source: Path
    """The folder made outside the run."""

    @classmethod
    def parse(cls, spec: str) -> Adoption:
        name, sep, folder = spec.partition("=")
        if not sep or not name or not folder:
            raise ConfigError("--adopt", f"{spec!r} is not NAME=FOLDER (e.g. nue@s1=runs/my_nue_s1)")
        return cls(name.strip(), Path(folder.strip()))


def collection_index(recipe: Recipe, name: str) -> int:
    """Which of ``recipe.collections()`` the stage ``name`` (``collect``, ``collect/<split>``) makes."""
    splits = [c.split for c in recipe.collections()]
    if name == "collect":
        return 0
    split = name.removeprefix("collect/")
    if not name.startswith("collect/") or split not in splits[1:]:
        raise ConfigError("--adopt", f"recipe {recipe.name!r} has no stage {name!r} (its collections: "
                                     f"{', '.join(['collect'] + [f'collect/{s}' for s in splits[1:]])})")
    return splits.index(split)


def planned_manifests(recipe: Recipe, folders: RunFolders, device: str = "cpu") -> list[str]:
    """The manifest hash of each collection the recipe's stages make, in order (the first is ``train_split``'s)."""
    return [plan_collection(cfg, folders.scenes_root)[1].hash() for cfg in collect_configs(recipe, device)]


def check_adoption(recipe: Recipe, folders: RunFolders, a: Adoption, device: str = "cpu") -> Path:
    """Where ``a`` goes in the run folder, after checking it is what the stage would make (else DataError)."""
    if not a.source.is_dir():
        raise DataError(a.source, "not a folder (--adopt NAME=FOLDER)")
    if a.name == "collect" or a.name.startswith("collect/"):
        k = collection_index(recipe, a.name)
        want = planned_manifests(recipe, folders, device)[k]
        have = read_manifest(a.source).hash()
        if have != want:
            raise DataError(manifest_path(a.source), f"holds collection {have}, but stage {a.name} of recipe "
                                                     f"{recipe.name!r} makes {want}; not adopted")
        return folders.demos_of(recipe.collections()[k].split, k == 0)
    runs = [r.name for r in recipe.training_runs()]
    if a.name not in runs:
        raise ConfigError("--adopt", f"recipe {recipe.name!r} has no stage or training run {a.name!r} "
                                     f"(its runs: {', '.join(runs)})")
    last = a.source / "last.pt"
    if not last.is_file():
        raise DataError(last, "missing: not a training run folder")
    stored = load_checkpoint(last)
    cfg = train_config(recipe, a.name, folders, device)
    hashes = planned_manifests(recipe, folders, device)
    now = {"train_config": {**dataclasses.asdict(cfg),
                            "precision_resolved": resolve_precision(cfg.precision, torch.device(device))},
           "manifest_hash": hashes[0], "data": {"manifests": hashes}}
    changed = resume_mismatches(stored, now)
    if changed:
        raise DataError(last, f"was trained with other settings than run {a.name} of recipe {recipe.name!r} "
                              f"({'; '.join(changed)}); not adopted")
    return folders.run(a.name)


LINKED = (".pt", ".nue")
"""Files hard-linked rather than copied: checkpoints and episode files, which are only ever replaced (written to a
temporary file and renamed), so a later write in either folder never reaches the other."""


def _link_tree(source: Path, target: Path) -> None:
    """``target`` as a copy of ``source``: :data:`LINKED` files hard-linked when possible, other files copied."""
    tmp = target.with_name(target.name + ".adopting")
    if tmp.exists():
        shutil.rmtree(tmp)

    def put(src: str, dst: str) -> None:
        if src.endswith(LINKED):
            try:
                os.link(src, dst)
                return
            except OSError:
                pass
        shutil.copy2(src, dst)

    shutil.copytree(source, tmp, copy_function=put, ignore=shutil.ignore_patterns(".*.lock"))
    tmp.rename(target)  # a half-copied folder is never taken for an adopted one


def adopt(recipe: Recipe, folders: RunFolders, adoptions: list[Adoption], device: str = "cpu") -> list[str]:
    """Check every adoption, then put each into the run folder (one that is already there is kept); returns a line
    per adoption saying what happened. Nothing is moved unless all of them pass."""
    targets = [(a, check_adoption(recipe, folders, a, device)) for a in adoptions]
    lines = []
    for a, target in targets:
        if target.exists():
            lines.append(f"adopt {a.name}: {target} exists, kept (a stage resumes what it holds)")
            continue
        target.parent.mkdir(parents=True, exist_ok=True)
        with hold_output(a.source):  # not a folder another process is still writing (OutputInUseError at once)
            _link_tree(a.source, target)
        lines.append(f"adopt {a.name}: {a.source} -> {target}")
    return lines


def _last(folders: RunFolders, name: str) -> dict | None:
    """A training run's ``last.pt`` (memory-mapped: only its counters are read), or None."""
    last = folders.run(name) / "last.pt"
    return torch.load(last, map_location="cpu", weights_only=False, mmap=True) if last.is_file() else None


def trained_shares(recipe: Recipe, folders: RunFolders, runs: list[str]) -> dict[str, float]:
    """The share of its training each of ``runs`` has done: its folder's ``last.pt`` step over the recipe's steps
    (the trainer's clock over the budget for a time budget); runs without a ``last.pt`` are left out."""
    out = {}
    for name in runs:
        ck = _last(folders, name)
        if ck is not None:
            out[name] = (float(ck.get("elapsed_s", 0.0)) / (60 * recipe.train_minutes) if recipe.train_minutes > 0
                         else ck.get("step", 0) / recipe.train_steps(recipe.training_run(name).model))
    return out


def finished_runs(recipe: Recipe, folders: RunFolders, runs: list[str]) -> set[str]:
    """Those of ``runs`` whose folder holds a ``last.pt`` at the recipe's final step (adopted, or killed after
    training): their stage costs a resumed selection, not a training."""
    out = set()
    for name in runs:
        ck = _last(folders, name)
        if ck is not None and ck.get("step", 0) >= recipe.train_steps(recipe.training_run(name).model):
            out.add(name)
    return out
