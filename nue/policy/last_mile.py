"""SLING-style last mile (Wasserman et al., CoRL 2022) as a wrapper around any agent of the loop.

:class:`LastMileAgent` lets the wrapped agent act until the goal photo can be located from the robot's own
frames (:mod:`nue.policy.goal_pose`: SIFT matches, the current depth, PnP-RANSAC, a running estimate in world
coordinates); from then on a point-goal controller drives to the estimated goal on the robot's own depth-built
map (:mod:`nue.policy.seen_map`, steered by the experts' :class:`nue.sim.expert.PathDriver`). Control goes back
to the wrapped agent when the estimate is dropped: by inconsistent measurements, by reaching it while the
episode goes on (it was wrong: success would have ended the episode), when the map shows no way to it, or
after ``max_drive_steps``. The wrapped agent is asked for an action at every step, also while the controller
drives (its recurrent state and action sampling stay those of the unwrapped agent, so an episode is the same
as without the wrapper until the first acceptance).

The wrapper reads from the env only the task (camera, actions) and the floor height at ``reset``; never the
scene, its navigation grid or the goal. :meth:`LastMileAgent.summary` writes its decisions for the record;
the estimate's error against the true goal is computed there from a goal position the caller passes after
the episode, for analysis only.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from nue.errors import ConfigError
from nue.policy.commit import LearnedGoalLocator, LearnedLocatorConfig
from nue.policy.goal_pose import GoalPoseConfig, GoalPoseEstimator, GoalTracker, TrackerConfig
from nue.policy.protocols import tell_executed
from nue.policy.seen_map import SeenMap, SeenMapConfig
from nue.sim.expert import ExpertConfig, PathDriver

SLING_PREFIX = "sling+"
"""A method named ``sling+<name>`` in ``nue eval`` runs checkpoint ``<name>`` wrapped in :class:`LastMileAgent`."""


@dataclass(frozen=True)
class LastMileConfig:
    """The last-mile wrapper: matching schedule, estimate, map and controller (steps, metres)."""

    pose: GoalPoseConfig = field(default_factory=GoalPoseConfig)
    """Matching and pose acceptance per frame."""
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    """How measurements make, refine and drop the running estimate."""
    map: SeenMapConfig = field(default_factory=SeenMapConfig)
    """The robot's own map and planning on it."""
    match_every: int = 4
    """Match the goal photo every this-many steps while the wrapped agent drives (SIFT costs ~10 ms a frame)."""
    match_every_driving: int = 2
    """... and while the controller drives (refines the estimate as the robot closes in)."""
    follow_up_matches: int = 8
    """After an attempt with at least this many ratio-test matches the next step is matched too, whatever the
    schedule (views that locate the goal come in short runs; on FR's near misses of val252 this located the goal
    in 8 of 14 episodes instead of 5, for 17% more matching)."""
    map_every: int = 2
    """Add every this-many-th depth frame to the map (every frame while the controller drives)."""
    lookahead: float = 0.8
    """The controller aims at the farthest point of its path within this distance that is in straight reach."""
    arrive_radius: float = 0.3
    """Within this of the estimate with the episode still running, the estimate was wrong: dropped."""
    stop_margin: float = 0.25
    """With a STOP action: stop when the estimate is nearer than the success radius minus this."""
    max_unreachable: int = 5
    """Dropped after this many steps in a row without a path to the estimate on the map."""
    max_drive_steps: int = 120
    """Dropped after this many steps of driving toward one estimate."""
    locator: str = "sift"
    """Where measurements come from: ``sift`` (SLING's keypoints and PnP, :mod:`nue.policy.goal_pose`) or
    ``learned`` (the wrapped policy's goal head, :mod:`nue.policy.commit`; the ``commit+`` methods)."""
    learned: LearnedLocatorConfig = field(default_factory=LearnedLocatorConfig)
    """The learned locator's settings (``locator="learned"``)."""
    reject_inside_success: bool = False
    """Reject a measurement that puts the goal within the task's success radius of the robot when success needs no
    STOP: the episode would have ended, so that goal is a look-alike elsewhere (a repeated texture seen close up)."""

    def __post_init__(self) -> None:
        if self.locator not in LOCATORS:
            raise ValueError(f"last-mile locator must be one of {', '.join(LOCATORS)}, got {self.locator!r}")

    def to_dict(self) -> dict:
        """Every setting as plain JSON values (nested dicts), as records store it; the locator's entries only when
        it is not ``sift`` and ``reject_inside_success`` only when on (records from before they existed keep their exact
        settings)."""
        d = dataclasses.asdict(self)
        if self.locator == "sift":
            del d["locator"], d["learned"]
        if not self.reject_inside_success:
            del d["reject_inside_success"]
        return d

    def replace(self, **changes) -> "LastMileConfig":
        return dataclasses.replace(self, **changes)

    @classmethod
    def from_dict(cls, data: Any, where: str = "last-mile settings") -> "LastMileConfig":
        """The config from :meth:`to_dict`'s nested form; keys left out keep their defaults (so ``{"pose":
        {"contrast_threshold": 0.01}}`` changes one setting). An unknown key or a value of the wrong kind is a
        :class:`~nue.errors.ConfigError` naming ``where`` and the key."""
        return _build(cls, data, where, "")


