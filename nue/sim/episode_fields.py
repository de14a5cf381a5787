"""Checks of one episode entry: typed fields (numbers that are not booleans, 3-value positions, unit
yaw quaternions) while parsing, and the episode's geometry (start != goal, z on a floor) after it.

Each check raises or returns a one-line problem; :mod:`nue.sim.episodes` attaches the file and the
entry and reports all bad entries of a file together.
"""

from __future__ import annotations

import math
from dataclasses import MISSING, fields
from typing import Any, Sequence

QUAT_TOLERANCE = 1e-3
"""Allowed | |q| - 1 | and |x|, |y| of a rotation quaternion (x, y, z, w) about +z."""
FLOOR_TOLERANCE = 0.5
"""A start or goal z farther than this (metres) from every floor height of the scene is refused
(the authors' files store the robot base height, ~0.4 m above the floor)."""
COINCIDE = 1e-3
"""Start and goal closer than this in xy (metres) are the same point."""


class FieldProblem(ValueError):
    """A malformed field of one episode entry (the message names the field)."""


def _describe(value: Any) -> str:
    text = "null" if value is None else repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def number(value: Any, name: str) -> float:
    """A finite real number (int or float, not a boolean or a string)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise FieldProblem(f"{name}: expected a number, got {_describe(value)}")
    if not math.isfinite(value):
        raise FieldProblem(f"{name} is not finite: {value}")
    return float(value)


def vector(value: Any, name: str, n: int) -> tuple[float, ...]:
    """A list of ``n`` finite numbers."""
    if not isinstance(value, (list, tuple)) or len(value) != n:
        raise FieldProblem(f"{name}: expected {n} numbers, got {_describe(value)}")
    out = []
    for v in value:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise FieldProblem(f"{name}: expected {n} numbers, got {_describe(value)}")
        out.append(float(v))
    if not all(math.isfinite(v) for v in out):
        raise FieldProblem(f"{name} is not finite: {out}")
    return tuple(out)


def text(value: Any, name: str) -> str:
    """A string (an integer id is accepted and turned into one)."""
    if isinstance(value, str):
        return value
    if isinstance(value, int) and not isinstance(value, bool):
        return str(value)
    raise FieldProblem(f"{name}: expected a string, got {_describe(value)}")


def quaternion_problem(q: Sequence[float], name: str, axis: str = "z") -> str | None:
    """What is wrong with a rotation (x, y, z, w) that must be a unit quaternion about ``axis`` (+z
    for ours and the authors'; +y for habitat's, whose up axis is y), or None."""
    norm = math.sqrt(sum(v * v for v in q))
    if abs(norm - 1.0) > QUAT_TOLERANCE:
        return f"{name} is not a unit quaternion (norm {norm:.4g}): {list(q)}"
    others = [i for i, a in enumerate("xyz") if a != axis]
    if max(abs(q[i]) for i in others) > QUAT_TOLERANCE:
        zero = ", ".join("xyz"[i] for i in others)
        return f"{name} is not a rotation about {axis} ({zero} must be 0): {list(q)}"
    return None


def parse_ours(item: Any, episode_cls) -> dict:
    """The :class:`~nue.sim.episodes.Episode` fields of one entry of our format, type-checked."""
    if not isinstance(item, dict):
        raise FieldProblem(f"expected an object with the episode's fields, got a {type(item).__name__}")
    known = {f.name: f for f in fields(episode_cls)}
    unknown = sorted(set(item) - set(known))
    if unknown:
        raise FieldProblem(f"unknown field(s): {', '.join(unknown)}")
    missing = [k for k, f in known.items() if k not in item and f.default is MISSING and f.default_factory is MISSING]
    if missing:
        raise FieldProblem(f"missing field(s): {', '.join(missing)}")
    out: dict = {}
    for k, v in item.items():
        if k.endswith("_position"):
            out[k] = vector(v, k, 3)
        elif k.endswith("_rotation"):
            out[k] = vector(v, k, 4)
        elif k.endswith("_distance"):
            out[k] = number(v, k)
        else:
            out[k] = text(v, k)
    return out


def geometry_problem(ep, floors: Sequence[float] | None = None) -> str | None:
    """What is wrong with an episode's poses, or None: NaN or inf, a rotation that is not a unit
    quaternion about +z, start and goal at the same point, negative distances, or (with the scene's
    ``floors``) a z farther than :data:`FLOOR_TOLERANCE` from every floor."""
    for name in ("start_position", "start_rotation", "goal_position", "goal_rotation"):
        if not all(math.isfinite(v) for v in getattr(ep, name)):
            return f"{name} is not finite: {list(getattr(ep, name))}"
    for name in ("start_rotation", "goal_rotation"):
        problem = quaternion_problem(getattr(ep, name), name)
        if problem:
            return problem
    s, g = ep.start_position, ep.goal_position
    if math.hypot(g[0] - s[0], g[1] - s[1]) < COINCIDE:
        return f"start and goal are the same point {list(s[:2])}"
    for name in ("euclidean_distance", "geodesic_distance"):
        if not math.isfinite(getattr(ep, name)) or getattr(ep, name) < 0:
            return f"{name} must be a finite distance >= 0, got {getattr(ep, name)}"
    if floors:
        for name, p in (("start_position", s), ("goal_position", g)):
            if min(abs(p[2] - h) for h in floors) > FLOOR_TOLERANCE:
                return (f"{name} z = {p[2]:g} m is more than {FLOOR_TOLERANCE:g} m from every floor "
                        f"({', '.join(f'{h:g}' for h in floors)} m)")
    return None
