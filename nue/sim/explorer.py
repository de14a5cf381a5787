"""The exploring expert: frontier exploration on its own seen map until the goal is in view, then the geodesic expert.

Exploration -> exploitation, as in the paper: the expert's actions follow from what the robot has
seen, which gives the policy's uncertainty branch behaviour to imitate. Each step it adds the floor
cells its depth frame sees, and the cells the frame shows as obstacle, to its seen map
(:mod:`nue.sim.seen`; never the scene's geometry). Once the goal's cell is seen in the current frame
within ``view_range`` of the robot it switches for good to the geodesic expert (identical behaviour
from then on, STOP included). Until then it explores: frontier cells are seen cells where the robot
can stand (the eroded navigation grid, its own free space) next to an unknown region (cells seen
neither as floor nor as obstacle) of at least ``min_unknown_area``; clusters smaller than
``min_cluster_cells`` are dropped; the chosen frontier cell has the least geodesic cost from the
robot plus a turn penalty (``turn_weight`` per radian of bearing) and is kept until reached or no
longer a frontier (hysteresis). The robot drives to a cell with clearance next to it, with the
geodesic expert's steering (:class:`nue.sim.expert.PathDriver`, plus a check that a forward move
stays in free space). With no frontier left, or after ``max_explore_steps``, it falls back to the
geodesic expert, so every episode finishes. Deterministic: the same inputs give the same actions.

The goal position is used only to decide whether the goal is in view; where to explore depends on
the seen map alone (paths are planned on the navigation grid).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from skimage.graph import MCP_Geometric

from nue.scene.navgrid import NavGrid
from nue.sim.camera import wrap_angle
from nue.sim.expert import ExpertConfig, GeodesicExpert
from nue.sim.seen import CoverageConfig, seen_cells
from nue.sim.task import TaskConfig, get_task

_EIGHT = np.ones((3, 3), dtype=bool)


@dataclass(frozen=True)
class ExplorerConfig:
    """Behaviour of the exploring expert (distances in metres)."""

    view_range: float = 3.0
    """The goal is in view when its cell is seen in the current frame at most this far from the robot."""
    max_explore_steps: int = 250
    """After this many exploring steps the geodesic expert takes over (every episode finishes)."""
    seen: CoverageConfig = CoverageConfig()
    """Which cells a depth frame shows as floor (range ``max_range``) and as obstacle."""
    known_radius: float = 0.5
    """Cells within this distance of the robot's centre count as seen (the floor around its own
    disc; the camera sees no floor nearer than ~0.8 m)."""
    min_unknown_area: float = 1.0
    """Unknown regions (4-connected cells seen neither as floor nor as obstacle) smaller than this, m²,
    make no frontier: pockets behind furniture and the blind ring around the start are not worth a visit."""
    min_cluster_cells: int = 5
    """Frontier clusters (8-connected) with fewer cells are ignored (a doorway's frontier has ~10 cells of 5 cm)."""
    min_target_dist: float = 1.0
    """Frontier cells nearer than this (straight line) are not chosen while farther ones exist (the
    floor right in front of the camera is in its blind zone)."""
    reach_dist: float = 0.3
    """A target this close to the robot counts as reached."""
    target_clearance: float = 0.25
    """The robot drives to the cell within ``target_shift`` of the chosen frontier cell that has the
    most clearance up to this (distance to the grid's blocked cells), so it does not nose into walls."""
    target_shift: float = 0.3
    """How far the driven-to target may lie from the chosen frontier cell."""
    keep_cells: int = 2
    """A target stays valid while a frontier cell lies within this many cells (Chebyshev) of its frontier cell."""
    turn_weight: float | None = None
    """Extra cost of a frontier per radian of bearing from the heading, metres; ``None`` = forward step /
    turn angle (a turn costs as much as a forward step)."""
    safe_forward: bool = True
    """While exploring, a forward move that would leave the robot's free space becomes a turn toward the
    aim point when that helps (see :meth:`nue.sim.expert.PathDriver.steer`)."""
    drop_radius: float = 0.5
    """When a target is reached but its frontier cell is still a frontier, frontier cells within this
    distance of that cell are ignored from then on (so it cannot be chosen again and again)."""


class ExploringExpert:
    """Frontier explorer until the goal is in view, then :class:`GeodesicExpert`; ``act(pose, depth)``
    returns an action id of the task preset.

    ``floor_z``: height of the navigation grid's floor (``env.floor_z``), metres. After an episode,
    ``mode`` (``"explore"`` / ``"geodesic"``) and ``stats`` tell what it did.
    """

    def __init__(self, navgrid: NavGrid, task: TaskConfig | str = "paper", config: ExplorerConfig = ExplorerConfig(),
                 expert_config: ExpertConfig = ExpertConfig(), floor_z: float = 0.0):
        self.nav = navgrid
        self.task = get_task(task)
        self.config = config
        self.floor_z = float(floor_z)
        self.geodesic = GeodesicExpert(navgrid, self.task, expert_config)
        """Takes over once the goal is in view; its :class:`PathDriver` also steers while exploring."""
        self.driver = self.geodesic.driver
        self.turn_weight = (self.task.forward_step / self.task.turn_angle if config.turn_weight is None
                            else float(config.turn_weight))
        self._costs = np.where(navgrid.free, 1.0, np.inf)
        self._clearance = ndimage.distance_transform_edt(navgrid.free) * navgrid.cell
        self._known = self._offsets(config.known_radius)
        self.goal = None

    def reset(self, goal_xy) -> None:
        """Start a new episode toward ``goal_xy``: empty seen map, explore mode."""
        self.goal = np.asarray(goal_xy, dtype=np.float64)[:2]
        self.geodesic.reset(self.goal)
        shape = self.nav.free.shape
        self.seen = np.zeros(shape, dtype=bool)
        """(M, M) bool: floor cells seen so far (plus the cells around the robot's path)."""
        self.obstacle = np.zeros(shape, dtype=bool)
        """(M, M) bool: cells seen as obstacle so far."""
        self._dropped = np.zeros(shape, dtype=bool)
        self._goal_cell = tuple(int(v) for v in self.nav.cell_of(self.goal))
        self.mode = "explore"
        self.target: np.ndarray | None = None
        """Current target, world (x, y) metres (a clear cell near the chosen frontier cell), or None."""
        self._target_cell: np.ndarray | None = None
        self.stats = {"steps": 0, "explore_steps": 0, "goal_in_view_at_start": None, "goal_seen_step": None,
                      "switch": None, "switch_step": None, "targets": 0, "targets_reached": 0, "targets_arrived": 0}
        """Per episode: steps so far, steps in explore mode, whether the goal was in view at step 0, the
        first step its cell was seen at any range (while exploring), why (``goal_in_view`` /
        ``no_frontier`` / ``budget``) and at which step it switched to geodesic mode, frontier targets
        chosen, completed (arrived at or no longer a frontier) and arrived at (within ``reach_dist``)."""

    def act(self, pose, depth) -> int:
        """Action for robot pose ``(x, y, yaw)`` and depth frame ``depth`` (H, W[, 1]) metres seen from it."""
        if self.goal is None:
            raise RuntimeError("call reset(goal_xy) first")
        st = self.stats
        st["steps"] += 1
        if self.mode == "explore":
            action = self._explore_step(pose, depth)
            if action is not None:
                st["explore_steps"] += 1
                return action
        return self.geodesic.act(pose)

    def executed(self, action: int) -> None:
        """The action actually executed after the last ``act`` (differs under noise injection)."""
        self.driver.executed(action)

    # -- exploring ------------------------------------------------------------------------------
    def _explore_step(self, pose, depth) -> int | None:
        """Update the seen map; an exploring action, or None after switching to geodesic mode."""
        cfg, st = self.config, self.stats
        xy, yaw = np.asarray(pose[:2], dtype=np.float64), float(pose[2])
        floor, obstacle = seen_cells(depth, pose, self.task.camera, self.nav, self.floor_z, cfg.seen)
        seen_goal = bool(floor[self._goal_cell])
        if seen_goal and st["goal_seen_step"] is None:
            st["goal_seen_step"] = st["steps"] - 1
        in_view = seen_goal and float(np.linalg.norm(self.goal - xy)) <= cfg.view_range
        if st["goal_in_view_at_start"] is None:
            st["goal_in_view_at_start"] = in_view
        if in_view:
            return self._switch("goal_in_view")
        if st["explore_steps"] >= cfg.max_explore_steps:
            return self._switch("budget")
        self.seen |= floor
        self.obstacle |= obstacle
        self._mark_known(xy)
        frontier = self.frontier()
        if self.target is not None:
            arrived = float(np.linalg.norm(self.target - xy)) <= cfg.reach_dist
            still = self._is_frontier_near(frontier, self._target_cell)
            if arrived or not still:
                st["targets_reached"] += 1
                st["targets_arrived"] += int(arrived)
                if arrived and still:
                    self._dropped[self._cells_within(self._target_cell, self._offsets(cfg.drop_radius))] = True
                self.target = None
        if self.target is None:
            self._target_cell = self._choose_frontier_cell(frontier, xy, yaw)
            if self._target_cell is None:
                return self._switch("no_frontier")
            self.target = self._clear_target(self._target_cell)
            st["targets"] += 1
        return self.driver.drive(xy, yaw, self.target, safe=cfg.safe_forward)

    def frontier(self) -> np.ndarray:
        """(M, M) bool: seen cells where the robot can stand that touch (8-neighbourhood) an unknown
        region (cells seen neither as floor nor as obstacle) of at least ``min_unknown_area``; cells
        dropped after unresolved arrivals are left out."""
        labels, _ = ndimage.label(~(self.seen | self.obstacle))
        area = np.bincount(labels.ravel()) * self.nav.cell**2
        area[0] = 0.0
        unknown = area[labels] >= self.config.min_unknown_area
        return self.nav.free & self.seen & ~self._dropped & ndimage.binary_dilation(unknown, _EIGHT)

    def _choose_frontier_cell(self, frontier: np.ndarray, xy: np.ndarray, yaw: float) -> np.ndarray | None:
        """Least-cost frontier cell (row, col) (2,) of a large enough cluster, or None if none is reachable."""
        cfg = self.config
        labels, _ = ndimage.label(frontier, structure=_EIGHT)
        sizes = np.bincount(labels.ravel())
        sizes[0] = 0
        cells = np.argwhere(sizes[labels] >= cfg.min_cluster_cells)
        if len(cells) == 0:
            return None
        cost = self._cost_from(xy)[cells[:, 0], cells[:, 1]]
        centres = self.nav.cell_centre(cells)
        d = centres - xy
        bearing = np.abs(wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - yaw))
        score = cost + self.turn_weight * bearing
        far = np.hypot(d[:, 0], d[:, 1]) >= cfg.min_target_dist
        if np.isfinite(score[far]).any():
            score = np.where(far, score, np.inf)
        if not np.isfinite(score).any():
            return None
        return cells[int(np.argmin(score))]

    def _clear_target(self, rc: np.ndarray) -> np.ndarray:
        """World (2,) centre of the cell near frontier cell ``rc`` (2,) with the most clearance (capped at
        ``target_clearance``), nearest to ``rc`` among equals."""
        cfg = self.config
        window = np.stack(self._cells_within(rc, self._offsets(cfg.target_shift)), axis=1)
        clear = np.minimum(self._clearance[window[:, 0], window[:, 1]], cfg.target_clearance)
        dist = np.linalg.norm(window - rc, axis=1)
        best = np.lexsort((dist, -clear))[0]
        return self.nav.cell_centre(window[best])

    def _cost_from(self, xy: np.ndarray) -> np.ndarray:
        """(M, M) geodesic distance (metres, 8-connected) from the free cells next to the robot; inf = unreachable."""
        rc = self.nav.cell_of(xy)
        m = self.nav.free.shape[0]
        for ring in (1, 2, 4, 8):
            lo, hi = np.clip(rc - ring, 0, m - 1), np.clip(rc + ring, 0, m - 1)
            starts = np.argwhere(self.nav.free[lo[0] : hi[0] + 1, lo[1] : hi[1] + 1]) + lo
            if len(starts):
                break
        else:
            return np.full(self.nav.free.shape, np.inf)
        costs, _ = MCP_Geometric(self._costs, fully_connected=True).find_costs([tuple(s) for s in starts])
        return np.where(np.isfinite(costs), costs * self.nav.cell, np.inf)

    def _is_frontier_near(self, frontier: np.ndarray, rc) -> bool:
        r, c = (int(v) for v in rc)
        k = self.config.keep_cells
        return bool(frontier[max(r - k, 0) : r + k + 1, max(c - k, 0) : c + k + 1].any())

    def _offsets(self, radius: float) -> np.ndarray:
        """(K, 2) cell offsets of the disc of ``radius`` metres around a cell."""
        r = int(math.ceil(radius / self.nav.cell))
        dr, dc = np.mgrid[-r : r + 1, -r : r + 1]
        inside = np.hypot(dr, dc) * self.nav.cell <= radius
        return np.stack([dr[inside], dc[inside]], axis=1)

    def _cells_within(self, rc, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(rows, cols) of the grid cells at ``offsets`` (K, 2) from cell ``rc`` (2,)."""
        rc = np.asarray(rc) + offsets
        m = self.nav.free.shape[0]
        rc = rc[np.all((rc >= 0) & (rc < m), axis=1)]
        return rc[:, 0], rc[:, 1]

    def _mark_known(self, xy) -> None:
        self.seen[self._cells_within(self.nav.cell_of(xy), self._known)] = True

    def _switch(self, reason: str) -> None:
        self.mode, self.target, self._target_cell = "geodesic", None, None
        self.stats["switch"], self.stats["switch_step"] = reason, self.stats["steps"] - 1
        return None
