"""The fixed evaluation episode sets committed under ``episodes/``, as data, and how each is (re)built.

A set is one episode file per house of a split (``episodes/<set>/<split>_<NN>.json``) made by the
episode generator from fixed seeds, so every method runs the same episodes with the same per-episode
seeds. A set may *extend* a smaller one: each of its files starts with the smaller set's episodes
(same ids, same order), then adds new ones drawn with another seed (:func:`extend_episodes`), so the
small set's records are a subset of the large set's (an evaluation on the large set also gives the
small set's table). ``nue episodes make-set NAME`` rebuilds a set from its spec.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

from nue.errors import ConfigError
from nue.scene.generator import SPLITS, ensure_house
from nue.scene.navgrid import NavGrid
from nue.scene.scene import Scene
from nue.sim.episode_gen import EpisodeGenConfig, extend_episodes, generate_episodes
from nue.sim.episodes import load_episodes, save_episodes
from nue.sim.renderer import Renderer
from nue.sim.task import get_task


@dataclass(frozen=True)
class EpisodeSetSpec:
    """One fixed set of evaluation episodes."""

    name: str
    """Folder name under ``episodes/``."""
    split: str
    """House split whose houses the files cover, one file per house (``<split>_<NN>.json``)."""
    per_bin: int
    """New episodes per difficulty bin per house (on top of those of ``extends``)."""
    seed: int
    """Seed of the episode generator for the new episodes."""
    extends: str = ""
    """Name of a set of the same split whose episodes open every file of this one ('' = none)."""
    task: str = "paper"
    """Task preset whose difficulty bins the episodes fill."""
    description: str = ""
    """What the set is for (shown in reports)."""
    held_out: bool = False
    """Whether the set's houses are a held-out style family (outside every training style; the generalisation
    table of ``nue report --generalisation`` compares models on these sets with the reference set)."""
    houses: tuple[int, ...] = ()
    """Indices of the split's houses the set covers (empty = all of them)."""
    bin_per_house: bool = False
    """Keep one difficulty bin per house, the bins in turn by house index (house ``i`` keeps bin ``i mod 3`` of the
    ``per_bin`` episodes drawn in every bin): the closed-loop selection sets in training houses."""


EPISODE_SETS: dict[str, EpisodeSetSpec] = {
    "val": EpisodeSetSpec("val", "val", per_bin=2, seed=0,
                          description="14 validation houses x 3 difficulties x 2 = 84 episodes (the quick set)"),
    "val252": EpisodeSetSpec("val252", "val", per_bin=4, seed=1, extends="val",
                             description="14 validation houses x 3 difficulties x 6 = 252 episodes; the first 6 of "
                                         "each file are episodes/val"),
    "val_plain": EpisodeSetSpec("val_plain", "val_plain", per_bin=6, seed=0, held_out=True,
                                description="14 houses of the held-out plain scene style x 3 difficulties x 6 = "
                                            "252 episodes"),
    "val_pale": EpisodeSetSpec("val_pale", "val_pale", per_bin=6, seed=0, held_out=True,
                               description="14 houses of the held-out pale family (flat near-white walls, open plan "
                                           "or L hallway; outside the diverse training styles) x 3 difficulties x 6 "
                                           "= 252 episodes"),
    "select": EpisodeSetSpec("select", "train", per_bin=1, seed=31337, bin_per_house=True,
                             description="closed-loop selection (nue.selection): one episode in each of the 21 "
                                         "training houses, easy / medium / hard in turn = 21 episodes"),
    "select_diverse": EpisodeSetSpec("select_diverse", "train_diverse", per_bin=1, seed=31337, bin_per_house=True,
                                     houses=tuple(range(0, 42, 2)),
                                     description="closed-loop selection for models trained on train_diverse: one "
                                                 "episode in every other of its 42 houses (0, 2, ..., 40), the bins "
                                                 "in turn by house index = 21 episodes, 7 per bin"),
}
"""The committed sets (``episodes/<name>/``): evaluation sets in validation houses, and closed-loop selection's sets
in training houses (``bin_per_house``; never an evaluation set of a recipe)."""


def held_out_sets() -> list[str]:
    """Names of the sets whose houses are a held-out style family, in :data:`EPISODE_SETS` order."""
    return [name for name, spec in EPISODE_SETS.items() if spec.held_out]


def get_episode_set(name: str) -> EpisodeSetSpec:
    """A set's spec; unknown name -> ConfigError."""
    try:
        return EPISODE_SETS[name]
    except KeyError:
        raise ConfigError(name, f"unknown episode set; known: {', '.join(EPISODE_SETS)}") from None


def set_houses(name: str) -> tuple[int, ...]:
    """Indices of the houses a set covers."""
    spec = get_episode_set(name)
    return spec.houses or tuple(range(len(SPLITS[spec.split])))


def set_size(name: str) -> int:
    """Episodes in the full set: houses x bins x episodes per bin (those of ``extends`` included; one bin per house
    for a ``bin_per_house`` set)."""
    return len(set_houses(name)) * (1 if get_episode_set(name).bin_per_house else 3) * per_house_bin(name)


def per_house_bin(name: str) -> int:
    """Episodes per bin per house of a set (those of the sets it extends included)."""
    spec = get_episode_set(name)
    return spec.per_bin + (per_house_bin(spec.extends) if spec.extends else 0)


def build_episode_set(name: str, scenes_root, root="episodes", houses: tuple[int, ...] = (),
                      progress: bool = True) -> list[Path]:
    """Write ``root/<name>/<split>_<NN>.json`` for the houses of the set's split (all, or ``houses``),
    generating missing houses under ``scenes_root``; an extended set reads ``root/<extends>/`` first."""
    spec = get_episode_set(name)
    indices = houses or set_houses(name)
    if unknown := sorted(set(indices) - set(set_houses(name))):
        raise ConfigError(name, f"house indices {unknown} are not in the set (houses {list(set_houses(name))})")
    out = []
    for k, i in enumerate(indices):
        scene = Scene.load(ensure_house(spec.split, i, scenes_root))
        nav, renderer = NavGrid.from_scene(scene), Renderer(scene, get_task(spec.task).camera)
        gen = EpisodeGenConfig(per_bin=spec.per_bin)
        if spec.extends:
            base = load_episodes(Path(root) / spec.extends / f"{scene.name}.json", scene, spec.task, navgrid=nav)
            eps = extend_episodes(base, scene, spec.task, gen, seed=spec.seed, navgrid=nav, renderer=renderer)
        else:
            eps = generate_episodes(scene, spec.task, gen, seed=spec.seed, navgrid=nav, renderer=renderer)
        if spec.bin_per_house:
            names = get_task(spec.task).bins.names
            eps = [e for e in eps if e.difficulty == names[i % len(names)]]
        out.append(save_episodes(Path(root) / name / f"{scene.name}.json", eps, spec.task))
        if progress:
            print(f"[{k + 1}/{len(indices)}] {out[-1]} ({len(eps)} episodes)", file=sys.stderr)
    return out
