"""Hallway and open-plan floor plans for the style distributions (``PlanParams.layout``), all in integer cm.

:func:`make_any_plan` is the plan entry point of the generator: with ``layout == ''`` it is exactly
:func:`nue.scene.house_layout.make_plan` (the original corridor / BSP mix, same random stream, so every
existing house stays byte-identical); otherwise it builds the named layout of :data:`LAYOUTS`:

- ``corridor`` / ``bsp``: the original layouts, without the random choice between them;
- ``l_hall``: an L-shaped hallway: one leg along the long axis (rooms on one or both sides), the other
  along the short axis at one end (rooms stacked beside it);
- ``t_hall``: a hallway along the whole long axis and a stem from it to the outer wall, rooms stacked on
  both sides of the stem and along the hallway's other side;
- ``open_plan``: two or three open zones (living room, kitchen, dining room) joined by wide openings
  (no door-sized gaps: at most ``OPEN_MARGIN`` cm of wall at each end), with bedrooms, a bathroom and
  an office in a band along one long side (or no band: three zones).

A hallway of two rectangles is joined by an opening as wide as the hallway (the walls on either side run
straight on), so it reads as one L or T. Every other room gets a door to a hallway piece (or open zone)
it borders, else to an already connected neighbour; then loop doors as in the original layouts.
"""

from __future__ import annotations

import numpy as np

from nue.scene.house_layout import (Door, Plan, PlanFailure, PlanParams, Rect, Room, _bsp_plan, _corridor_plan,
                                    _extra_doors, _name_rooms, _place_door, _split_length, _transform, make_plan,
                                    shared_wall)

LAYOUTS = ("corridor", "bsp", "l_hall", "t_hall", "open_plan")
"""Layout kinds a style may ask for."""

OPEN_MARGIN = 60
"""Open plan: at most this much wall (cm) is left at each end of the opening between two zones."""


def _opening(p: PlanParams, rooms: list[Room], i: int, j: int, margin: int) -> Door:
    """The widest opening between rooms i and j that leaves ``margin`` cm of wall at each end."""
    wall = shared_wall(rooms[i].cell, rooms[j].cell)
    if wall is None:
        raise PlanFailure("rooms to open up do not touch")
    normal, line, lo, hi = wall
    lo, hi = lo + p.half_wall + margin, hi - p.half_wall - margin
    if hi - lo < p.door_width[0]:
        raise PlanFailure("no room for an opening")
    h = p.half_wall
    rect = (line - h, lo, line + h, hi) if normal == 0 else (lo, line - h, hi, line + h)
    return Door((i, j), rect, normal)


