"""The robot's own map for the last mile: floor and obstacle cells its depth frames showed, and shortest paths on it.

A square grid centred on the episode's start (the robot cannot know the scene's bounds), world-axis aligned,
``cell`` metres per cell; each depth frame adds the cells it sees as floor and as obstacle
(:func:`nue.sim.seen.seen_cells`, as the exploring expert builds its map). For planning, obstacle cells are
*blocked* after dilation by the robot's radius (plus a margin); cells the robot's centre has been in are never
blocked; cells seen neither as floor nor as obstacle are *unknown* and traversable at ``unknown_cost`` times the
cost of seen floor. A cost near blocked cells keeps paths off walls (as the navigation grid's comfort field).

:class:`SeenMap` answers what :class:`nue.sim.expert.PathDriver` asks of a navigation grid (``cell``,
``shortest_path``, ``segment_free``), so the experts' steering drives on it; it never reads the scene.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage
from skimage.graph import MCP_Geometric

from nue.scene.navgrid import ROBOT_RADIUS
from nue.sim.seen import CoverageConfig, seen_cells
from nue.sim.task import CameraConfig

_NEIGHBOURS = np.array([(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)])


@dataclass(frozen=True)
class SeenMapConfig:
    """The robot's own map and how it plans on it (metres)."""

    size: float = 24.0
    """Side of the square map centred on the start; what lies outside is neither mapped nor planned on."""
    cell: float = 0.05
    """Cell size."""
    robot_radius: float = ROBOT_RADIUS
    """Obstacle cells are dilated by this plus ``margin`` for planning."""
    margin: float = 0.02
    """Extra clearance beyond the robot's radius."""
    unknown_cost: float = 1.5
    """Cost of crossing an unknown cell relative to seen floor (unknown is traversable, at a cost)."""
    comfort_clearance: float = 0.3
    """Cells within this of a blocked cell cost extra (linear up to ``comfort_weight`` at zero clearance)."""
    comfort_weight: float = 3.0
    """Extra cost per cell at zero clearance."""
    plan_margin: float = 2.5
    """Paths are planned in the box around the robot and the target widened by this."""
    seen: CoverageConfig = field(default_factory=CoverageConfig)
    """Which cells a depth frame shows as floor and as obstacle."""


