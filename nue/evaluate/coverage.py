"""Exploration coverage: floor area seen by the depth camera, per step, per episode and averaged per method.

A floor cell counts as *seen* once the depth camera sees the floor there (not occluded, within
``max_range`` metres of the robot; see :func:`seen_floor_cells`, defined in :mod:`nue.sim.seen`). The
runner accumulates the union of seen cells over an episode and stores the area after every step,
in m², as ``record.extra["coverage"]``; :func:`mean_coverage_curves` averages those curves per
method (:func:`nue.viz.coverage.plot_coverage` draws them).

Typical use inside an ``on_step`` callback (or with :class:`CoverageTracker`)::

    seen = seen_floor_cells(obs["depth"], obs["pose"], task.camera, env.navgrid, env.floor_z) | seen
    areas.append(cell_area(env.navgrid) * seen.sum())
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from nue.evaluate.table import canonical_method, is_earlier_recipe, order_methods, split_seed
from nue.sim.record import EpisodeRecord
from nue.sim.seen import CoverageConfig, GridLike, cell_area, seen_floor_cells, seen_obstacle_cells
from nue.sim.task import CameraConfig

__all__ = [  # the per-frame geometry lives in nue.sim.seen (the exploring expert uses it too); re-exported
    "COVERAGE_KEY", "COVERAGE_NOTE", "CoverageConfig", "CoverageTracker", "GridLike", "cell_area", "coverage_curve",
    "coverage_curves", "format_coverage_markdown", "mean_coverage_curves", "pad_curves", "seen_floor_cells", "seen_obstacle_cells",
]

COVERAGE_KEY = "coverage"
"""Key of ``EpisodeRecord.extra`` holding the per-step seen floor area, m² (list of floats)."""


def coverage_curve(masks: Iterable[np.ndarray], area_per_cell: float) -> np.ndarray:
    """Cumulative seen area after each step: ``(T,)`` m², ``a_t = area_per_cell * |m_0 ∪ ... ∪ m_t|``.

    ``masks``: T per-step (M, M) bool masks from :func:`seen_floor_cells`. Non-decreasing.
    Example: masks with 2, then 3 (1 new) cells at 0.05 m -> ``[0.005, 0.0075]``.
    """
    seen: np.ndarray | None = None
    out = []
    for m in masks:
        seen = m.copy() if seen is None else (seen | m)
        out.append(area_per_cell * float(np.count_nonzero(seen)))
    return np.asarray(out, dtype=np.float64)


@dataclass
class CoverageTracker:
    """An ``on_step`` callback of :func:`nue.rollout.run_episode` accumulating seen floor area.

    Create one per episode; after the episode ``tracker.areas`` is the list to store as
    ``record.extra["coverage"]`` (one value per step, m²).
    """

    camera: CameraConfig
    """The task's camera (depth images are at its resolution)."""
    grid: Any
    """The episode's grid (``env.navgrid``), see :class:`GridLike`."""
    floor_z: float = 0.0
    """Floor height, metres (``env.floor_z``)."""
    config: CoverageConfig = CoverageConfig()
    """Which pixels count."""
    areas: list[float] = field(default_factory=list)
    """Seen area after each step so far, m²."""
    seen: np.ndarray | None = None
    """(M, M) bool union of seen cells so far."""
    region: np.ndarray | None = None
    """Optional (M, M) bool cells (e.g. the floor the robot can reach, :func:`explorable_cells`): ``region_areas``
    then holds the seen area within them after each step, m²."""
    region_areas: list[float] = field(default_factory=list)
    """Seen area within ``region`` after each step so far, m² (empty without a region)."""
    _centres: np.ndarray | None = field(default=None, init=False, repr=False)

    def __call__(self, step) -> None:
        if self._centres is None:  # every cell's centre, once (the frames project only the cells not seen yet)
            rows, cols = self.grid.free.shape
            rc = np.stack(np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij"), axis=-1)
            self._centres = np.asarray(self.grid.cell_centre(rc))
        m = seen_floor_cells(step.obs["depth"], step.obs["pose"], self.camera, self.grid, self.floor_z, self.config,
                             known=self.seen, centres=self._centres)
        self.seen = m if self.seen is None else (self.seen | m)
        self.areas.append(round(cell_area(self.grid) * float(np.count_nonzero(self.seen)), 6))
        if self.region is not None:
            self.region_areas.append(round(cell_area(self.grid) * float(np.count_nonzero(self.seen & self.region)), 6))


def explorable_cells(grid, start_xy) -> np.ndarray:
    """(M, M) bool planning cells of ``grid`` (a :class:`~nue.scene.navgrid.NavGrid`) holding floor of the
    traversability map's free region (1 cm pixels, not eroded) that contains the navigable point nearest
    ``start_xy``: the floor an exploring robot could see at most."""
    from scipy import ndimage

    labels, _ = ndimage.label(grid.trav)
    xy, _ = grid.snap(np.asarray(start_xy, dtype=np.float64))
    if xy is None:
        xy = np.asarray(start_xy, dtype=np.float64)
    n, f = grid.n, grid.factor
    col = int(np.clip(np.floor(xy[0] / grid.resolution + n / 2), 0, n - 1))
    row = int(np.clip(np.floor(xy[1] / grid.resolution + n / 2), 0, n - 1))
    lab = labels[row, col]
    m = grid.free.shape[0]
    padded = np.zeros((m * f, m * f), dtype=bool)
    if lab:
        padded[:n, :n] = labels == lab
    return padded.reshape(m, f, m, f).any(axis=(1, 3))


def pad_curves(curves: Sequence[Sequence[float]], length: int | None = None) -> np.ndarray:
    """Stack curves of different lengths into ``(N, L)``, holding each at its last value.

    An episode that ended early (success) keeps the area it had seen; ``length`` defaults to the
    longest curve (longer curves are cut). Empty curves count as 0.
    """
    length = max((len(c) for c in curves), default=0) if length is None else int(length)
    out = np.zeros((len(curves), length), dtype=np.float64)
    for i, c in enumerate(curves):
        c = np.asarray(c, dtype=np.float64)[:length]
        if len(c):
            out[i, : len(c)] = c
            out[i, len(c):] = c[-1]
    return out


def mean_coverage_curves(records: Sequence[EpisodeRecord], methods: Sequence[str] | None = None,
                         method_of=lambda r: r.method, length: int | None = None) -> dict[str, np.ndarray]:
    """Mean seen-area-vs-step curve ``(L,)`` m² per method, over its records carrying coverage.

    Curves are padded with :func:`pad_curves` (ended episodes hold their final area) to the longest
    curve of all methods (or ``length``). ``methods`` fixes the key order (methods without coverage
    are left out); ``method_of`` maps a record to its method key.
    """
    by_method: dict[str, list] = {}
    for r in records:
        cov = r.extra.get(COVERAGE_KEY) if isinstance(r.extra, Mapping) else None
        if cov is not None:
            by_method.setdefault(method_of(r), []).append(cov)
    if length is None:
        length = max((len(c) for cs in by_method.values() for c in cs), default=0)
    order = list(methods) if methods is not None else sorted(by_method)
    order += [m for m in sorted(by_method) if m not in order]
    return {m: pad_curves(by_method[m], length).mean(axis=0) for m in order if m in by_method}


COVERAGE_NOTE = (
    "Episodes that ended keep their final area. Earlier recipes' rows (`_v<N>`) are left out, as in the coverage "
    "figure: the seen floor got a depth check in 7a2b8f9 (2026-12-05; floor behind a wall's foot no longer counts), "
    "after the v6 run, so records made before it count more seen floor for the same path (about 10% on the geodesic "
    "expert's first 47 val252 episodes: ratio 0.88-0.95, new to old) and compare only with each other."
)
"""The coverage tables' note: what counts and which rows are not comparable."""


def coverage_curves(records: Sequence[EpisodeRecord]) -> dict[str, np.ndarray]:
    """Mean seen-area-vs-step curve (m²) per method of the table (canonical names, in table order; earlier recipes'
    rows left out, :data:`COVERAGE_NOTE`); a method's training seeds are one method, as in Table I (the mean over all
    its seeds' episodes: with the same episodes per seed, the mean of the seeds' mean curves)."""
    def key(r: EpisodeRecord) -> str:
        return canonical_method(split_seed(r.method)[0])

    current = [r for r in records if not is_earlier_recipe(r.method)]
    keys = order_methods({key(r) for r in current})
    return mean_coverage_curves(current, keys, method_of=key)


def format_coverage_markdown(curves: Mapping[str, np.ndarray], labels: Mapping[str, str] | None = None,
                             steps: Sequence[int] = (50, 100, 200, 400)) -> str:
    """Markdown table of mean seen area (m²) per method at the given steps and at the curves' last step."""
    length = max((len(c) for c in curves.values()), default=0)
    steps = sorted({s for s in (*steps, length) if 0 < s <= length})
    lines = ["| method | " + " | ".join(f"step {s}" for s in steps) + " |", "|" + "---|" * (len(steps) + 1)]
    lines += [f"| {(labels or {}).get(k, k)} | " + " | ".join(f"{c[s - 1]:.1f}" for s in steps) + " |"
              for k, c in curves.items()]
    return "\n".join(lines) + "\n"

