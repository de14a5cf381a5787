"""The exploration -> exploitation hand-off of one episode: when the goal was first *seen*, how close the robot
came, and where a failed episode was lost.

An episode splits in two phases at the step the goal is first *in view* (the exploring expert's own switch,
:func:`nue.sim.seen.goal_in_view`: the goal's grid cell is seen as floor in the current depth frame and the robot is at most
``view_range`` = 3 m from the goal): steps before it are *search*, steps from it to the end *exploitation*. A
failed episode (every failure here is a time-out) is one of

- ``found_then_lost``: the goal was in view at some step, or the robot *approached* it (came within ``near``
  = 2 m geodesic after starting farther away), and the episode did not finish;
- ``near_unseen``: never in view and never approached, but within ``far`` = 3 m geodesic at some pose (a start
  already within 2 m that never turned to the goal lands here);
- ``never_near``: never in view and never within ``far``.

Everything here is a pure function of per-step values; :class:`GoalSightTracker` collects the one value the
agent loop must measure while it runs (the first in-view step) and :func:`handoff_of_record` recomputes all
of it for a finished record from its trajectory (re-rendering the depth where the goal may be in view).
Step t is the observation before action t (t = 0 at the start); poses are ``T + 1`` (before every action
and after the last), so a step index runs over 0..T.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Mapping, Sequence

import numpy as np

from nue.sim.seen import CoverageConfig, goal_in_view

HANDOFF_KEY = "handoff"
"""Key of ``EpisodeRecord.extra`` (and of a hand-off file's lines) holding a :class:`Handoff`'s dict."""
OUTCOMES = ("success", "found_then_lost", "near_unseen", "never_near")
"""The outcome classes, successes first."""
FAILURE_CLASSES = OUTCOMES[1:]


@dataclass(frozen=True)
class HandoffConfig:
    """Radii of the hand-off split (metres)."""

    view_range: float = 3.0
    """The goal is in view when its cell is seen in the current frame at most this far (straight line) from the
    robot: the exploring expert's switch (:class:`nue.sim.explorer.ExplorerConfig`)."""
    near: float = 2.0
    """Coming within this geodesic distance of the goal (from farther away) counts as having found it."""
    far: float = 3.0
    """A failure that never came within this geodesic distance and never saw the goal is ``never_near``."""
    seen: CoverageConfig = CoverageConfig()
    """Which depth pixels see floor (as the exploring expert's seen map)."""


@dataclass(frozen=True)
class Handoff:
    """The hand-off of one episode (see the module docstring)."""

    first_seen_step: int | None
    """First step at which the goal was in view; None if never."""
    first_near_step: int | None
    """First step at which the robot was within ``near`` geodesic of the goal; None if never."""
    closest_geodesic: float
    """Least geodesic distance to the goal over the episode's poses, metres."""
    closest_step: int
    """First step at which the robot was that close."""
    steps_near: int
    """Poses (of the T + 1) within ``near`` geodesic of the goal."""
    search_steps: int
    """Steps before the goal was first in view; all of them if it never was."""
    exploit_steps: int
    """Steps from the first in-view step to the end (0 if the goal was never in view)."""
    outcome: str
    """One of :data:`OUTCOMES`."""

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: Mapping) -> "Handoff":
        return cls(**{k: d[k] for k in cls.__dataclass_fields__})


