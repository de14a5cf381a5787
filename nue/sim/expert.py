"""The geodesic expert: a deterministic shortest-path follower on the navigation grid.

Each step it takes the shortest path from its position to the goal (steepest descent on the cached
driving field, a geodesic field that charges extra near walls), aims at the farthest path point
within ``lookahead`` metres that it can reach in a straight line, and turns toward it when the
heading error exceeds half a turn step, else moves forward. It never turns back the way it just turned for a small error (no left-right thrashing),
and after a blocked forward move it turns toward the path before trying again. With a STOP action
in the task (``habitat``) it stops once safely inside the success radius. The steering toward a
point (:class:`PathDriver`) is shared with the exploring expert (``nue.sim.explorer``).
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


class PathDriver:
    """Drives toward a target point along the navigation grid's shortest path, one action at a time.

    The steering shared by the geodesic and the exploring expert: aim at the farthest point of the
    (comfort) shortest path within ``config.lookahead`` metres that is in straight reach; turn toward
    it when the heading error exceeds half a turn step, else move forward; never undo the last turn
    for an error smaller than a turn step (no left-right thrashing); after a blocked forward move
    (the robot moved less than a quarter step) turn toward the path before retrying.
    """

    def __init__(self, navgrid: NavGrid, task: TaskConfig, config: ExpertConfig = ExpertConfig()):
        self.nav, self.task, self.config = navgrid, task, config
        self.forward = task.action_id("MOVE_FORWARD")
        self.left = task.action_id("TURN_LEFT")
        self.right = task.action_id("TURN_RIGHT")
        self.reset()

    def reset(self) -> None:
        """Forget the last action (start of an episode)."""
        self.last_action: int | None = None
        self.last_xy: np.ndarray | None = None

    def blocked(self, xy) -> bool:
        """Whether the last action was a forward move that (nearly) did not move the robot to ``xy``."""
        return (
            self.last_action == self.forward
            and self.last_xy is not None
            and np.linalg.norm(np.asarray(xy, dtype=np.float64) - self.last_xy) < 0.25 * self.task.forward_step
        )

    def drive(self, xy, yaw: float, target, safe: bool = False) -> int:
        """The action (remembered for the blocked-move check) toward world point ``target`` (2,) from
        position ``xy`` (2,) metres and heading ``yaw`` radians; ``safe``: see :meth:`steer`."""
        return self.remember(self.steer(xy, yaw, target, self.blocked(xy), safe), xy)

    def steer(self, xy, yaw: float, target, blocked: bool, safe: bool = False) -> int:
        """Turn or forward toward ``target`` (not remembered); ``blocked``: the last forward move was blocked.

        ``safe``: a forward move that would leave free space becomes the turn toward the aim point when
        the forward move after that turn would stay free (the geodesic expert does not use it)."""
        angle = wrap_angle(self.aim_angle(xy, yaw, target))
        tolerance = 0.5 * self.task.turn_angle + 1e-6
        if blocked:
            # A blocked move: turn toward the path (or left if it points straight ahead) before retrying.
            return self.right if angle < -1e-3 else self.left
        if abs(angle) <= tolerance:
            action = self.forward
        else:
            action = self.left if angle > 0 else self.right
            opposite = {self.left: self.right, self.right: self.left}.get(action)
            if self.last_action == opposite and abs(angle) < self.task.turn_angle:
                action = self.forward  # no thrashing: a small residual error does not undo the last turn
        if safe and action == self.forward and not self.forward_free(xy, yaw):
            turn = 1.0 if angle >= 0 else -1.0
            if self.forward_free(xy, yaw + turn * self.task.turn_angle):
                action = self.left if turn > 0 else self.right
        return action

    def forward_free(self, xy, yaw: float) -> bool:
        """Whether a forward step from ``xy`` along heading ``yaw`` stays in free space."""
        xy = np.asarray(xy, dtype=np.float64)
        end = xy + self.task.forward_step * np.array([math.cos(yaw), math.sin(yaw)])
        return self.nav.segment_free(xy, end, step=0.02)

    def aim_point(self, xy, target) -> np.ndarray:
        """The farthest point within ``lookahead`` along the shortest path to ``target`` that is in straight reach."""
        target = np.asarray(target, dtype=np.float64)[:2]
        n_cells = int(math.ceil(self.config.lookahead / self.nav.cell)) + 2
        path = self.nav.shortest_path(xy, target, max_len=n_cells, comfort=self.config.keep_clear)
        if len(path) < 2:
            return target.copy()
        seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
        along = np.concatenate([[0.0], np.cumsum(seg)])
        best = path[1]
        for i in range(1, len(path)):
            if along[i] > self.config.lookahead:
                break
            if self.nav.segment_free(xy, path[i], step=0.03):
                best = path[i]
        return best

    def aim_angle(self, xy, yaw: float, target) -> float:
        """Heading error toward the aim point, radians, positive = to the left."""
        xy = np.asarray(xy, dtype=np.float64)
        d = self.aim_point(xy, target) - xy
        if np.linalg.norm(d) < 1e-9:
            d = np.asarray(target, dtype=np.float64)[:2] - xy
        return wrap_angle(math.atan2(d[1], d[0]) - yaw)

    def executed(self, action: int) -> None:
        """The action actually executed after the last ``drive`` (differs under noise injection)."""
        self.last_action = int(action)

    def remember(self, action: int, xy) -> int:
        """Record ``action`` taken at ``xy`` for the next blocked-move check; returns it."""
        self.last_action = action
        self.last_xy = np.array(xy, dtype=np.float64)
        return action


class GeodesicExpert:
    """Shortest-path follower; ``act(pose)`` returns an action id of the task preset."""

    def __init__(self, navgrid: NavGrid, task: TaskConfig | str = "paper", config: ExpertConfig = ExpertConfig()):
        self.nav = navgrid
        self.task = get_task(task)
        self.config = config
        self.driver = PathDriver(navgrid, self.task, config)
        """The steering (also used by :class:`nue.sim.explorer.ExploringExpert` while it explores)."""
        self.forward, self.left, self.right = self.driver.forward, self.driver.left, self.driver.right
        self.stop = self.task.action_id("STOP")
        self.goal = None

    def reset(self, goal_xy) -> None:
        """Start a new episode toward ``goal_xy``."""
        self.goal = np.asarray(goal_xy, dtype=np.float64)[:2]
        self._field = self.nav.distance_field(self.goal)
        self.driver.reset()

    def act(self, pose) -> int:
        """Action for robot pose ``(x, y, yaw)``."""
        if self.goal is None:
            raise RuntimeError("call reset(goal_xy) first")
        xy = np.asarray(pose[:2], dtype=np.float64)
        if self.stop is not None:
            geo = self.nav.lookup(self._field, xy)
            if geo <= self.task.success_radius - self.config.stop_margin:
                return self.driver.remember(self.stop, xy)
        return self.driver.drive(xy, float(pose[2]), self.goal)

    def aim_point(self, xy) -> np.ndarray:
        """The farthest point within ``lookahead`` along the shortest path that is in straight reach."""
        return self.driver.aim_point(xy, self.goal)

    def aim_angle(self, xy, yaw: float) -> float:
        """Heading error toward the aim point, radians, positive = to the left."""
        return self.driver.aim_angle(xy, yaw, self.goal)

    def executed(self, action: int) -> None:
        """The action actually executed after the last ``act`` (differs under noise injection): the
        blocked-move check compares against it."""
        self.driver.executed(action)
