"""The geodesic expert: a deterministic shortest-path follower on the navigation grid.

Each step it takes the shortest path from its position to the goal (steepest descent on the cached
driving field, a geodesic field that charges extra near walls), aims at the farthest path point
within ``lookahead`` metres that it can reach in a straight line, and turns toward it when the
heading error exceeds half a turn step, else moves forward. It never turns back the way it just turned for a small error (no left-right thrashing),
and after a blocked forward move it turns toward the path before trying again. With a STOP action
in the task (``habitat``) it stops once safely inside the success radius.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nue.scene.navgrid import NavGrid
from nue.sim.camera import wrap_angle
from nue.sim.task import TaskConfig, get_task


@dataclass(frozen=True)
class ExpertConfig:
    """Behaviour of the geodesic expert."""

    lookahead: float = 0.8
    """How far along the path (metres) the expert looks for its aim point."""
    stop_margin: float = 0.25
    """With a STOP action: stop when the geodesic distance is below success radius minus this (metres)."""
    keep_clear: bool = True
    """Follow the navigation grid's comfort field (keeps to the middle of corridors, fewer collisions)."""


class GeodesicExpert:
    """Shortest-path follower; ``act(pose)`` returns an action id of the task preset."""

    def __init__(self, navgrid: NavGrid, task: TaskConfig | str = "paper", config: ExpertConfig = ExpertConfig()):
        self.nav = navgrid
        self.task = get_task(task)
        self.config = config
        self.forward = self.task.action_id("MOVE_FORWARD")
        self.left = self.task.action_id("TURN_LEFT")
        self.right = self.task.action_id("TURN_RIGHT")
        self.stop = self.task.action_id("STOP")
        self.goal = None

    def reset(self, goal_xy) -> None:
        """Start a new episode toward ``goal_xy``."""
        self.goal = np.asarray(goal_xy, dtype=np.float64)[:2]
        self._field = self.nav.distance_field(self.goal)
        self._last_action = None
        self._last_xy = None

    def act(self, pose) -> int:
        """Action for robot pose ``(x, y, yaw)``."""
        if self.goal is None:
            raise RuntimeError("call reset(goal_xy) first")
        xy = np.asarray(pose[:2], dtype=np.float64)
        yaw = float(pose[2])
        stuck = (
            self._last_action == self.forward
            and self._last_xy is not None
            and np.linalg.norm(xy - self._last_xy) < 0.25 * self.task.forward_step
        )
        if self.stop is not None:
            geo = self.nav.lookup(self._field, xy)
            if geo <= self.task.success_radius - self.config.stop_margin:
                return self._remember(self.stop, xy)
        angle = wrap_angle(self.aim_angle(xy, yaw))
        tolerance = 0.5 * self.task.turn_angle + 1e-6
        if stuck:
            # A blocked move: turn toward the path (or left if it points straight ahead) before retrying.
            action = self.right if angle < -1e-3 else self.left
        elif abs(angle) <= tolerance:
            action = self.forward
        else:
            action = self.left if angle > 0 else self.right
            opposite = {self.left: self.right, self.right: self.left}.get(action)
            if self._last_action == opposite and abs(angle) < self.task.turn_angle:
                action = self.forward  # no thrashing: a small residual error does not undo the last turn
        return self._remember(action, xy)

    def aim_point(self, xy) -> np.ndarray:
        """The farthest point within ``lookahead`` along the shortest path that is in straight reach."""
        n_cells = int(math.ceil(self.config.lookahead / self.nav.cell)) + 2
        path = self.nav.shortest_path(xy, self.goal, max_len=n_cells, comfort=self.config.keep_clear)
        if len(path) < 2:
            return self.goal.copy()
        seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
        along = np.concatenate([[0.0], np.cumsum(seg)])
        best = path[1]
        for i in range(1, len(path)):
            if along[i] > self.config.lookahead:
                break
            if self.nav.segment_free(xy, path[i], step=0.03):
                best = path[i]
        return best

    def aim_angle(self, xy, yaw: float) -> float:
        """Heading error toward the aim point, radians, positive = to the left."""
        target = self.aim_point(xy)
        d = target - xy
        if np.linalg.norm(d) < 1e-9:
            d = self.goal - xy
        return wrap_angle(math.atan2(d[1], d[0]) - yaw)

    def _remember(self, action: int, xy) -> int:
        self._last_action = action
        self._last_xy = np.array(xy, dtype=np.float64)
        return action
