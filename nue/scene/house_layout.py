"""Floor plans for the procedural house generator: footprint, rooms, corridor, doors (integer cm).

All plan geometry is in integer centimetres so that every wall face, door jamb and furniture edge
lies on the 1 cm grid of the traversability map (pixel centres never fall on an edge). A room's
``cell`` runs along wall centre lines; its ``interior`` (the free floor) is the cell shrunk by half
a wall thickness. Two layouts:

- ``corridor``: a hallway along the long axis with rooms on one or both sides (each with a door to
  the hallway), optionally an end room across the full short side;
- ``bsp``: recursive binary splits of the footprint, one door in every dividing wall, which
  connects the two halves of every split and hence the whole house.

Three more layouts live in :mod:`nue.scene.house_plans`, used by the style distributions of
:mod:`nue.scene.house_styles` (chosen with ``PlanParams.layout``; the default '' keeps the original
corridor / BSP mix and its random stream):

- ``l_hall``: an L-shaped hallway (two hallway rectangles joined by a full-width opening), rooms along
  both legs and beside the corner;
- ``t_hall``: a hallway across the whole long side with a stem from its middle to the outer wall;
- ``open_plan``: two or three open zones (living room, kitchen, dining room) joined by wide openings,
  with private rooms in a band along one long side (or none).

All layouts may add extra doors between neighbouring rooms (loops, at most ``max_extra_doors``). Plans are
built with the long axis along x and then rotated / mirrored at random, so houses are centred on the
world origin.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

Rect = tuple[int, int, int, int]
"""Axis-aligned rectangle ``(x0, y0, x1, y1)`` in cm with ``x0 < x1`` and ``y0 < y1``."""


class PlanFailure(Exception):
    """Internal: this random draw gave no valid plan; the generator retries with the next attempt."""


@dataclass
class Room:
    """One room (or the hallway) of a plan."""

    kind: str
    """``hallway``, ``living room``, ``kitchen``, ``bedroom``, ``bathroom``, ``office``, ``dining room``."""
    cell: Rect
    """Rectangle on the wall centre lines, cm."""
    half_wall: int
    """Half the wall thickness, cm."""
    name: str = ""
    """Unique display name, e.g. ``bedroom 2``."""

    @property
    def interior(self) -> Rect:
        """Free floor rectangle (cell shrunk by half a wall thickness), cm."""
        x0, y0, x1, y1 = self.cell
        h = self.half_wall
        return (x0 + h, y0 + h, x1 - h, y1 - h)

    @property
    def area_m2(self) -> float:
        x0, y0, x1, y1 = self.interior
        return (x1 - x0) * (y1 - y0) / 1e4


@dataclass
class Door:
    """A doorway: a free opening through one wall, floor to ``door_height``."""

    rooms: tuple[int, int]
    """Indices of the two rooms it joins."""
    rect: Rect
    """Opening footprint (wall thickness x free width), cm."""
    normal: int
    """Passage axis: 0 when the wall is a line x = const (walk along x), 1 when y = const."""

    @property
    def width(self) -> int:
        """Free opening width along the wall, cm."""
        x0, y0, x1, y1 = self.rect
        return (y1 - y0) if self.normal == 0 else (x1 - x0)

    @property
    def line(self) -> int:
        """Wall centre-line coordinate, cm."""
        x0, y0, x1, y1 = self.rect
        return (x0 + x1) // 2 if self.normal == 0 else (y0 + y1) // 2

    @property
    def span(self) -> tuple[int, int]:
        """Opening interval along the wall, cm."""
        x0, y0, x1, y1 = self.rect
        return (y0, y1) if self.normal == 0 else (x0, x1)


@dataclass
class Plan:
    """A floor plan: footprint, rooms and doors, all in cm."""

    layout: str
    footprint: Rect
    rooms: list[Room]
    doors: list[Door] = field(default_factory=list)


@dataclass(frozen=True)
class PlanParams:
    """Plan parameters in integer cm (derived from ``HouseConfig``)."""

    long_side: int
    short_side: int
    half_wall: int
    min_room_side: int
    corridor_width: tuple[int, int]
    door_width: tuple[int, int]
    door_margin: int
    max_rooms: int
    min_rooms: int
    corridor_prob: float
    extra_door_prob: float
    room_area: tuple[float, float] = (12.0, 20.0)
    """BSP: range of the mean room area, m^2."""
    max_extra_doors: int = 2
    """At most this many loop doors per house."""
    layout: str = ""
    """One of :data:`LAYOUTS` for every draw, or '' for the original mix (``corridor_prob``: corridor, else BSP)."""


def shared_wall(a: Rect, b: Rect) -> tuple[int, int, int, int] | None:
    """``(normal, line, lo, hi)`` of the wall two cells share (overlap ``lo..hi`` > 0), else None."""
    for normal in (0, 1):
        o = 1 - normal
        if a[normal + 2] == b[normal]:
            line = a[normal + 2]
        elif a[normal] == b[normal + 2]:
            line = a[normal]
        else:
            continue
        lo, hi = max(a[o], b[o]), min(a[o + 2], b[o + 2])
        if hi > lo:
            return normal, line, lo, hi
    return None


def _place_door(rng, p: PlanParams, rooms: list[Room], i: int, j: int) -> Door | None:
    """A door of random width and position in the wall between rooms i and j, or None if none fits."""
    wall = shared_wall(rooms[i].cell, rooms[j].cell)
    if wall is None:
        return None
    normal, line, lo, hi = wall
    lo, hi = lo + p.half_wall + p.door_margin, hi - p.half_wall - p.door_margin
    if hi - lo < p.door_width[0]:
        return None
    width = int(rng.integers(p.door_width[0], min(p.door_width[1], hi - lo) + 1))
    s0 = int(rng.integers(lo, hi - width + 1))
    h = p.half_wall
    rect = (line - h, s0, line + h, s0 + width) if normal == 0 else (s0, line - h, s0 + width, line + h)
    return Door((i, j), rect, normal)


def _split_length(rng, total: int, k: int, min_len: int) -> list[int]:
    """Split ``total`` cm into ``k`` integer parts, each >= ``min_len``."""
    spare = total - k * min_len
    if spare < 0:
        raise PlanFailure("too short")
    cuts = np.round(np.cumsum(rng.dirichlet(np.full(k, 3.0))) * spare).astype(int)
    parts = np.diff(np.concatenate([[0], cuts])) + min_len
    parts[-1] = total - int(parts[:-1].sum())
    return [int(v) for v in parts]


def _corridor_plan(rng, p: PlanParams) -> Plan:
    """Hallway along x with rooms on one or both sides and an optional end room."""
    L, S, ms = p.long_side, p.short_side, p.min_room_side
    x0, y0, x1, y1 = -L // 2, -S // 2, L // 2, S // 2
    cw = int(rng.integers(p.corridor_width[0], p.corridor_width[1] + 1))
    can_two = S >= 2 * ms + cw
    two_sided = can_two and (S - cw > 600 or rng.random() < 0.75)
    if not two_sided and S - cw < ms:
        raise PlanFailure("too narrow for a corridor plan")
    end = 0
    if rng.random() < 0.4 and L - 2 * ms >= 700:
        end = int(rng.integers(ms, min(450, L - 700) + 1))
    cx0 = x0 + end
    if two_sided:
        yc0 = y0 + int(rng.integers(ms, S - cw - ms + 1))
    else:
        yc0 = y0
    yc1 = yc0 + cw
    rooms = [Room("hallway", (cx0, yc0, x1, yc1), p.half_wall)]
    if end:
        rooms.append(Room("", (x0, y0, cx0, y1), p.half_wall))
    length = x1 - cx0
    k_min, k_max = max(1, -(-length // 550)), length // ms
    if k_max < k_min:
        raise PlanFailure("corridor too short")
    bands = [(yc1, y1)] + ([(y0, yc0)] if two_sided else [])
    counts = [int(rng.integers(k_min, k_max + 1)) for _ in bands]
    while len(rooms) + sum(counts) > p.max_rooms:
        i = int(np.argmax(counts))
        if counts[i] <= k_min:
            raise PlanFailure("too many rooms")
        counts[i] -= 1
    while len(rooms) - 1 + sum(counts) < p.min_rooms:  # at least min_rooms besides the hallway
        i = int(np.argmin(counts))
        if counts[i] >= k_max or len(rooms) + sum(counts) >= p.max_rooms:
            raise PlanFailure("too few rooms")
        counts[i] += 1
    sides: list[list[int]] = []
    for (b0, b1), k in zip(bands, counts):
        xs = np.concatenate([[cx0], cx0 + np.cumsum(_split_length(rng, length, k, ms))])
        sides.append([])
        for a, b in zip(xs[:-1], xs[1:]):
            sides[-1].append(len(rooms))
            rooms.append(Room("", (int(a), b0, int(b), b1), p.half_wall))
    plan = Plan("corridor", (x0, y0, x1, y1), rooms)
    for i in range(1, len(rooms)):
        door = _place_door(rng, p, rooms, 0, i)
        if door is None:
            raise PlanFailure("no room for a hallway door")
        plan.doors.append(door)
    extra = [(a, b) for side in sides for a, b in zip(side[:-1], side[1:])]
    if end:
        extra += [(1, side[0]) for side in sides]
    _extra_doors(rng, p, plan, extra)
    return plan


def _bsp_plan(rng, p: PlanParams) -> Plan:
    """Recursive splits of the footprint; one door per split joins its two halves."""
    L, S, ms = p.long_side, p.short_side, p.min_room_side
    fp = (-L // 2, -S // 2, L // 2, S // 2)
    target = int(np.clip(round(L * S / 1e4 / rng.uniform(*p.room_area)), p.min_rooms, p.max_rooms))
    leaves: list[Rect] = [fp]
    splits: list[tuple[Rect, Rect]] = []
    while len(leaves) < target:
        dims = [(r[2] - r[0], r[3] - r[1]) for r in leaves]
        ok = [i for i, (w, h) in enumerate(dims) if max(w, h) >= 2 * ms]
        if not ok:
            break
        ok.sort(key=lambda i: -dims[i][0] * dims[i][1])
        i = ok[int(rng.integers(0, min(2, len(ok))))]
        r, (w, h) = leaves[i], dims[i]
        axis = 0 if w > h else 1 if h > w else int(rng.integers(0, 2))
        if (w, h)[axis] < 2 * ms:
            axis = 1 - axis
        pos = r[axis] + int(rng.integers(ms, (w, h)[axis] - ms + 1))
        if axis == 0:
            a, b = (r[0], r[1], pos, r[3]), (pos, r[1], r[2], r[3])
        else:
            a, b = (r[0], r[1], r[2], pos), (r[0], pos, r[2], r[3])
        leaves[i:i + 1] = [a, b]
        splits.append((a, b))
    rooms = [Room("", leaf, p.half_wall) for leaf in leaves]
    plan = Plan("bsp", fp, rooms)

    def inside(leaf: Rect, region: Rect) -> bool:
        return region[0] <= leaf[0] and region[1] <= leaf[1] and leaf[2] <= region[2] and leaf[3] <= region[3]

    for a, b in splits:
        pairs = [(i, j) for i, la in enumerate(leaves) if inside(la, a) for j, lb in enumerate(leaves) if inside(lb, b)]
        doors = [d for d in (_place_door(rng, p, rooms, i, j) for i, j in pairs) if d is not None]
        if not doors:
            raise PlanFailure("no door fits a dividing wall")
        plan.doors.append(doors[int(rng.integers(0, len(doors)))])
    joined = {tuple(sorted(d.rooms)) for d in plan.doors}
    extra = [(i, j) for i in range(len(rooms)) for j in range(i + 1, len(rooms))
             if (i, j) not in joined and shared_wall(rooms[i].cell, rooms[j].cell) is not None]
    _extra_doors(rng, p, plan, extra)
    return plan


def _extra_doors(rng, p: PlanParams, plan: Plan, pairs: list[tuple[int, int]]) -> None:
    """Add loop doors between some neighbouring rooms (at most ``p.max_extra_doors`` per house)."""
    added = 0
    for i, j in pairs:
        if added < p.max_extra_doors and rng.random() < p.extra_door_prob:
            door = _place_door(rng, p, plan.rooms, i, j)
            if door is not None:
                plan.doors.append(door)
                added += 1


def _name_rooms(rng, plan: Plan) -> None:
    """Give every room without a kind one (largest: living room, small: bathroom), then every room a unique name."""
    idx = [i for i, r in enumerate(plan.rooms) if not r.kind]  # rooms a layout named itself keep their kind
    idx.sort(key=lambda i: (-plan.rooms[i].area_m2, i))
    kinds = ["living room"]
    pool = ["kitchen", "bedroom", "bathroom", "office", "bedroom", "dining room", "bedroom"]
    rest = [pool[0]] + [pool[k] for k in 1 + rng.permutation(len(pool) - 1)]
    kinds += rest[: len(idx) - 1]
    if len(idx) >= 4 and "bathroom" in kinds:  # the bathroom is the smallest room
        kinds.remove("bathroom")
        kinds.append("bathroom")
    counts: dict[str, int] = {}
    for i, kind in zip(idx, kinds):
        plan.rooms[i].kind = kind
    for r in plan.rooms:
        counts[r.kind] = counts.get(r.kind, 0) + 1
        r.name = r.kind if counts[r.kind] == 1 else f"{r.kind} {counts[r.kind]}"


def _transform(plan: Plan, swap: bool, flip_x: bool, flip_y: bool) -> None:
    """Rotate / mirror a plan in place (swap x and y, then negate x and / or y)."""

    def tr(r: Rect) -> Rect:
        x0, y0, x1, y1 = (r[1], r[0], r[3], r[2]) if swap else r
        if flip_x:
            x0, x1 = -x1, -x0
        if flip_y:
            y0, y1 = -y1, -y0
        return (x0, y0, x1, y1)

    plan.footprint = tr(plan.footprint)
    for room in plan.rooms:
        room.cell = tr(room.cell)
    for door in plan.doors:
        door.rect = tr(door.rect)
        door.normal = 1 - door.normal if swap else door.normal


def make_plan(rng: np.random.Generator, p: PlanParams) -> Plan:
    """A random plan (corridor or BSP layout), named, rotated and mirrored at random.

    Raises :class:`PlanFailure` when the draw does not give a valid plan.
    """
    plan = _corridor_plan(rng, p) if rng.random() < p.corridor_prob else _bsp_plan(rng, p)
    if not p.min_rooms <= len(plan.rooms) <= p.max_rooms:
        raise PlanFailure(f"{len(plan.rooms)} rooms")
    _name_rooms(rng, plan)
    _transform(plan, bool(rng.random() < 0.5), bool(rng.random() < 0.5), bool(rng.random() < 0.5))
    return plan
