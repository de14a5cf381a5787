"""Traversability map of a generated house (iGibson convention) and the checks a house must pass.

Map: square (N, N) uint8, 1 cm per pixel, centred on the world origin, pixel (row, col) =
(y / 0.01 + N/2, x / 0.01 + N/2), 255 = free. Free = room interiors and door openings minus
furniture footprints, then only the largest 4-connected free component is kept (as iGibson does).
Plan geometry is in integer cm, so every edge falls between pixel centres and the map matches
the mesh exactly.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from nue.scene.house_furnish import Item
from nue.scene.house_layout import Plan, Rect

_FOUR = ndimage.generate_binary_structure(2, 1)


def map_size(plan: Plan, margin_cm: int = 50) -> int:
    """Side N (even, whole metres) of a square map holding the footprint plus a margin."""
    reach = max(abs(v) for v in plan.footprint) + margin_cm
    return 2 * 100 * (-(-reach // 100))


def _fill(grid: np.ndarray, rect: Rect, value) -> None:
    half = grid.shape[0] // 2
    x0, y0, x1, y1 = rect
    grid[y0 + half:y1 + half, x0 + half:x1 + half] = value


def trav_map(plan: Plan, items: list[Item], n: int) -> np.ndarray:
    """The traversability map (N, N) uint8: 255 free, 0 blocked."""
    free = np.zeros((n, n), dtype=bool)
    for room in plan.rooms:
        _fill(free, room.interior, True)
    for door in plan.doors:
        _fill(free, door.rect, True)
    for item in items:
        _fill(free, item.rect, False)
    labels, count = ndimage.label(free, structure=_FOUR)
    if count > 1:
        sizes = np.bincount(labels.ravel())
        sizes[0] = 0
        free = labels == int(np.argmax(sizes))
    return np.where(free, 255, 0).astype(np.uint8)


def robot_free(trav: np.ndarray, radius_m: float, resolution: float = 0.01) -> np.ndarray:
    """Where a disc of ``radius_m`` fits: free pixels farther than it from any blocked one, (N, N) bool."""
    return ndimage.distance_transform_edt(trav > 0) * resolution > radius_m


def check_house(plan: Plan, trav: np.ndarray, radius_m: float, min_extent_m: float,
                area_range: tuple[float, float], min_door_m: float, coarse_cell: int = 5) -> list[str]:
    """Problems of a generated house (empty list = valid).

    Checks: floor area in ``area_range`` m^2; every door opening free and >= ``min_door_m`` wide in
    the map; free space eroded by ``radius_m`` is one 4-connected piece that reaches every room;
    on a ``coarse_cell`` cm planning grid (cells free when all their pixels are, 8-connected) the
    largest piece still reaches every room; the extent along x or y is >= ``min_extent_m``.
    """
    problems = []
    n = trav.shape[0]
    half = n // 2
    area = sum(r.area_m2 for r in plan.rooms)
    if not area_range[0] <= area <= area_range[1]:
        problems.append(f"floor area {area:.1f} m^2")
    for door in plan.doors:
        x0, y0, x1, y1 = door.rect
        patch = trav[y0 + half:y1 + half, x0 + half:x1 + half] > 0
        across = patch.all(axis=1 - door.normal).sum()  # free lines straight through the wall
        if door.width < min_door_m * 100 or across < door.width:
            problems.append(f"door {door.rooms} blocked or narrow")
    core = robot_free(trav, radius_m)
    labels, count = ndimage.label(core, structure=_FOUR)
    if count != 1:
        problems.append(f"robot-free space has {count} components")
    for room in plan.rooms:
        x0, y0, x1, y1 = room.interior
        if not labels[y0 + half:y1 + half, x0 + half:x1 + half].any():
            problems.append(f"room {room.name} unreachable")
    # The same on a coarse planning grid (a cell is free when all its pixels are): narrow necks
    # that a 1 cm grid still passes must not cut a room off there.
    f = coarse_cell
    m = n // f
    coarse = core[: m * f, : m * f].reshape(m, f, m, f).all(axis=(1, 3))
    clab, ccount = ndimage.label(coarse, structure=np.ones((3, 3)))
    main = int(np.argmax(np.bincount(clab.ravel())[1:])) + 1 if ccount else -1
    for room in plan.rooms:
        x0, y0, x1, y1 = ((v + half) // f for v in room.interior)
        if not (clab[y0:y1, x0:x1] == main).any():
            problems.append(f"room {room.name} cut off on a {f} cm grid")
    rows, cols = np.nonzero(core)
    if rows.size == 0 or max(np.ptp(rows), np.ptp(cols)) * 0.01 < min_extent_m:
        problems.append("free extent too small")
    return problems