def _build(cls, data: Any, where: str, prefix: str):
    if not isinstance(data, dict):
        raise ConfigError(where, f"{prefix.rstrip('.') or 'the settings'}: expected an object of settings, got {data!r}")
    defaults = cls()
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ConfigError(where, f"unknown setting(s) {', '.join(prefix + k for k in unknown)} "
                                 f"(known: {', '.join(sorted(names))})")
    kwargs = {}
    for key, value in data.items():
        default = getattr(defaults, key)
        if dataclasses.is_dataclass(default):
            kwargs[key] = _build(type(default), value, where, f"{prefix}{key}.")
        elif isinstance(default, bool) != isinstance(value, bool) or (
                isinstance(default, (int, float)) and not isinstance(value, (int, float))) or (
                isinstance(default, str) and not isinstance(value, str)):
            raise ConfigError(where, f"{prefix}{key}: expected a value like {default!r}, got {value!r}")
        elif isinstance(default, int) and not isinstance(default, bool) and not float(value).is_integer():
            raise ConfigError(where, f"{prefix}{key}: expected an integer, got {value!r}")
        else:
            kwargs[key] = type(default)(value) if isinstance(default, (int, float)) else value
    try:
        return cls(**kwargs)
    except (ValueError, TypeError) as e:
        raise ConfigError(where, f"{prefix.rstrip('.') or 'settings'}: {e}") from None


LOCATORS = ("sift", "learned")

COMMIT_LAST_MILE = LastMileConfig(locator="learned", match_every=1, match_every_driving=1, follow_up_matches=10**6,
                                  learned=LearnedLocatorConfig(min_view_probability=0.9))
"""The ``commit+`` methods' wrapper: the learned locator, read at every step (it costs nothing), measuring at an in-view
probability of 0.9: on the v6 demonstrations' held-out steps the highest threshold of 0.5 / 0.7 / 0.8 / 0.9 / 0.95 at
which ``nue_match`` (seed 0) still recalls half the in-view steps (precision 0.55;
``results/diagnostics/goal_head_nue_match_s0.cog.json``)."""


