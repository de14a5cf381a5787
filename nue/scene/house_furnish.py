"""Furniture and wall pictures for a floor plan: box-built pieces placed so no room is cut off.

Every piece is a union of solid boxes standing on the floor whose footprint is its rectangle
(the traversability map blocks exactly that rectangle). Pieces go either flush against a wall or
free-standing with >= 0.5 m around them; none enters the clearance zone in front of a door, and
after each placement the room's free floor, eroded by half the minimum passage width, must stay one
connected piece that reaches all its doors. Pictures hang on free wall stretches (no door, no tall piece).
All geometry is in integer cm, in the plan's frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from nue.scene.house_layout import Plan, Rect

Box = tuple[int, int, int, int, int, int, str, "str | None"]
"""Local box ``(a0, a1, b0, b1, z0, z1, material, front_material)``: a along the back wall, b away
from it, z up (cm); the front material (or None) is used on the face at ``b = b1``."""


@dataclass
class Item:
    """A placed piece of furniture."""

    kind: str
    room: int
    rect: Rect
    """Footprint, cm (world frame)."""
    height: int
    """Top of the highest box, cm."""
    back: tuple[int, int]
    """(axis, sign): the piece's back faces -sign along axis; its front faces +sign."""
    against_wall: bool
    boxes: list[tuple[Rect, int, int, str, str | None]]
    """World boxes ``(rect, z0, z1, material, front_material)``."""


@dataclass
class Picture:
    """A picture hanging on a wall face."""

    room: int
    axis: int
    """Axis the wall face is perpendicular to (0: face x = const)."""
    sign: int
    """+1 when the face is the room's min side (the picture faces +axis), -1 for the max side."""
    plane: int
    """Wall face coordinate, cm."""
    span: tuple[int, int]
    """Extent along the wall, cm."""
    z: tuple[int, int]
    """Bottom and top height, cm."""
    material: str


def _bed(w, d, h):
    return [(0, w, 0, 6, 0, 100, "wood_dark", None), (0, w, 6, d, 0, h, "bedding", None),
            (10, w - 10, 12, 50, h, h + 12, "white", None)]


def _sofa(w, d, h):
    return [(0, w, 0, 22, 0, h, "fabric_a", None), (0, 18, 22, d, 0, 62, "fabric_a", None),
            (w - 18, w, 22, d, 0, 62, "fabric_a", None), (18, w - 18, 22, d, 0, 42, "fabric_a", None)]


def _table(w, d, h):
    return [(0, w, 0, d, h - 5, h, "wood_light", None), (6, w - 6, 6, d - 6, 0, h - 5, "wood_dark", None)]


def _chair(w, d, h):
    return [(0, w, 0, 6, 0, h, "wood_dark", None), (0, w, 6, d, 0, 46, "fabric_b", None)]


def _tv_stand(w, d, h):
    t0 = w * 15 // 100
    screen_top = h + (w - 2 * t0) * 9 // 16
    return [(0, w, 0, d, 0, h, "wood_dark", "drawers"), (t0, w - t0, 8, 14, h, screen_top, "screen", None)]


def _toilet(w, d, h):
    return [(0, w, 0, 20, 0, h, "white", None), (0, w, 20, d, 0, 42, "white", None)]


def _plant(w, d, h):
    return [(8, w - 8, 8, d - 8, 0, 35, "pot", None), (0, w, 0, d, 35, h, "plant", None)]


def _box(material, front=None):
    return lambda w, d, h: [(0, w, 0, d, 0, h, material, front)]


