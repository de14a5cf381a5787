"""Episode generator: reachable start/goal pairs on one floor, filled into the task's difficulty bins.

A candidate is rejected when the goal is unreachable, when the goal's success disc reaches behind a
wall (a free cell within r of the goal whose geodesic distance exceeds r + slack: success is
Euclidean, so the goal region must be one open area), or when the goal photo's median depth is under
``min_goal_depth`` (a photo of a wall identifies nothing). Everything random comes from one
``numpy.random.Generator`` seeded by (seed, CRC32 of the scene name): stable across processes.
"""

from __future__ import annotations

import dataclasses
import math
import zlib
from dataclasses import dataclass

import numpy as np

from nue.errors import EpisodeGenerationError
from nue.scene.navgrid import NavGrid
from nue.scene.scene import Scene
from nue.sim.episodes import Episode
from nue.sim.renderer import Renderer
from nue.sim.task import TaskConfig, get_task


@dataclass(frozen=True)
class EpisodeGenConfig:
    """How episodes are sampled."""

    per_bin: int = 10
    """Episodes per difficulty bin."""
    tries_per_episode: int = 300
    """Try budget per requested episode; a bin that cannot be filled within per_bin x this raises."""
    min_goal_depth: float = 1.0
    """Reject goal photos whose median depth (metres) is below this."""
    goal_region_slack: float = 0.5
    """Reject goals with a free cell within r whose geodesic distance exceeds r + this (metres)."""


def episode_rng(seed: int, scene_name: str) -> np.random.Generator:
    """The generator's random stream for a scene: depends only on ``seed`` and the scene's name."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), zlib.crc32(scene_name.encode())]))


def generate_episodes(
    scene: Scene,
    task: TaskConfig | str = "paper",
    config: EpisodeGenConfig = EpisodeGenConfig(),
    seed: int = 0,
    floor: int = 0,
    navgrid: NavGrid | None = None,
    renderer=None,
    bins: tuple[str, ...] | None = None,
) -> list[Episode]:
    """Sample ``config.per_bin`` episodes for each difficulty bin of ``task`` in ``scene``."""
    task = get_task(task)
    nav = navgrid or NavGrid.from_scene(scene, floor)
    renderer = renderer or Renderer(scene, task.camera)
    rng = episode_rng(seed, scene.name)
    cells = nav.largest_component_cells()
    centres = nav.cell_centre(cells)
    floor_z = scene.floor_heights[floor]
    episodes: list[Episode] = []
    for name in bins or task.bins.names:
        lo, hi = task.bins.range_of(name)
        budget = config.per_bin * config.tries_per_episode
        made, tries = 0, 0
        while made < config.per_bin:
            tries += 1
            if tries > budget:
                raise EpisodeGenerationError(
                    scene.path,
                    f"could not fill difficulty bin {name!r} ({lo}-{hi} m): {made}/{config.per_bin} "
                    f"episodes after {budget} tries",
                )
            ep = _try_one(nav, task, config, rng, centres, lo, hi, renderer, floor_z, scene, f"{name}_{made:03d}")
            if ep is not None:
                episodes.append(ep)
                made += 1
    return episodes


def extend_episodes(
    base: list[Episode],
    scene: Scene,
    task: TaskConfig | str = "paper",
    config: EpisodeGenConfig = EpisodeGenConfig(),
    seed: int = 1,
    navgrid: NavGrid | None = None,
    renderer=None,
    bins: tuple[str, ...] | None = None,
) -> list[Episode]:
    """``base`` unchanged, then ``config.per_bin`` new episodes per bin drawn with ``seed`` (use a seed other
    than base's), whose ids continue each bin's numbering (``easy_002`` after ``easy_000``, ``easy_001``).

    A larger fixed set that starts with a smaller one: its first episodes of every file are the smaller
    set, with the same ids, so each of them gets the same per-episode seed in an evaluation.
    """
    new = generate_episodes(scene, task, config, seed=seed, navgrid=navgrid, renderer=renderer, bins=bins)
    taken = {e.episode_id for e in base}
    counts: dict[str, int] = {}
    for e in base:
        name = e.episode_id.rsplit("_", 1)[0]
        counts[name] = counts.get(name, 0) + 1
    out = list(base)
    for e in new:
        name = e.episode_id.rsplit("_", 1)[0]
        episode_id = f"{name}_{counts.get(name, 0):03d}"
        counts[name] = counts.get(name, 0) + 1
        if episode_id in taken:
            raise EpisodeGenerationError(scene.path, f"cannot extend: episode id {episode_id!r} is taken")
        out.append(dataclasses.replace(e, episode_id=episode_id))
    return out


def _try_one(nav, task, config, rng, centres, lo, hi, renderer, floor_z, scene, episode_id):
    start = centres[rng.integers(len(centres))]
    if task.bins.key == "euclidean":
        d = np.linalg.norm(centres - start, axis=1)
    else:
        start_field = nav.distance_field(start)
        cells = nav.cell_of(centres)
        d = start_field[cells[:, 0], cells[:, 1]]
    candidates = np.flatnonzero((d >= lo) & (d < hi))
    if len(candidates) == 0:
        return None
    goal = centres[candidates[rng.integers(len(candidates))]]
    start_yaw = rng.uniform(-math.pi, math.pi)
    goal_yaw = rng.uniform(-math.pi, math.pi)
    field = nav.distance_field(goal)
    geo = nav.lookup(field, start)
    if not np.isfinite(geo):
        return None
    euc = float(np.linalg.norm(goal - start))
    key = euc if task.bins.key == "euclidean" else geo
    if not lo <= key < hi and not (key == hi):
        return None
    if not goal_region_is_open(nav, field, goal, task.success_radius, config.goal_region_slack):
        return None
    _, depth = renderer.render((goal[0], goal[1], goal_yaw), floor_z)
    if float(np.median(depth)) < config.min_goal_depth:
        return None
    difficulty, path_type = task.bins.label(euc, geo)
    return Episode.from_poses(
        episode_id,
        scene.name,
        (start[0], start[1], start_yaw),
        (goal[0], goal[1], goal_yaw),
        z=floor_z,
        euclidean_distance=euc,
        geodesic_distance=geo,
        difficulty=difficulty,
        path_type=path_type,
        scene_hash=scene.content_hash,
    )


def goal_region_is_open(nav: NavGrid, field: np.ndarray, goal, radius: float, slack: float) -> bool:
    """True if every free cell within ``radius`` of the goal is within ``radius + slack`` geodesically."""
    rc = nav.cell_of(goal)
    k = int(math.ceil(radius / nav.cell)) + 1
    m = nav.free.shape[0]
    r0, r1 = max(rc[0] - k, 0), min(rc[0] + k + 1, m)
    c0, c1 = max(rc[1] - k, 0), min(rc[1] + k + 1, m)
    rr, cc = np.mgrid[r0:r1, c0:c1]
    pts = nav.cell_centre(np.stack([rr, cc], axis=-1))
    near = (np.linalg.norm(pts - goal, axis=-1) <= radius) & nav.free[r0:r1, c0:c1]
    return bool(np.all(field[r0:r1, c0:c1][near] <= radius + slack))