class SeenMap:
    """Floor / obstacle cells seen by the robot's depth frames, with planning toward a target point.

    ``camera``, ``floor_z``: the task's camera and the floor height (metres); ``origin``: world (x, y) of the map's
    centre (the start position). Grid cell (row, col) covers y (rows) and x (cols), like the navigation grid.
    """

    def __init__(self, camera: CameraConfig, floor_z: float, origin, config: SeenMapConfig = SeenMapConfig()):
        self.camera, self.floor_z, self.config = camera, float(floor_z), config
        self.cell = float(config.cell)
        m = int(math.ceil(config.size / self.cell))
        self.origin = np.asarray(origin, dtype=np.float64)[:2] - m * self.cell / 2
        """World (x, y) of the corner of cell (0, 0)."""
        self.free = np.zeros((m, m), dtype=bool)
        """(M, M) only its shape is read (:class:`nue.sim.seen.GridLike`)."""
        self.floor = np.zeros((m, m), dtype=bool)
        """(M, M) cells seen as floor."""
        self.obstacle = np.zeros((m, m), dtype=bool)
        """(M, M) cells seen as obstacle."""
        self.visited = np.zeros((m, m), dtype=bool)
        """(M, M) cells the robot's centre has been in."""
        r = int(math.ceil((config.robot_radius + config.margin) / self.cell))
        dr, dc = np.mgrid[-r:r + 1, -r:r + 1]
        self._disc = np.hypot(dr, dc) * self.cell <= config.robot_radius + config.margin
        self._plan: tuple | None = None  # (target cell, version, window lo, cost-to-go field of the window)
        self.version = 0

    # -- GridLike -------------------------------------------------------------------------------
    def cell_of(self, xy) -> np.ndarray:
        """World (x, y) (..., 2) -> cell (row, col) (..., 2), int."""
        xy = np.asarray(xy, dtype=np.float64)
        return np.floor((xy[..., ::-1] - self.origin[::-1]) / self.cell).astype(np.int64)

    def cell_centre(self, rc) -> np.ndarray:
        """Cell (row, col) (..., 2) -> world (x, y) (..., 2) of its centre."""
        rc = np.asarray(rc, dtype=np.float64)
        return (rc[..., ::-1] + 0.5) * self.cell + self.origin

    # -- mapping --------------------------------------------------------------------------------
    def add_frame(self, depth: np.ndarray, pose) -> None:
        """Add what depth frame ``depth`` (H, W[, 1]) z-depth metres, seen from robot ``pose`` (x, y, yaw), shows."""
        floor, obstacle = seen_cells(depth, pose, self.camera, self, self.floor_z, self.config.seen)
        self.floor |= floor
        self.obstacle |= obstacle
        self.version += 1

    def add_position(self, xy) -> None:
        """The robot's centre is at world ``xy`` (2,): its cell and the 8 around it are never blocked."""
        r, c = (int(v) for v in self.cell_of(xy))
        m = self.free.shape[0]
        self.visited[max(r - 1, 0):min(r + 2, m), max(c - 1, 0):min(c + 2, m)] = True
        self.version += 1

    def blocked(self, window: tuple[slice, slice] | None = None) -> np.ndarray:
        """Cells the robot's centre may not enter (dilated obstacles, not visited), in ``window`` (default all)."""
        window = window or (slice(None), slice(None))
        obstacle = self.obstacle[window]
        if not obstacle.any():
            return np.zeros(obstacle.shape, dtype=bool)
        return ndimage.binary_dilation(obstacle, self._disc) & ~self.visited[window]

    # -- what PathDriver asks of a grid ---------------------------------------------------------
    def is_free(self, xy) -> bool | np.ndarray:
        """Whether the robot's centre may be at world (x, y) (..., 2) as far as the map knows (unknown counts as
        free; outside the map does not)."""
        rc = self.cell_of(xy)
        m = self.free.shape[0]
        inside = np.all((rc >= 0) & (rc < m), axis=-1)
        rc = np.clip(rc, 0, m - 1)
        r, c = rc[..., 0], rc[..., 1]
        lo_r, lo_c = max(int(np.min(r)) - len(self._disc), 0), max(int(np.min(c)) - len(self._disc), 0)
        hi_r, hi_c = min(int(np.max(r)) + len(self._disc) + 1, m), min(int(np.max(c)) + len(self._disc) + 1, m)
        blocked = self.blocked((slice(lo_r, hi_r), slice(lo_c, hi_c)))
        ok = inside & ~blocked[r - lo_r, c - lo_c]
        return bool(ok) if np.ndim(ok) == 0 else ok

    def segment_free(self, a, b, step: float = 0.02) -> bool:
        """Whether the straight segment from world point a to b stays out of blocked cells (sampled every ``step``)."""
        a, b = np.asarray(a, dtype=np.float64)[:2], np.asarray(b, dtype=np.float64)[:2]
        k = max(2, int(np.ceil(np.linalg.norm(b - a) / step)) + 1)
        return bool(np.all(self.is_free(a + (b - a) * np.linspace(0.0, 1.0, k)[:, None])))

    def cost_to_go(self, start_xy, target_xy) -> tuple[np.ndarray, np.ndarray] | None:
        """``(lo (2,), field)``: the cost-to-go (metres-equivalent, inf = unreachable) to the target over a window of
        cells starting at cell ``lo``: the box around the start and the target widened by ``plan_margin``, or the
        whole map when the start cannot reach the target inside that box. The target cell is the unblocked cell
        nearest to ``target_xy``. None if no cell is unblocked. Cached until the map changes."""
        cfg, m = self.config, self.free.shape[0]
        pad = int(math.ceil(cfg.plan_margin / self.cell))
        cells = np.clip(np.stack([self.cell_of(start_xy), self.cell_of(target_xy)]), 0, m - 1)
        key = (tuple(cells[0]), tuple(cells[1]), self.version)
        if self._plan is not None and self._plan[0] == key:
            return self._plan[1]
        lo, hi = np.clip(cells.min(axis=0) - pad, 0, m - 1), np.clip(cells.max(axis=0) + pad, 0, m - 1)
        result = self._field(lo, hi, cells[1])
        if result is not None and not np.isfinite(result[1][tuple(cells[0] - lo)]) and (lo > 0).any() | (hi < m - 1).any():
            result = self._field(np.zeros(2, dtype=np.int64), np.full(2, m - 1), cells[1])
        self._plan = (key, result)
        return result

    def _field(self, lo: np.ndarray, hi: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """Cost-to-go to cell ``target`` (2,) over the cells ``lo`` .. ``hi`` (inclusive), as :meth:`cost_to_go`."""
        cfg = self.config
        window = (slice(lo[0], hi[0] + 1), slice(lo[1], hi[1] + 1))
        blocked = self.blocked(window)
        if blocked.all():
            return None
        clearance = ndimage.distance_transform_edt(~blocked) * self.cell if blocked.any() else np.full(blocked.shape, np.inf)
        cost = np.where(self.floor[window] | self.visited[window], 1.0, cfg.unknown_cost)
        cost = cost + cfg.comfort_weight * np.clip(1.0 - clearance / cfg.comfort_clearance, 0.0, 1.0)
        cost[blocked] = np.inf
        goal = target - lo
        if blocked[tuple(goal)]:
            near = ndimage.distance_transform_edt(blocked, return_distances=False, return_indices=True)
            goal = near[:, goal[0], goal[1]]
        costs, _ = MCP_Geometric(cost, fully_connected=True).find_costs([tuple(int(v) for v in goal)])
        return lo, np.where(np.isfinite(costs), costs * self.cell, np.inf)

    def shortest_path(self, start_xy, goal_xy, max_len: int | None = None, comfort: bool = True) -> np.ndarray:
        """Waypoints (K, 2) world from the start along the steepest descent of :meth:`cost_to_go` (up to ``max_len``
        cells), ending at the goal if reached; empty (0, 2) if unreachable. ``comfort`` is accepted for
        :class:`nue.sim.expert.PathDriver` (the field always keeps off walls)."""
        start_xy = np.asarray(start_xy, dtype=np.float64)[:2]
        planned = self.cost_to_go(start_xy, goal_xy)
        if planned is None:
            return np.zeros((0, 2))
        lo, fld = planned
        rc = self.cell_of(start_xy) - lo
        around = rc + np.vstack([[0, 0], _NEIGHBOURS])
        around = around[np.all((around >= 0) & (around < fld.shape), axis=1)]
        if len(around) == 0:
            return np.zeros((0, 2))
        vals = fld[around[:, 0], around[:, 1]]
        if not np.isfinite(vals).any():
            return np.zeros((0, 2))
        rc = tuple(int(v) for v in around[int(np.argmin(vals))])
        cells = [rc]
        limit = max_len if max_len is not None else fld.size
        while fld[rc] > 0 and len(cells) < limit:
            nb = np.asarray(rc) + _NEIGHBOURS
            nb = nb[np.all((nb >= 0) & (nb < fld.shape), axis=1)]
            v = fld[nb[:, 0], nb[:, 1]]
            i = int(np.argmin(v))
            if not v[i] < fld[rc]:
                break
            rc = tuple(int(x) for x in nb[i])
            cells.append(rc)
        pts = self.cell_centre(np.array(cells) + lo)
        if fld[rc] == 0:
            pts = np.vstack([pts, np.asarray(goal_xy, dtype=np.float64)[:2]])
        return np.vstack([start_xy, pts])

    def reachable(self, start_xy, target_xy) -> bool:
        """Whether the map has a path from the start to (the free cell nearest) the target."""
        return len(self.shortest_path(start_xy, target_xy, max_len=2)) > 0