def _band(rng, p: PlanParams, rooms: list[Room], band: Rect, axis: int, kinds: list[str] | None = None) -> list[int]:
    """Split ``band`` along ``axis`` (0: x) into rooms of at most 5.5 m and at least ``min_room_side``;
    returns their indices. ``kinds`` (optional) names them in order."""
    length = band[axis + 2] - band[axis]
    if band[3 - axis] - band[1 - axis] < p.min_room_side:
        raise PlanFailure("band too thin")
    k_min, k_max = max(1, -(-length // 550)), length // p.min_room_side
    if k_max < k_min:
        raise PlanFailure("band too short")
    k = int(rng.integers(k_min, k_max + 1))
    edges = np.concatenate([[band[axis]], band[axis] + np.cumsum(_split_length(rng, length, k, p.min_room_side))])
    out = []
    for n, (a, b) in enumerate(zip(edges[:-1], edges[1:])):
        rect = (int(a), band[1], int(b), band[3]) if axis == 0 else (band[0], int(a), band[2], int(b))
        out.append(len(rooms))
        rooms.append(Room(kinds[n % len(kinds)] if kinds else "", rect, p.half_wall))
    return out


def _connect(rng, p: PlanParams, plan: Plan, hubs: list[int]) -> None:
    """Give every room that is not a hub a door: to a hub it borders if one fits, else to a connected room."""
    rooms = plan.rooms
    linked = set(hubs)
    pending = [i for i in range(len(rooms)) if i not in linked]
    while pending:
        left = []
        for i in pending:
            near = [j for j in sorted(linked) if shared_wall(rooms[i].cell, rooms[j].cell) is not None]
            near = [j for j in near if j in hubs] or near
            door = None
            for j in rng.permutation(near) if near else ():
                door = _place_door(rng, p, rooms, int(j), i)
                if door is not None:
                    break
            if door is None:
                left.append(i)
            else:
                plan.doors.append(door)
                linked.add(i)
        if len(left) == len(pending):
            raise PlanFailure("a room cannot be connected")
        pending = left
    joined = {tuple(sorted(d.rooms)) for d in plan.doors}
    extra = [(i, j) for i in range(len(rooms)) for j in range(i + 1, len(rooms))
             if (i, j) not in joined and not (i in hubs and j in hubs)
             and shared_wall(rooms[i].cell, rooms[j].cell) is not None]
    _extra_doors(rng, p, plan, extra)


def _hall_geometry(rng, p: PlanParams, one_sided_prob: float) -> tuple[int, int, int]:
    """Hallway width and the y range (yc0, yc1) of a hallway along x with a band below it or none."""
    S, ms = p.short_side, p.min_room_side
    cw = int(rng.integers(p.corridor_width[0], p.corridor_width[1] + 1))
    if S - cw < ms:
        raise PlanFailure("too narrow for a hallway")
    below = 0
    if S - cw >= 2 * ms and rng.random() >= one_sided_prob:
        below = int(rng.integers(ms, S - cw - ms + 1))
    y0 = -S // 2
    return cw, y0 + below, y0 + below + cw


def _l_hall_plan(rng, p: PlanParams) -> Plan:
    """L-shaped hallway: leg A along x (rooms above, and below when there is room), leg B from A's left end
    up to the outer wall, with a strip of rooms stacked along y to its left."""
    L, S, ms = p.long_side, p.short_side, p.min_room_side
    x0, y0, x1, y1 = -L // 2, -S // 2, L // 2, S // 2
    cw, yc0, yc1 = _hall_geometry(rng, p, 0.35)
    if x1 - x0 - cw - 2 * ms < 0:
        raise PlanFailure("too short for an L hallway")
    xv0 = x0 + int(rng.integers(ms, min(500, L - cw - ms) + 1))
    rooms = [Room("hallway", (xv0, yc0, x1, yc1), p.half_wall), Room("hallway", (xv0, yc1, xv0 + cw, y1), p.half_wall)]
    plan = Plan("l_hall", (x0, y0, x1, y1), rooms)
    plan.doors.append(_opening(p, rooms, 0, 1, 0))
    _band(rng, p, rooms, (x0, y0, xv0, y1), 1)
    if yc0 > y0:
        _band(rng, p, rooms, (xv0, y0, x1, yc0), 0)
    _band(rng, p, rooms, (xv0 + cw, yc1, x1, y1), 0)
    _connect(rng, p, plan, [0, 1])
    return plan


def _t_hall_plan(rng, p: PlanParams) -> Plan:
    """T-shaped hallway: a hallway along the whole long side and a stem from its middle half to the outer
    wall; rooms stacked along y on both sides of the stem, and in a band below the hallway if there is room."""
    L, S, ms = p.long_side, p.short_side, p.min_room_side
    x0, y0, x1, y1 = -L // 2, -S // 2, L // 2, S // 2
    cw, yc0, yc1 = _hall_geometry(rng, p, 0.25)
    lo, hi = max(x0 + ms, x0 + L // 4), min(x1 - ms - cw, x1 - L // 4 - cw)
    if hi < lo:
        raise PlanFailure("too short for a T hallway")
    xv0 = int(rng.integers(lo, hi + 1))
    rooms = [Room("hallway", (x0, yc0, x1, yc1), p.half_wall), Room("hallway", (xv0, yc1, xv0 + cw, y1), p.half_wall)]
    plan = Plan("t_hall", (x0, y0, x1, y1), rooms)
    plan.doors.append(_opening(p, rooms, 0, 1, 0))
    _band(rng, p, rooms, (x0, yc1, xv0, y1), 1)
    _band(rng, p, rooms, (xv0 + cw, yc1, x1, y1), 1)
    if yc0 > y0:
        _band(rng, p, rooms, (x0, y0, x1, yc0), 0)
    _connect(rng, p, plan, [0, 1])
    return plan


def _open_plan(rng, p: PlanParams) -> Plan:
    """Open zones along the long axis joined by wide openings; private rooms in a band below (or none)."""
    L, S, ms = p.long_side, p.short_side, p.min_room_side
    x0, y0, x1, y1 = -L // 2, -S // 2, L // 2, S // 2
    depth = 0
    if S - ms >= 320 and rng.random() < 0.8:
        depth = int(rng.integers(ms, min(450, S - 320) + 1))
    k = 3 if depth == 0 else int(rng.integers(2, 4))
    if L < k * 300:
        raise PlanFailure("too short for the open zones")
    xs = np.concatenate([[x0], x0 + np.cumsum(_split_length(rng, L, k, 300))])
    kinds = [str(v) for v in rng.permutation(["living room", "kitchen", "dining room"])[:k]]
    rooms = [Room(kinds[n], (int(a), y0 + depth, int(b), y1), p.half_wall) for n, (a, b) in enumerate(zip(xs[:-1], xs[1:]))]
    plan = Plan("open_plan", (x0, y0, x1, y1), rooms)
    for n in range(k - 1):
        plan.doors.append(_opening(p, rooms, n, n + 1, int(rng.integers(0, OPEN_MARGIN + 1))))
    if depth:
        private = ["bedroom", "bathroom", "bedroom", "office", "bedroom", "bathroom"]
        _band(rng, p, rooms, (x0, y0, x1, y0 + depth), 0, [private[int(i)] for i in rng.permutation(len(private))])
    _connect(rng, p, plan, list(range(k)))
    return plan


_BUILDERS = {"corridor": _corridor_plan, "bsp": _bsp_plan, "l_hall": _l_hall_plan, "t_hall": _t_hall_plan,
             "open_plan": _open_plan}


def make_any_plan(rng: np.random.Generator, p: PlanParams) -> Plan:
    """A random plan of layout ``p.layout`` ('' = :func:`make_plan`'s corridor / BSP mix), named, rotated and
    mirrored at random. Raises :class:`PlanFailure` when the draw does not give a valid plan."""
    if not p.layout:
        return make_plan(rng, p)
    if p.layout not in _BUILDERS:
        raise ValueError(f"unknown layout {p.layout!r}; known: {', '.join(LAYOUTS)}")
    plan = _BUILDERS[p.layout](rng, p)
    if not p.min_rooms <= len(plan.rooms) <= p.max_rooms:
        raise PlanFailure(f"{len(plan.rooms)} rooms")
    _name_rooms(rng, plan)
    _transform(plan, bool(rng.random() < 0.5), bool(rng.random() < 0.5), bool(rng.random() < 0.5))
    return plan
