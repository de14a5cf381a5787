"""``ImageNavEnv``: the gymnasium environment of image-goal navigation in a Gibson-layout scene.

Observation: ``rgb`` (H, W, 3) uint8, ``depth`` (H, W, 1) float32 metres (z-depth, 0 = no surface),
``pose`` (x, y, yaw) float32 and ``goal`` (H, W, 3) uint8, the photo taken at the goal pose. Actions
and rules come from a task preset (:mod:`nue.sim.task`). The robot is a disc that never enters
non-traversable space: a blocked forward move slides along the obstacle (or stops, per preset) and
counts one collision. An episode's start or goal off the navigable cells is snapped
(:meth:`nue.scene.navgrid.NavGrid.snap`): the robot starts at the snapped start, geodesics and the
expert use the snapped goal, the goal photo and Euclidean distances use the goal as given; records
then carry ``extra["start_snap"]`` / ``extra["goal_snap"]`` (metres). Success ends the episode
(``terminated``); the step limit truncates it.
Reward (for RL users; imitation learning ignores it): decrease of geodesic distance to the goal,
+2.5 on success, -0.01 per step.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path
from typing import Any, Sequence

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from nue.scene.navgrid import NavGrid
from nue.scene.scene import Scene
from nue.sim.camera import wrap_angle
from nue.sim.episode_gen import EpisodeGenConfig, generate_episodes
from nue.sim.episodes import Episode, validate_episode
from nue.sim.record import TRAJECTORY_KEY, EpisodeRecord, Trajectory
from nue.sim.renderer import Renderer
from nue.sim.task import TaskConfig, get_task

SUCCESS_REWARD = 2.5
SLACK_REWARD = -0.01
_SUBSTEP = 0.02  # metres per collision-check sub-step of a forward move


class ImageNavEnv(gym.Env):
    """Image-goal navigation in one scene (one floor), gymnasium API."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        scene: Scene | str,
        task: TaskConfig | str = "paper",
        episodes: Sequence[Episode] | None = None,
        floor: int = 0,
        renderer: Renderer | None = None,
        navgrid: NavGrid | None = None,
        render_mode: str | None = None,
    ):
        """``episodes``: the episodes ``reset`` draws from (or that ``options={'episode_index': i}``
        selects); without them, ``reset`` generates a random episode from its seed."""
        self.scene = scene if isinstance(scene, Scene) else Scene.load(scene)
        self.task = get_task(task)
        self.floor = floor
        self.floor_z = self.scene.floor_heights[floor]
        self.navgrid = navgrid or NavGrid.from_scene(self.scene, floor)
        self.renderer = renderer or Renderer(self.scene, self.task.camera)
        self.episodes = list(episodes) if episodes is not None else None
        for ep in self.episodes or []:
            validate_episode(ep, self.navgrid, where=f"{self.scene.name}")
        self.render_mode = render_mode
        cam = self.task.camera
        h, w = cam.height, cam.width
        size = self.scene.trav_maps[floor].shape[0] * self.scene.resolution / 2
        half_extent = np.array([size, size, math.pi], dtype=np.float32)
        self.observation_space = spaces.Dict(
            {
                "rgb": spaces.Box(0, 255, (h, w, 3), np.uint8),
                "depth": spaces.Box(0.0, np.float32(cam.far), (h, w, 1), np.float32),
                "pose": spaces.Box(-half_extent, half_extent, (3,), np.float32),
                "goal": spaces.Box(0, 255, (h, w, 3), np.uint8),
            }
        )
        self.action_space = spaces.Discrete(len(self.task.actions))
        self.episode: Episode | None = None
        self._obs: dict[str, np.ndarray] | None = None

    # -- gymnasium API -------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        options = options or {}
        if "episode" in options:
            ep = options["episode"]
            validate_episode(ep, self.navgrid)
        elif self.episodes:
            i = options.get("episode_index", int(self.np_random.integers(len(self.episodes))))
            ep = self.episodes[i]
        else:
            ep = self._random_episode()
        self.episode = ep
        self.pose = np.asarray(ep.start_pose, dtype=np.float64)
        start_xy, start_snap = self.navgrid.snap(self.pose[:2])
        self.pose[:2] = start_xy  # the start itself unless it had to be snapped
        self.goal_xy = np.asarray(ep.goal_position[:2], dtype=np.float64)
        """The goal as given (Euclidean distance, goal angle; the goal photo is taken here)."""
        goal_xy, goal_snap = self.navgrid.snap(self.goal_xy, on_cell=True)
        self.nav_goal_xy = np.asarray(goal_xy, dtype=np.float64)
        """The goal for geodesics and the expert: ``goal_xy`` unless it had to be snapped to a navigable cell."""
        self._field = self.navgrid.distance_field(self.nav_goal_xy)
        self.snap = {k: round(v, 6) for k, v in (("start_snap", start_snap), ("goal_snap", goal_snap)) if v > 0}
        """Metres the start / goal were snapped to navigable cells (only those that were), for the record."""
        self.goal_image, _ = self.renderer.render(ep.goal_pose, self.floor_z)
        if "goal_image" in options:  # e.g. a photo from another house: the exploration benchmark's nothing-to-find goal
            self.goal_image = np.array(options["goal_image"], dtype=np.uint8).reshape(self.goal_image.shape)
        self.explore_only = bool(options.get("explore_only", False))
        """Success never ends the episode (nor counts): it runs to the step limit (the exploration benchmark)."""
        self.steps = 0
        self.collisions = 0
        self.path_length = 0.0
        self.success = False
        self.done = False
        self.geodesic_start = self.navgrid.lookup(self._field, self.pose[:2])
        self.trajectory = [self.pose.copy()]
        self.actions: list[int] = []
        self.collided: list[bool] = []
        self._geo = self.geodesic_start
        self._t0 = time.perf_counter()
        self._obs = self._observe()
        return self._obs, self._info(collided=False)

    def step(self, action):
        if self.episode is None:
            raise RuntimeError("call reset() before step()")
        if self.done:
            raise RuntimeError("episode is over; call reset()")
        if not self.action_space.contains(action):
            raise ValueError(f"invalid action {action!r} for {self.action_space}")
        name = self.task.actions[int(action)]
        collided = False
        stop = False
        if name == "MOVE_FORWARD":
            new_xy, collided = self._move(self.pose[:2], self.pose[2], self.task.forward_step)
            self.path_length += float(np.linalg.norm(new_xy - self.pose[:2]))
            self.pose[:2] = new_xy
        elif name == "TURN_LEFT":
            self.pose[2] = wrap_angle(self.pose[2] + self.task.turn_angle)
        elif name == "TURN_RIGHT":
            self.pose[2] = wrap_angle(self.pose[2] - self.task.turn_angle)
        elif name == "STOP":
            stop = True
        self.steps += 1
        self.collisions += int(collided)
        self.trajectory.append(self.pose.copy())
        self.actions.append(int(action))
        self.collided.append(bool(collided))
        prev_geo = self._geo
        self._geo = self.navgrid.lookup(self._field, self.pose[:2])
        inside = self._distance_for_success() <= self.task.success_radius
        if self.explore_only:
            terminated = False
            self.success = False
        elif self.task.success_requires_stop:
            terminated = stop
            self.success = stop and inside
        else:
            terminated = inside
            self.success = inside
        truncated = not terminated and self.steps >= self.task.max_steps
        self.done = terminated or truncated
        progress = prev_geo - self._geo if math.isfinite(prev_geo) and math.isfinite(self._geo) else 0.0
        reward = float(progress + SLACK_REWARD + (SUCCESS_REWARD if self.success else 0.0))
        self._obs = self._observe()
        return self._obs, reward, terminated, truncated, self._info(collided)

    def render(self):
        if self.render_mode == "rgb_array" and self._obs is not None:
            return self._obs["rgb"]
        return None

    def close(self):
        pass

    # -- helpers -------------------------------------------------------------------------------
    @property
    def euclidean_distance(self) -> float:
        return float(np.linalg.norm(self.pose[:2] - self.goal_xy))

    @property
    def geodesic_distance(self) -> float:
        return float(self._geo)

    @property
    def goal_field(self) -> np.ndarray:
        """(M, M) geodesic distance to the episode's navigation goal on ``navgrid``'s cells, metres (inf = unreachable)."""
        return self._field

    def goal_angle(self) -> float:
        """Signed angle from the heading to the goal direction, positive = goal to the left, in (-pi, pi]."""
        d = self.goal_xy - self.pose[:2]
        return wrap_angle(math.atan2(d[1], d[0]) - self.pose[2])

    def episode_record(self, method: str = "", **extra) -> EpisodeRecord:
        """The :class:`EpisodeRecord` of the current (finished or not) episode."""
        ep = self.episode
        return EpisodeRecord(
            episode_id=ep.episode_id,
            scene=ep.scene or self.scene.name,
            difficulty=ep.difficulty,
            success=bool(self.success),
            geodesic_start=float(self.geodesic_start),
            path_length=float(self.path_length),
            final_geodesic=float(self._geo),
            final_euclidean=self.euclidean_distance,
            success_radius=self.task.success_radius,
            collisions=int(self.collisions),
            steps=int(self.steps),
            path_type=ep.path_type,
            method=method,
            wall_time=time.perf_counter() - self._t0,
            extra={TRAJECTORY_KEY: self.trajectory_so_far().encode(), **self.snap, **extra},
        )

    def trajectory_so_far(self) -> Trajectory:
        """Actions, blocked-move flags and poses of the current episode so far."""
        return Trajectory(np.array(self.actions, dtype=np.int64), np.array(self.collided, dtype=bool),
                          np.array(self.trajectory, dtype=np.float64).reshape(-1, 3))

    def _distance_for_success(self) -> float:
        return self._geo if self.task.success_metric == "geodesic" else self.euclidean_distance

    def _observe(self) -> dict[str, np.ndarray]:
        rgb, depth = self.renderer.render(self.pose, self.floor_z)
        return {
            "rgb": rgb,
            "depth": depth[..., None],
            "pose": self.pose.astype(np.float32),
            "goal": self.goal_image.copy(),
        }

    def _info(self, collided: bool) -> dict[str, Any]:
        return {
            "episode_id": self.episode.episode_id,
            "difficulty": self.episode.difficulty,
            "success": bool(self.success),
            "collided": bool(collided),
            "collisions": int(self.collisions),
            "geodesic_distance": float(self._geo),
            "euclidean_distance": self.euclidean_distance,
            "path_length": float(self.path_length),
            "steps": int(self.steps),
            "goal_angle": self.goal_angle(),
        }

    def _move(self, xy: np.ndarray, yaw: float, dist: float) -> tuple[np.ndarray, bool]:
        """Move the disc ``dist`` metres along ``yaw``; on contact slide along the free axis (or stop)."""
        n = max(1, int(math.ceil(dist / _SUBSTEP)))
        delta = np.array([math.cos(yaw), math.sin(yaw)]) * (dist / n)
        pos = xy.copy()
        collided = False
        nav = self.navgrid
        for _ in range(n):
            if nav.is_free(pos + delta):
                pos = pos + delta
                continue
            collided = True
            if self.task.collision != "slide":
                break
            parts = sorted((delta * [1.0, 0.0], delta * [0.0, 1.0]), key=lambda p: -abs(p).sum())
            for part in parts:
                if abs(part).sum() > 1e-9 and nav.is_free(pos + part):
                    pos = pos + part
                    break
            else:
                break
        return pos, collided

    def _random_episode(self) -> Episode:
        bins = self.task.bins.names
        b = bins[int(self.np_random.integers(len(bins)))]
        seed = int(self.np_random.integers(2**31))
        return generate_episodes(
            self.scene,
            self.task,
            EpisodeGenConfig(per_bin=1),
            seed=seed,
            floor=self.floor,
            navgrid=self.navgrid,
            renderer=self.renderer,
            bins=(b,),
        )[0]


def make_env(scene: Scene | str | Path, task: TaskConfig | str = "paper", max_steps: int = 0,
             episodes: Sequence[Episode] | None = None) -> ImageNavEnv:
    """The environment of a scene (a loaded :class:`Scene` or a Gibson-layout folder) and a task preset,
    with the preset's step limit replaced by ``max_steps`` when it is > 0 (smoke runs, model selection);
    the env builds its own navigation grid and renderer. The one setup path of eval, collect and the demo."""
    task = get_task(task)
    if max_steps:
        task = dataclasses.replace(task, max_steps=max_steps)
    return ImageNavEnv(scene if isinstance(scene, Scene) else Scene.load(scene), task, episodes)