def handoff(geodesic: Sequence[float] | np.ndarray, first_seen_step: int | None, success: bool,
            config: HandoffConfig = HandoffConfig()) -> Handoff:
    """The :class:`Handoff` of an episode from its per-pose geodesic distances to the goal ``(T + 1,)`` metres
    (``inf`` where unknown), its first in-view step and whether it succeeded.

    Example: geodesic ``[4, 3, 1.5, 2.5, 2.6]`` (T = 4), never in view, failed -> approached at step 2, closest
    1.5 m at step 2, 1 pose near, search 4 steps, exploitation 0, ``found_then_lost``; the same seen at step 1 ->
    search 1, exploitation 3.
    """
    g = np.asarray(geodesic, dtype=np.float64)
    if g.ndim != 1 or g.size == 0:
        raise ValueError("handoff: geodesic must be a non-empty (T + 1,) array")
    steps = g.size - 1
    near = np.flatnonzero(g <= config.near)
    first_near = int(near[0]) if near.size else None
    approached = first_near is not None and g[0] > config.near
    closest_step = int(np.argmin(g))
    seen = first_seen_step is not None
    if success:
        outcome = "success"
    elif seen or approached:
        outcome = "found_then_lost"
    elif g[closest_step] <= config.far:
        outcome = "near_unseen"
    else:
        outcome = "never_near"
    found = min(int(first_seen_step), steps) if seen else steps
    return Handoff(first_seen_step=int(first_seen_step) if seen else None, first_near_step=first_near,
                   closest_geodesic=round(float(g[closest_step]), 3), closest_step=closest_step,
                   steps_near=int(near.size), search_steps=found, exploit_steps=steps - found, outcome=outcome)


class GoalSightTracker:
    """An ``on_step`` callback of :func:`nue.rollout.run_episode` finding the first step the goal is in view.

    Reads the env's navigation goal at the first step; renders nothing (the step's own depth frame) and tests a
    frame only while the robot is within ``view_range`` of the goal and the goal has not been seen yet.
    """

    def __init__(self, config: HandoffConfig = HandoffConfig()):
        self.config = config
        self.first_seen_step: int | None = None
        self._goal = None

    def __call__(self, step) -> None:
        if self.first_seen_step is not None:
            return
        env = step.env
        if self._goal is None:
            self._goal = np.asarray(env.nav_goal_xy, dtype=np.float64)
            self._cell = tuple(int(v) for v in env.navgrid.cell_of(self._goal))
        if goal_in_view(step.obs["depth"], step.obs["pose"], self._cell, self._goal, env.task.camera, env.navgrid,
                        env.floor_z, self.config.view_range, self.config.seen):
            self.first_seen_step = int(step.t)


def geodesic_along(poses: np.ndarray, grid, field: np.ndarray) -> np.ndarray:
    """Geodesic distance to the goal ``(T + 1,)`` metres at every pose ``(T + 1, 3)`` of a trajectory, looked up in
    the goal's distance ``field`` of ``grid`` (:meth:`nue.scene.navgrid.NavGrid.lookup`)."""
    return np.array([grid.lookup(field, p[:2]) for p in np.asarray(poses)], dtype=np.float64)


def handoff_of_record(record, env, config: HandoffConfig = HandoffConfig()) -> Handoff:
    """Recompute a finished record's :class:`Handoff` in ``env`` (an :class:`~nue.sim.env.ImageNavEnv` reset to the
    record's episode): geodesic distances along its stored trajectory, and the first in-view step by rendering
    the depth at the stored poses (1 cm / 1 mrad) where the robot was within ``view_range`` of the goal."""
    traj = record.trajectory()
    if traj is None:
        raise ValueError(f"{record.method}/{record.scene}/{record.episode_id}: the record has no trajectory")
    goal = np.asarray(env.nav_goal_xy, dtype=np.float64)
    cell = tuple(int(v) for v in env.navgrid.cell_of(goal))
    first_seen = None
    poses = traj.poses
    close = np.flatnonzero(np.hypot(poses[:-1, 0] - goal[0], poses[:-1, 1] - goal[1]) <= config.view_range)
    for t in close:  # observations exist for steps 0..T-1 (the last pose is never observed by the agent)
        _, depth = env.renderer.render(poses[t], env.floor_z)
        if goal_in_view(depth, poses[t], cell, goal, env.task.camera, env.navgrid, env.floor_z, config.view_range,
                        config.seen):
            first_seen = int(t)
            break
    return handoff(geodesic_along(poses, env.navgrid, env.goal_field), first_seen, record.success, config)