class LastMileAgent:
    """Wraps an :class:`~nue.policy.protocols.Agent`: ``inner`` acts until a goal estimate is accepted, then the
    controller.

    After an episode, ``events`` lists ``(step, what, detail)`` and :meth:`summary` gives the record's entry.
    """

    def __init__(self, inner, config: LastMileConfig = LastMileConfig()):
        self.inner, self.config = inner, config
        self.git_commit = getattr(inner, "git_commit", "")
        """The wrapped policy's training commit (recorded with evaluation records)."""

    # -- the Agent protocol ---------------------------------------------------------------------
    def reset(self, env, obs: dict[str, np.ndarray], seed: int = 0) -> None:
        """New episode: reset the wrapped agent; an empty map centred on the start, the goal photo's keypoints."""
        self.inner.reset(env, obs, seed)
        cfg, task = self.config, env.task
        self.task = task
        self.estimator: GoalPoseEstimator | LearnedGoalLocator
        if cfg.locator == "learned":
            self.estimator = LearnedGoalLocator(self.inner, cfg.learned)
        else:
            self.estimator = GoalPoseEstimator(task.camera, env.floor_z, cfg.pose)
        self.estimator.set_goal(obs["goal"])
        self.tracker = GoalTracker(cfg.tracker)
        self.map = SeenMap(task.camera, env.floor_z, obs["pose"][:2], cfg.map)
        self.driver = PathDriver(self.map, task, ExpertConfig(lookahead=cfg.lookahead))
        self.stop = task.action_id("STOP")
        self.t = -1
        self.driving = False
        self.follow_up = False
        self.drive_steps = 0
        self.unreachable = 0
        self.events: list[tuple[int, str, Any]] = []
        self.measurements: list[tuple[int, float, float, float, int, float]] = []
        """(step, x, y, yaw, inliers, distance) of every measurement that passed the per-frame checks."""
        self.timing = {"match": 0.0, "map": 0.0, "drive": 0.0, "matches": 0}
        self.control_steps = 0
        self.inner_actions = 0

    def act(self, obs: dict[str, np.ndarray], maps) -> int:
        """This step's action: the wrapped agent's, or the controller's while an accepted estimate stands."""
        cfg = self.config
        self.t += 1
        inner_action = int(self.inner.act(obs, maps))
        pose = np.asarray(obs["pose"], dtype=np.float64)
        t0 = time.perf_counter()
        self.map.add_position(pose[:2])
        if self.driving or self.t % cfg.map_every == 0:
            self.map.add_frame(obs["depth"], pose)
        t1 = time.perf_counter()
        if self.follow_up or self.t % (cfg.match_every_driving if self.driving else cfg.match_every) == 0:
            self._measure(obs, pose)
            self.follow_up = self.estimator.report.matches >= cfg.follow_up_matches
        t2 = time.perf_counter()
        action = self._drive(pose) if self.tracker.accepted else None
        t3 = time.perf_counter()
        self.timing["map"] += t1 - t0
        self.timing["match"] += t2 - t1
        self.timing["drive"] += t3 - t2
        if action is None:
            self.driving = False
            self.inner_actions += 1
            return inner_action
        self.control_steps += 1
        if action != inner_action:
            tell_executed(self.inner, action)
        return action

    def executed(self, action: int) -> None:
        """Told by an outer wrapper which action was executed (the steering's blocked-move check uses it)."""
        if self.driving:
            self.driver.executed(action)
        tell_executed(self.inner, action)

    # -- internals ------------------------------------------------------------------------------
    def _measure(self, obs, pose) -> None:
        self.timing["matches"] += 1
        m = self.estimator.estimate(obs["rgb"], obs["depth"], pose)
        if m is None:
            return
        if (self.config.reject_inside_success and not self.task.success_requires_stop
                and m.distance < self.task.success_radius):
            self.events.append((self.t, "reject_inside_success", round(float(m.distance), 3)))
            return
        self.measurements.append((self.t, float(m.xy[0]), float(m.xy[1]), float(m.yaw), m.inliers, m.distance))
        if len(self.measurements) == 1:
            self.events.append((self.t, "first_match", m.inliers))
        before = None if self.tracker.xy is None else _rounded(self.tracker.xy)
        what = self.tracker.update(m)
        if what == "dropped":
            self.events.append((self.t, "drop_inconsistent", before))
            self._hand_back(None)
        if what == "accepted" or (what == "dropped" and self.tracker.accepted):
            self.events.append((self.t, "accepted", _rounded(self.tracker.xy)))

    def _drive(self, pose) -> int | None:
        """The controller's action toward the accepted estimate, or None after dropping it."""
        cfg = self.config
        if not self.driving:
            self.driving, self.drive_steps, self.unreachable = True, 0, 0
            self.driver.reset()
        self.drive_steps += 1
        xy, goal = pose[:2], self.tracker.xy
        dist = float(np.linalg.norm(goal - xy))
        if self.stop is not None and dist <= self.task.success_radius - cfg.stop_margin:
            return self.driver.remember(self.stop, xy)
        if dist <= cfg.arrive_radius:
            return self._hand_back("arrived")
        if self.drive_steps > cfg.max_drive_steps:
            return self._hand_back("timeout")
        if not self.map.reachable(xy, goal):
            self.unreachable += 1
            if self.unreachable >= cfg.max_unreachable:
                return self._hand_back("unreachable")
            return self.driver.drive(xy, float(pose[2]), goal, safe=True)
        self.unreachable = 0
        return self.driver.drive(xy, float(pose[2]), goal, safe=True)

    def _hand_back(self, reason: str | None) -> None:
        """Drop the estimate (``reason`` None: the tracker already did) and give control back."""
        if reason is not None:
            self.events.append((self.t, f"drop_{reason}", _rounded(self.tracker.xy)))
            self.tracker.drop(disproved=reason in ("arrived", "unreachable"))
        self.driving = False
        return None

    # -- the record -----------------------------------------------------------------------------
    def summary(self, goal_xy=None) -> dict:
        """The record's ``extra["last_mile"]``: first match and acceptance steps, events, measurements, steps
        under control, time spent (ms per step, by part) and, given the true ``goal_xy`` (analysis only, after
        the episode), the error of every measurement, accepted estimate and the final estimate (metres)."""
        steps = max(self.t + 1, 1)
        first = {what: next((s for s, w, _ in self.events if w == what), None) for what in ("first_match", "accepted")}
        out: dict[str, Any] = {
            "first_match_step": first["first_match"],
            "first_accept_step": first["accepted"],
            "events": [[s, w, d] for s, w, d in self.events],
            "measurements": [[s, round(x, 3), round(y, 3), round(yaw, 4), n, round(d, 3)]
                             for s, x, y, yaw, n, d in self.measurements],
            "control_steps": self.control_steps,
            "estimate": None if self.tracker.xy is None else _rounded(self.tracker.xy),
            "estimate_accepted": bool(self.tracker.accepted),
            "match_calls": self.timing["matches"],
            "ms_per_step": {k: round(1000 * self.timing[k] / steps, 3) for k in ("match", "map", "drive")},
        }
        if goal_xy is not None:
            g = np.asarray(goal_xy, dtype=np.float64)[:2]
            err = lambda xy: round(float(np.linalg.norm(np.asarray(xy, dtype=np.float64) - g)), 3)  # noqa: E731
            out["measurement_errors"] = [err((x, y)) for _, x, y, *_ in self.measurements]
            out["accepted_errors"] = [err(d) for _, w, d in self.events if w == "accepted"]
            out["estimate_error"] = None if self.tracker.xy is None else err(self.tracker.xy)
        return out


def _rounded(xy) -> list[float]:
    """World (x, y) as a JSON pair rounded to the millimetre."""
    return [round(float(xy[0]), 3), round(float(xy[1]), 3)]
