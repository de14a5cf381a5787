"""The uncertainty-seeking expert: explores toward the heading its own memory renders as most uncertain, then (goal in
view) hands over to the geodesic expert.

An expert whose choices the policy can read: while exploring it picks the heading from the memory's panorama of
I_u (``MemoryMaps.panorama``, :meth:`nue.nerf.online.OnlineNeRF.render_panorama`, which a policy given the same
panorama sees too) — the view with the highest mean uncertainty among those the robot can drive into — and drives
to a point up to ``reach`` metres that way. The goal switch is the exploring expert's (the goal's cell seen in
the current depth frame within ``view_range``, :func:`nue.sim.seen.goal_in_view`); after it, or after
``max_explore_steps``, it is the geodesic expert. Driving uses the navigation grid (which straight segments
are free, the geodesic expert's steering), as the frontier expert does; *where* to go follows from the
panorama alone. Deterministic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nue.scene.navgrid import NavGrid
from nue.sim.expert import ExpertConfig, GeodesicExpert
from nue.sim.seen import goal_in_view
from nue.sim.task import TaskConfig, get_task


@dataclass(frozen=True)
class UncertaintyExpertConfig:
    """Behaviour of the uncertainty-seeking expert (distances in metres)."""

    view_range: float = 3.0
    """The goal is in view when its cell is seen in the current frame at most this far away (the exploring expert's)."""
    max_explore_steps: int = 250
    """After this many exploring steps the geodesic expert takes over (every episode finishes)."""
    reach: float = 2.0
    """A heading's target is the farthest point along it, up to this far, that a straight free segment reaches."""
    min_reach: float = 0.5
    """Headings whose free reach is shorter are not chosen (facing a wall)."""
    keep_steps: int = 12
    """A target is kept this many steps unless reached earlier (no dithering between near-equal headings)."""
    reach_dist: float = 0.3
    """A target this close counts as reached."""


class UncertaintyExpert:
    """``act(pose, depth, panorama)`` -> an action id of the task preset; ``reset(goal_xy)`` per episode. After an
    episode ``mode`` and ``stats`` (steps, exploring steps, switch reason and step, targets chosen) tell what it did."""

    def __init__(self, navgrid: NavGrid, task: TaskConfig | str = "paper",
                 config: UncertaintyExpertConfig = UncertaintyExpertConfig(),
                 expert_config: ExpertConfig = ExpertConfig(), floor_z: float = 0.0):
        self.nav, self.task, self.config, self.floor_z = navgrid, get_task(task), config, float(floor_z)
        self.geodesic = GeodesicExpert(navgrid, self.task, expert_config)
        self.driver = self.geodesic.driver
        self.goal = None

    def reset(self, goal_xy) -> None:
        self.goal = np.asarray(goal_xy, dtype=np.float64)[:2]
        self.geodesic.reset(self.goal)
        self._goal_cell = tuple(int(v) for v in self.nav.cell_of(self.goal))
        self.mode = "explore"
        self.target: np.ndarray | None = None
        self._target_age = 0
        self.stats = {"steps": 0, "explore_steps": 0, "switch": None, "switch_step": None, "targets": 0}

    def act(self, pose, depth, panorama) -> int:
        """Action for pose ``(x, y, yaw)``, depth frame (H, W[, 1]) metres and I_u panorama ``(K, hp, wp)`` (array or
        tensor; view k heads ``yaw + 2 pi k / K``)."""
        if self.goal is None:
            raise RuntimeError("call reset(goal_xy) first")
        st, cfg = self.stats, self.config
        st["steps"] += 1
        if self.mode == "explore":
            xy, yaw = np.asarray(pose[:2], dtype=np.float64), float(pose[2])
            if goal_in_view(depth, pose, self._goal_cell, self.goal, self.task.camera, self.nav, self.floor_z,
                            cfg.view_range):
                self._switch("goal_in_view")
            elif st["explore_steps"] >= cfg.max_explore_steps:
                self._switch("budget")
            else:
                action = self._explore(xy, yaw, panorama)
                if action is not None:
                    st["explore_steps"] += 1
                    return action
                self._switch("no_heading")
        return self.geodesic.act(pose)

    def executed(self, action: int) -> None:
        """The action actually executed after the last ``act`` (differs under noise injection)."""
        self.driver.executed(action)

    def heading_scores(self, panorama) -> np.ndarray:
        """Mean I_u per view ``(K,)``."""
        p = panorama.detach().float().cpu().numpy() if hasattr(panorama, "detach") else np.asarray(panorama, dtype=float)
        return p.reshape(p.shape[0], -1).mean(axis=1)

    def _explore(self, xy: np.ndarray, yaw: float, panorama) -> int | None:
        cfg = self.config
        if self.target is not None:
            self._target_age += 1
            if np.linalg.norm(self.target - xy) <= cfg.reach_dist or self._target_age > cfg.keep_steps:
                self.target = None
        if self.target is None:
            scores = self.heading_scores(panorama)
            k = len(scores)
            best = None
            for i in np.argsort(-scores, kind="stable"):  # most uncertain first, ties to the robot's own heading
                point, dist = self._free_reach(xy, yaw + 2.0 * math.pi * int(i) / k)
                if dist >= cfg.min_reach:
                    best = point
                    break
            if best is None:
                return None
            self.target, self._target_age = best, 0
            self.stats["targets"] += 1
        return self.driver.drive(xy, yaw, self.target, safe=True)

    def _free_reach(self, xy: np.ndarray, heading: float) -> tuple[np.ndarray, float]:
        """The farthest point along ``heading`` within ``reach`` up to which the straight segment from ``xy`` stays
        free (checked every 2 cm), and its distance."""
        step = 0.02
        t = np.arange(1, int(round(self.config.reach / step)) + 1) * step
        pts = xy[None, :] + t[:, None] * np.array([math.cos(heading), math.sin(heading)])[None, :]
        free = np.asarray(self.nav.is_free(pts), dtype=bool)
        n = int(np.argmin(free)) if not free.all() else len(t)
        return (pts[n - 1], float(t[n - 1])) if n else (xy, 0.0)

    def _switch(self, reason: str) -> None:
        self.mode, self.target = "geodesic", None
        self.stats["switch"], self.stats["switch_step"] = reason, self.stats["steps"] - 1