def record_handoff(record) -> Handoff | None:
    """The :class:`Handoff` a record carries (``extra['handoff']``), or None."""
    d = record.extra.get(HANDOFF_KEY) if isinstance(record.extra, Mapping) else None
    return None if d is None else Handoff.from_dict(d)


@dataclass(frozen=True)
class HandoffSummary:
    """The hand-off of one method's episodes (medians over the episodes where the value exists)."""

    method: str
    episodes: int
    successes: int
    outcomes: dict
    """Outcome class -> episodes (:data:`OUTCOMES`)."""
    seen: int
    """Episodes in which the goal was in view at some step."""
    median_first_seen: float | None
    """Median first in-view step over the episodes that saw the goal."""
    median_search_success: float | None
    """Median search steps of the successes."""
    median_exploit_success: float | None
    """Median exploitation steps of the successes (from finding the goal to reaching it)."""
    median_steps_near_lost: float | None
    """Median poses within ``near`` of the goal of the ``found_then_lost`` failures."""
    median_closest_lost: float | None
    """Median closest geodesic approach of the ``found_then_lost`` failures, metres."""


def _median(xs) -> float | None:
    xs = [x for x in xs if x is not None]
    return float(np.median(xs)) if xs else None


def summarise(method: str, pairs: Sequence[tuple[bool, Handoff]]) -> HandoffSummary:
    """:class:`HandoffSummary` of ``(success, handoff)`` pairs of one method."""
    hs = [h for _, h in pairs]
    lost = [h for h in hs if h.outcome == "found_then_lost"]
    won = [h for s, h in pairs if s]
    return HandoffSummary(
        method=method, episodes=len(hs), successes=len(won), outcomes={k: sum(h.outcome == k for h in hs) for k in OUTCOMES},
        seen=sum(h.first_seen_step is not None for h in hs), median_first_seen=_median(h.first_seen_step for h in hs),
        median_search_success=_median(h.search_steps for h in won), median_exploit_success=_median(h.exploit_steps for h in won),
        median_steps_near_lost=_median(h.steps_near for h in lost), median_closest_lost=_median(h.closest_geodesic for h in lost))


def handoff_summaries(records: Sequence, method_of=lambda r: r.method) -> dict[str, HandoffSummary]:
    """Per method (sorted), the :class:`HandoffSummary` of its records that carry a hand-off."""
    by: dict[str, list] = {}
    for r in records:
        h = record_handoff(r)
        if h is not None:
            by.setdefault(method_of(r), []).append((bool(r.success), h))
    return {m: summarise(m, by[m]) for m in sorted(by)}


