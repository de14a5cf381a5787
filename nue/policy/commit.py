"""The policy's own exploitation signal as a goal locator: the ``commit+`` wrapper's measurements.

A NUE model with ``goal_head`` predicts, from f_cog, whether the goal is in view (the exploring expert's switch
test) and how far it is; its auxiliary head predicts the goal's angle. :class:`LearnedGoalLocator` turns one step's
three outputs into a goal measurement in world coordinates,

    xy_goal = xy + d * (cos(yaw + a), sin(yaw + a))      when p_view >= min_view_probability,

weighted ``weight * p_view``, where the bearing ``a`` is 0 (``bearing="ahead"``, the default: the goal straight ahead)
or the auxiliary head's goal angle (``bearing="aux"``); docs/exploration.md says why straight ahead is the default.
The measurements go to the last-mile wrapper (:class:`nue.policy.last_mile.LastMileAgent` with
``locator="learned"``), which keeps the running estimate, commits to it once consistent measurements add up, and
drives there on the robot's own depth-built map. It replaces SLING's keypoint matching with what the policy
learned; the controller, the estimate's bookkeeping and the hand-back are the same. No scene or true goal is read.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nue.policy.goal_pose import GoalMeasurement, MatchReport

COMMIT_PREFIX = "commit+"
"""A method named ``commit+<name>`` in ``nue eval`` runs checkpoint ``<name>`` (a model with ``goal_head``) wrapped
in the last-mile agent with the learned locator."""


BEARINGS = ("ahead", "aux")
"""The learned locator's bearing sources (:attr:`LearnedLocatorConfig.bearing`)."""


@dataclass(frozen=True)
class LearnedLocatorConfig:
    """When one step's head outputs make a measurement, and its weight."""

    min_view_probability: float = 0.5
    """A step makes a measurement when the goal-in-view probability is at least this."""
    weight: float = 10.0
    """A measurement's weight (the tracker's "inliers") is ``weight * p_view``: with the tracker's
    ``accept_inliers`` = 20, about two confident steps that agree commit the robot."""
    max_distance: float = 4.0
    """Predicted distances beyond this (metres) make no measurement (the head is trained on in-view steps, <= 3 m)."""
    bearing: str = "ahead"
    """Where the goal is relative to the heading: ``ahead`` (straight ahead) or ``aux`` (the auxiliary angle head)."""

    def __post_init__(self) -> None:
        if self.bearing not in BEARINGS:
            raise ValueError(f"unknown bearing {self.bearing!r}; known: {', '.join(BEARINGS)}")


class LearnedGoalLocator:
    """Measurements from the wrapped policy's last outputs (``last_goal_view``, ``last_goal_distance``, ``last_aux``
    of :class:`nue.policy.agent.PolicyAgent`); same ``estimate`` / ``report`` interface as
    :class:`nue.policy.goal_pose.GoalPoseEstimator`. Call ``estimate`` after the policy acted on the same frame."""

    def __init__(self, policy, config: LearnedLocatorConfig = LearnedLocatorConfig()):
        if getattr(getattr(policy, "config", None), "goal_head", False) is not True:
            name = getattr(getattr(policy, "config", None), "name", type(policy).__name__)
            raise ValueError(f"the learned goal locator needs a model with goal_head; {name!r} has none")
        self.policy, self.config = policy, config
        self.report = MatchReport()

    def set_goal(self, goal_rgb: np.ndarray) -> None:
        """Nothing to prepare: the policy reads the goal photo itself."""

    def estimate(self, rgb: np.ndarray, depth: np.ndarray, pose) -> GoalMeasurement | None:
        """The goal position the policy's heads give at robot ``pose`` (x, y, yaw), or None (see :attr:`report`)."""
        cfg, pol = self.config, self.policy
        self.report = rep = MatchReport()
        p, d, a = pol.last_goal_view, pol.last_goal_distance, pol.last_aux
        if cfg.bearing == "ahead":
            a = 0.0
        if p is None or d is None or a is None:
            rep.reason = "no_head"
            return None
        rep.agreement = float(p)
        if p < cfg.min_view_probability:
            rep.reason = "not_in_view"
            return None
        if d > cfg.max_distance:
            rep.reason = "range"
            return None
        heading = float(pose[2]) + float(a)
        xy = np.asarray(pose[:2], dtype=np.float64) + d * np.array([math.cos(heading), math.sin(heading)])
        w = cfg.weight * float(p)
        rep.inliers = int(round(w))
        return GoalMeasurement(xy=xy, yaw=float("nan"), inliers=int(round(w)), matches=0, distance=float(d),
                               reprojection=0.0, agreement=float(p))