# kind: (width along the wall, depth, height) ranges in cm, placement ('wall', 'free', 'any'), builder
TEMPLATES = {
    "bed": ((140, 180), (195, 210), (42, 50), "wall", _bed),
    "single bed": ((90, 100), (195, 205), (42, 50), "wall", _bed),
    "nightstand": ((40, 50), (38, 42), (50, 60), "wall", _box("wood_light", "drawers")),
    "wardrobe": ((100, 180), (58, 62), (185, 205), "wall", _box("wood_light", "doors")),
    "desk": ((100, 150), (60, 72), (73, 77), "wall", _table),
    "chair": ((44, 50), (44, 50), (85, 95), "any", _chair),
    "sofa": ((180, 240), (85, 95), (80, 90), "wall", _sofa),
    "armchair": ((80, 90), (80, 90), (75, 85), "any", _sofa),
    "coffee table": ((90, 130), (50, 70), (40, 45), "free", _table),
    "tv stand": ((120, 180), (42, 48), (45, 55), "wall", _tv_stand),
    "bookshelf": ((80, 160), (32, 38), (175, 205), "wall", _box("wood_dark", "books")),
    "cabinet": ((60, 120), (40, 50), (80, 100), "wall", _box("wood_light", "drawers")),
    "sideboard": ((120, 180), (42, 50), (80, 95), "wall", _box("wood_dark", "drawers")),
    "console": ((60, 110), (30, 36), (80, 90), "wall", _box("wood_dark", "drawers")),
    "counter": ((150, 280), (58, 62), (88, 92), "wall", _box("white", "drawers")),
    "fridge": ((60, 75), (62, 70), (170, 190), "wall", _box("white")),
    "dining table": ((120, 180), (80, 100), (73, 77), "free", _table),
    "bathtub": ((150, 170), (70, 80), (52, 58), "wall", _box("white")),
    "sink cabinet": ((60, 90), (45, 52), (82, 88), "wall", _box("white", "drawers")),
    "toilet": ((38, 42), (62, 70), (75, 82), "wall", _toilet),
    "plant": ((35, 50), (35, 50), (80, 140), "any", _plant),
}

# room kind: (piece, probability before the density factor; 1.0 = always tried)
ROOM_FURNITURE = {
    "living room": [("sofa", 1.0), ("coffee table", 0.9), ("tv stand", 0.8), ("bookshelf", 0.7),
                    ("armchair", 0.6), ("plant", 0.6), ("cabinet", 0.4), ("bookshelf", 0.3)],
    "kitchen": [("counter", 1.0), ("fridge", 0.9), ("counter", 0.6), ("dining table", 0.7),
                ("chair", 0.6), ("chair", 0.5), ("cabinet", 0.4)],
    "bedroom": [("bed", 0.7), ("single bed", 0.3), ("wardrobe", 0.9), ("nightstand", 0.8),
                ("desk", 0.5), ("chair", 0.4), ("plant", 0.3)],
    "bathroom": [("sink cabinet", 1.0), ("toilet", 1.0), ("bathtub", 0.8), ("cabinet", 0.4)],
    "office": [("desk", 1.0), ("chair", 0.8), ("bookshelf", 0.9), ("bookshelf", 0.5), ("cabinet", 0.6),
               ("plant", 0.4)],
    "dining room": [("dining table", 1.0), ("chair", 0.7), ("chair", 0.7), ("chair", 0.6), ("sideboard", 0.8),
                    ("plant", 0.5), ("bookshelf", 0.3)],
    "hallway": [("console", 0.6), ("plant", 0.4), ("console", 0.3)],
}

# room kind: extra pieces, one draw tried per 12 m^2 of floor (probability 0.6 x density)
ROOM_EXTRAS = {
    "living room": ("armchair", "plant", "cabinet", "bookshelf", "chair", "sideboard"),
    "kitchen": ("chair", "cabinet", "plant"),
    "bedroom": ("plant", "chair", "cabinet", "bookshelf"),
    "office": ("chair", "plant", "cabinet", "bookshelf"),
    "dining room": ("chair", "plant", "cabinet"),
    "bathroom": ("cabinet",),
    "hallway": ("plant", "console"),
}

_SIDES = ((0, 1), (0, -1), (1, 1), (1, -1))  # (axis, sign): wall at the room's min (+1) / max (-1) side


def _overlaps(a: Rect, b: Rect, gap: int = 0) -> bool:
    return a[0] < b[2] + gap and b[0] < a[2] + gap and a[1] < b[3] + gap and b[1] < a[3] + gap