def format_handoff_markdown(summaries: Mapping[str, HandoffSummary], labels: Mapping[str, str] | None = None) -> str:
    """Markdown table of :func:`handoff_summaries`: episodes, failures split by class, goal seen, and the
    median steps of each phase."""
    def f(x, spec=".0f"):
        return "–" if x is None else format(x, spec)
    lines = ["| method | episodes | failures | found, then lost | near, unseen | never near | goal seen | "
             "first sight (median step) | search / exploitation steps of successes (median) | "
             "lost: steps within 2 m, closest (median) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for k, s in summaries.items():
        o = s.outcomes
        lines.append(f"| {(labels or {}).get(k, k)} | {s.episodes} | {s.episodes - s.successes} | {o['found_then_lost']} | "
                     f"{o['near_unseen']} | {o['never_near']} | {s.seen} | {f(s.median_first_seen)} | "
                     f"{f(s.median_search_success)} / {f(s.median_exploit_success)} | "
                     f"{f(s.median_steps_near_lost)}, {f(s.median_closest_lost, '.2f')} m |")
    return "\n".join(lines) + "\n"


@dataclass(frozen=True)
class OutcomeDiff:
    """A method's rate of one failure class minus the reference's, over the episodes both ran (paired)."""

    method: str
    outcome: str
    n: int
    """Episodes both ran (with several training seeds: that every seed's run of both ran)."""
    diff: float
    """Mean of (reference has the class) - (method has it), as a fraction: below 0 = the reference has fewer. With
    several seeds, each side's seed mean per episode."""
    lo: float
    hi: float
    """95% interval of ``diff`` (10,000 resamples, seed 0): paired bootstrap over the episodes, or with several
    training seeds on either side the two-level (seeds, then episodes) bootstrap of
    :func:`nue.evaluate.stats.seed_episode_bootstrap`."""
    seeds: int = 1
    """Training seeds (runs ``<method>@s<k>``) of the method pooled in the difference."""
    reference_seeds: int = 1
    """Training seeds of the reference pooled in the difference."""


def outcome_differences(records: Sequence, reference: str = "nue", classes: Sequence[str] = ("never_near", "found_then_lost"),
                        method_of=lambda r: r.method) -> list[OutcomeDiff]:
    """Per method other than ``reference`` (sorted) and class, the paired difference of the class's rate
    (reference minus method), matched on (scene, episode id) over the records carrying a hand-off. A method's
    training seeds (``<method>@s<k>``, :func:`nue.evaluate.table.split_seed`) are pooled, as the paired differences
    of SR pool them (:mod:`nue.evaluate.paired`): over the episodes every seed's run of both ran."""
    from nue.evaluate.stats import paired_bootstrap, seed_episode_bootstrap
    from nue.evaluate.table import split_seed

    by: dict[str, dict[int, dict]] = {}
    for r in records:
        h = record_handoff(r)
        if h is not None:
            base, k = split_seed(method_of(r))
            by.setdefault(base, {}).setdefault(k, {})[(r.scene, r.episode_id)] = h.outcome
    ref = by.get(reference)
    if not ref:
        return []
    out = []
    for m in sorted(k for k in by if k != reference):
        runs = [*by[m].values(), *ref.values()]
        keys = sorted(set.intersection(*(set(v) for v in runs)))
        if not keys:
            continue
        ind = lambda seeds: np.array([[[o[k] == c for c in classes] for k in keys]  # noqa: E731
                                      for o in seeds.values()], dtype=np.float64)  # (seeds, episodes, classes)
        a, b = ind(by[m]), ind(ref)
        if len(a) == len(b) == 1:
            mean, lo, hi = paired_bootstrap(b[0] - a[0])
        else:
            mean, lo, hi = seed_episode_bootstrap(b, a)
        out += [OutcomeDiff(m, c, len(keys), float(mean[i]), float(lo[i]), float(hi[i]), len(a), len(b))
                for i, c in enumerate(classes)]
    return out


def format_outcome_differences(diffs: Sequence[OutcomeDiff], labels: Mapping[str, str] | None = None,
                               reference: str = "NUE") -> str:
    """Markdown table of :func:`outcome_differences`: one row per method, one column per class, in points."""
    classes = list(dict.fromkeys(d.outcome for d in diffs))
    names = {"never_near": "never near", "found_then_lost": "found, then lost", "near_unseen": "near, unseen"}
    lines = ["| method | episodes | " + " | ".join(f"{reference} − method: {names.get(c, c)} (points, 95%)" for c in classes)
             + " |", "|" + "---|" * (len(classes) + 2)]
    for m in dict.fromkeys(d.method for d in diffs):
        row = {d.outcome: d for d in diffs if d.method == m}
        first = next(iter(row.values()))
        seeds = f" ({first.seeds} x {first.reference_seeds} seeds)" if (first.seeds, first.reference_seeds) != (1, 1) else ""
        lines.append(f"| {(labels or {}).get(m, m)} | {first.n}{seeds} | " + " | ".join(
            f"{100 * row[c].diff:+.1f} [{100 * row[c].lo:+.1f}, {100 * row[c].hi:+.1f}]" for c in classes) + " |")
    return "\n".join(lines) + "\n"