def door_zones(plan: Plan, room: int, clearance: int, widen: int = 15) -> list[tuple[Rect, tuple[int, int]]]:
    """Clearance rectangle in front of each door of a room and a point 0.5 m inside it (cm)."""
    ix0, iy0, ix1, iy1 = interior = plan.rooms[room].interior
    out = []
    for door in plan.doors:
        if room not in door.rooms:
            continue
        n, (s0, s1) = door.normal, door.span
        lo_side = door.rect[n + 2] == interior[n]  # the door is on the room's min side
        depth = (interior[n], interior[n] + clearance) if lo_side else (interior[n + 2] - clearance, interior[n + 2])
        inward = interior[n] + 50 if lo_side else interior[n + 2] - 50
        if n == 0:
            zone, pt = (depth[0], s0 - widen, depth[1], s1 + widen), (inward, (s0 + s1) // 2)
        else:
            zone, pt = (s0 - widen, depth[0], s1 + widen, depth[1]), ((s0 + s1) // 2, inward)
        zone = (max(zone[0], ix0), max(zone[1], iy0), min(zone[2], ix1), min(zone[3], iy1))
        out.append((zone, pt))
    return out


def _connected(interior: Rect, blocked: list[Rect], points: list[tuple[int, int]], radii: tuple[int, ...],
               cell: int = 2) -> bool:
    """Whether the room's free floor eroded by each of ``radii`` cm is one piece containing every point."""
    x0, y0, x1, y1 = interior
    nx, ny = (x1 - x0) // cell, (y1 - y0) // cell
    free = np.zeros((ny + 2, nx + 2), dtype=bool)
    free[1:-1, 1:-1] = True
    for r in blocked:
        c0, c1 = max(0, (r[0] - x0) // cell) + 1, min(nx, -(-(r[2] - x0) // cell)) + 1
        r0, r1 = max(0, (r[1] - y0) // cell) + 1, min(ny, -(-(r[3] - y0) // cell)) + 1
        free[r0:r1, c0:c1] = False
    dist = ndimage.distance_transform_edt(free) * cell
    for radius in radii:
        labels, n = ndimage.label(dist > radius)
        if n != 1:
            return False
        for px, py in points:
            i, j = (py - y0) // cell + 1, (px - x0) // cell + 1
            if not (0 <= i < ny + 2 and 0 <= j < nx + 2 and labels[i, j]):
                return False
    return True


def _world_boxes(local: list[Box], rect: Rect, back: tuple[int, int]):
    """Map local boxes onto a footprint whose back faces -sign along axis."""
    axis, sign = back
    out = []
    for a0, a1, b0, b1, z0, z1, mat, front in local:
        if axis == 0:
            xs = (rect[0] + b0, rect[0] + b1) if sign > 0 else (rect[2] - b1, rect[2] - b0)
            r = (xs[0], rect[1] + a0, xs[1], rect[1] + a1)
        else:
            ys = (rect[1] + b0, rect[1] + b1) if sign > 0 else (rect[3] - b1, rect[3] - b0)
            r = (rect[0] + a0, ys[0], rect[0] + a1, ys[1])
        out.append((r, z0, z1, mat, front))
    return out


def _scaled(ranges, scale: tuple[float, float, float]) -> list[tuple[int, int]]:
    """A template's (width, depth, height) ranges in cm, each multiplied by its factor of ``scale``."""
    return [(int(round(lo * s)), int(round(hi * s))) for (lo, hi), s in zip(ranges, scale)]


def _try_place(rng, kind: str, interior: Rect, zones: list[Rect], items: list[Item],
               scale: tuple[float, float, float] = (1.0, 1.0, 1.0)):
    """A random candidate for ``kind`` (its template's sizes times ``scale``) that avoids door zones and
    other pieces, or None.

    Returns ``(footprint, back (axis, sign), against_wall, (w, d, h))``.
    """
    *ranges, where, _ = TEMPLATES[kind]
    w, d, h = (int(rng.integers(lo, hi + 1)) for lo, hi in _scaled(ranges, scale))
    wall = where == "wall" or (where == "any" and rng.random() < 0.5)
    axis, sign = _SIDES[int(rng.integers(0, 4))]
    size = (d, w) if axis == 0 else (w, d)  # footprint extent along x, y
    lo = [interior[0], interior[1]]
    hi = [interior[2] - size[0], interior[3] - size[1]]
    margin = 0 if wall else 60
    if wall:  # flush with the chosen wall
        lo[axis] = hi[axis] = interior[axis] if sign > 0 else interior[axis + 2] - size[axis]
    lo, hi = [v + margin for v in lo], [v - margin for v in hi]
    if hi[0] < lo[0] or hi[1] < lo[1]:
        return None
    x, y = int(rng.integers(lo[0], hi[0] + 1)), int(rng.integers(lo[1], hi[1] + 1))
    rect = (x, y, x + size[0], y + size[1])
    if any(_overlaps(rect, z) for z in zones):
        return None
    for other in items:
        gap = 0 if (wall and other.against_wall) else 50
        if _overlaps(rect, other.rect, gap):
            return None
    return rect, (axis, sign), wall, (w, d, h)


def furnish(rng, plan: Plan, density: float, clearance: int, passage: int, robot: int, tries: int = 12,
            scale: tuple[float, float, float] = (1.0, 1.0, 1.0)) -> list[Item]:
    """Place furniture in every room of ``plan`` (see module docstring).

    ``passage``: half the minimum passage width; ``robot``: robot radius (cm). Each room's floor must
    stay one piece when eroded by ``passage`` and by radii around ``robot`` (no isolated slivers).
    ``scale``: factors on every template's width, depth and height ranges.
    """
    radii = (passage, robot - 2, robot, robot + 2)
    items: list[Item] = []
    for ri, room in enumerate(plan.rooms):
        zd = door_zones(plan, ri, clearance)
        zones, points = [z for z, _ in zd], [p for _, p in zd]
        mine: list[Item] = []
        extras = ROOM_EXTRAS.get(room.kind, ())
        wishes = list(ROOM_FURNITURE.get(room.kind, []))
        wishes += [(extras[int(rng.integers(0, len(extras)))], 0.6) for _ in range(int(room.area_m2 // 12))]
        for kind, prob in wishes:
            if rng.random() >= min(1.0, prob * density):
                continue
            for _ in range(tries):
                cand = _try_place(rng, kind, room.interior, zones, mine, scale)
                if cand is None:
                    continue
                rect, back, wall, (w, d, h) = cand
                if not _connected(room.interior, [it.rect for it in mine] + [rect], points, radii):
                    continue
                local = TEMPLATES[kind][4](w, d, h)
                boxes = _world_boxes(local, rect, back)
                mine.append(Item(kind, ri, rect, max(b[2] for b in boxes), back, wall, boxes))
                break
        items += mine
    return items


def free_intervals(lo: int, hi: int, taken: list[tuple[int, int]]) -> list[tuple[int, int]]:
    """Parts of [lo, hi) not covered by any ``taken`` interval."""
    out, cur = [], lo
    for a, b in sorted(taken):
        if a > cur:
            out.append((cur, min(a, hi)))
        cur = max(cur, b)
    if cur < hi:
        out.append((cur, hi))
    return [(a, b) for a, b in out if b > a]


def hang_pictures(rng, plan: Plan, items: list[Item], per_room: tuple[int, int], z_range: tuple[int, int],
                  first_index: int = 0) -> list[Picture]:
    """Hang pictures on free wall stretches; material names ``picture<NN>`` from ``first_index``."""
    pictures: list[Picture] = []
    for ri, room in enumerate(plan.rooms):
        interior = room.interior
        if room.kind == "hallway":
            length = max(interior[2] - interior[0], interior[3] - interior[1])
            count = max(1, int(round(length / 350)))
        else:
            count = int(rng.integers(per_room[0], per_room[1] + 1)) + int(room.area_m2 > 20)
        mine: list[Picture] = []
        for _ in range(count * 15):
            if len(mine) >= count:
                break
            axis, sign = _SIDES[int(rng.integers(0, 4))]
            o = 1 - axis
            plane = interior[axis] if sign > 0 else interior[axis + 2]
            taken = [(d.span[0] - 25, d.span[1] + 25) for d in plan.doors if d.normal == axis and
                     (d.rect[axis + 2] == plane or d.rect[axis] == plane)]
            taken += [(it.rect[o] - 10, it.rect[o + 2] + 10) for it in items
                      if it.room == ri and it.height > z_range[0] - 5 and
                      (it.rect[axis] <= plane + 5 if sign > 0 else it.rect[axis + 2] >= plane - 5)]
            taken += [(p.span[0] - 40, p.span[1] + 40) for p in mine if p.axis == axis and p.plane == plane]
            free = free_intervals(interior[o] + 25, interior[o + 2] - 25, taken)
            width = int(rng.integers(50, 111))
            free = [(a, b) for a, b in free if b - a >= width]
            if not free:
                continue
            a, b = free[int(rng.integers(0, len(free)))]
            s0 = int(rng.integers(a, b - width + 1))
            height = int(rng.integers(45, min(76, z_range[1] - z_range[0] + 1)))
            z0 = int(rng.integers(z_range[0], z_range[1] - height + 1))
            name = f"picture{first_index + len(pictures) + len(mine):02d}"
            mine.append(Picture(ri, axis, sign, plane, (s0, s0 + width), (z0, z0 + height), name))
        pictures += mine
    return pictures
