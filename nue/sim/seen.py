"""What one depth frame shows of the floor grid: the floor cells it sees and the cells it shows as obstacle.

Per-frame geometry shared by the exploring expert (its own seen map) and the evaluation's coverage
(the evaluation's coverage tracker re-exports these names). A floor cell is *seen* when the depth camera
sees the floor there (not occluded, within ``max_range`` metres of the robot; see
:func:`seen_floor_cells`); a cell is an *obstacle* cell when a depth point above the floor (a wall,
furniture) lands in it (:func:`seen_obstacle_cells`). Grids are (M, M) planning cells of a
:class:`GridLike` (``nue.scene.navgrid.NavGrid`` fits).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from nue.sim.camera import depth_to_points, world_from_camera
from nue.sim.task import CameraConfig


class GridLike(Protocol):
    """What the seen-cell functions need of a grid (``nue.scene.navgrid.NavGrid`` fits)."""

    free: np.ndarray
    """(M, M) cells; only its shape is used."""
    cell: float
    """Cell size, metres."""

    def cell_of(self, xy) -> np.ndarray:
        """World (x, y) (..., 2) -> cell (row, col) (..., 2), int."""
        ...

    def cell_centre(self, rc) -> np.ndarray:
        """Cell (row, col) (..., 2) -> world (x, y) (..., 2) of its centre."""
        ...


@dataclass(frozen=True)
class CoverageConfig:
    """Which floor cells a depth frame counts as seen (and which cells it shows as obstacle)."""

    max_range: float = 5.0
    """Horizontal distance from the robot beyond which the floor does not count, metres
    (the policy sees depth clipped at 5 m)."""
    floor_tolerance: float = 0.05
    """A back-projected point is on the floor when ``|z - floor_z| <=`` this, metres."""
    obstacle_min_height: float = 0.1
    """:func:`seen_obstacle_cells`: a point at least this high above the floor is an obstacle, metres."""
    obstacle_max_height: float = 1.5
    """:func:`seen_obstacle_cells`: points higher than this (ceilings, door lintels) are ignored, metres."""


def cell_area(grid: GridLike) -> float:
    """Area of one grid cell, m²."""
    return float(grid.cell) ** 2


def _frame_points(depth: np.ndarray, pose, camera: CameraConfig, floor_z: float):
    """(H, W) z-depth with NaN -> 0, and its world points (H, W, 3)."""
    z = np.nan_to_num(np.asarray(depth, dtype=np.float64).reshape(camera.height, camera.width), nan=0.0)
    return z, depth_to_points(z, pose, camera, floor_z)


def _mark(mask: np.ndarray, grid: GridLike, xy: np.ndarray) -> None:
    """Set the cells containing world points ``xy`` (K, 2) (those inside the grid)."""
    rc = np.asarray(grid.cell_of(xy)).reshape(-1, 2)
    ok = (rc[:, 0] >= 0) & (rc[:, 0] < mask.shape[0]) & (rc[:, 1] >= 0) & (rc[:, 1] < mask.shape[1])
    mask[rc[ok, 0], rc[ok, 1]] = True


def seen_floor_cells(depth: np.ndarray, pose, camera: CameraConfig, grid: GridLike, floor_z: float = 0.0,
                     config: CoverageConfig = CoverageConfig()) -> np.ndarray:
    """Grid cells whose floor this depth frame sees: an (M, M) bool mask.

    ``depth``: (H, W) or (H, W, 1) z-depth, metres (0 or NaN = no surface), at the camera's
    resolution; ``pose``: robot ``(x, y, yaw)``; ``grid``: (M, M) cells (see :class:`GridLike`).

    Every pixel is back-projected (:func:`nue.sim.camera.depth_to_points`); a pixel *sees floor*
    when its point lies within ``floor_tolerance`` of the floor plane. A cell is seen when its
    centre is within ``max_range`` (xy) of the robot, projects (on the floor plane) into the image,
    and the pixel it lands in sees floor (so occluded floor does not count), or when a floor point
    falls inside it. Projecting cell centres leaves no holes where far floor rows are sparse.
    """
    z, pts = _frame_points(depth, pose, camera, floor_z)
    return _floor_mask(z, pts, pose, camera, grid, floor_z, config)


def _floor_mask(z, pts, pose, camera: CameraConfig, grid: GridLike, floor_z: float, config: CoverageConfig) -> np.ndarray:
    h, w = camera.height, camera.width
    x0, y0 = float(pose[0]), float(pose[1])
    floor_px = (z > 0) & (np.abs(pts[..., 2] - floor_z) <= config.floor_tolerance)
    floor_px &= np.hypot(pts[..., 0] - x0, pts[..., 1] - y0) <= config.max_range
    m_rows, m_cols = grid.free.shape
    mask = np.zeros((m_rows, m_cols), dtype=bool)
    # 1) cells containing a floor point
    _mark(mask, grid, pts[floor_px][:, :2])
    # 2) cells in range whose centre's floor point projects onto a pixel that sees floor
    lo = np.asarray(grid.cell_of((x0 - config.max_range, y0 - config.max_range)))
    hi = np.asarray(grid.cell_of((x0 + config.max_range, y0 + config.max_range)))
    lo, hi = np.clip(lo, 0, [m_rows - 1, m_cols - 1]), np.clip(hi, 0, [m_rows - 1, m_cols - 1])
    rr, cc = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1), indexing="ij")
    cells = np.stack([rr.ravel(), cc.ravel()], axis=-1)
    centres = np.asarray(grid.cell_centre(cells))
    near = np.hypot(centres[:, 0] - x0, centres[:, 1] - y0) <= config.max_range
    cells, centres = cells[near], centres[near]
    m = world_from_camera(pose, camera, floor_z)
    p = np.c_[centres, np.full(len(centres), floor_z)]
    p_cam = (p - m[:3, 3]) @ m[:3, :3]  # world -> camera (rotation is orthonormal)
    front = p_cam[:, 2] > 1e-6
    u = np.floor(camera.fx * p_cam[front, 0] / p_cam[front, 2] + camera.cx).astype(np.int64)
    v = np.floor(camera.fy * p_cam[front, 1] / p_cam[front, 2] + camera.cy).astype(np.int64)
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    cells = cells[front][inside]
    sees = floor_px[v[inside], u[inside]]
    mask[cells[sees, 0], cells[sees, 1]] = True
    return mask


def seen_obstacle_cells(depth: np.ndarray, pose, camera: CameraConfig, grid: GridLike, floor_z: float = 0.0,
                        config: CoverageConfig = CoverageConfig()) -> np.ndarray:
    """Grid cells this depth frame shows as obstacle: an (M, M) bool mask.

    Same inputs as :func:`seen_floor_cells`. A cell is an obstacle cell when a back-projected point
    between ``obstacle_min_height`` and ``obstacle_max_height`` above the floor, within
    ``max_range`` (xy) of the robot, falls inside it (the faces of walls and furniture; ceilings
    and door lintels are above the band). A cell may be both floor-seen and obstacle (a wall's foot).
    """
    z, pts = _frame_points(depth, pose, camera, floor_z)
    return _obstacle_mask(z, pts, pose, grid, floor_z, config)


def _obstacle_mask(z, pts, pose, grid: GridLike, floor_z: float, config: CoverageConfig) -> np.ndarray:
    height = pts[..., 2] - floor_z
    hit = (z > 0) & (height >= config.obstacle_min_height) & (height <= config.obstacle_max_height)
    hit &= np.hypot(pts[..., 0] - float(pose[0]), pts[..., 1] - float(pose[1])) <= config.max_range
    mask = np.zeros(grid.free.shape, dtype=bool)
    _mark(mask, grid, pts[hit][:, :2])
    return mask


def seen_cells(depth: np.ndarray, pose, camera: CameraConfig, grid: GridLike, floor_z: float = 0.0,
               config: CoverageConfig = CoverageConfig()) -> tuple[np.ndarray, np.ndarray]:
    """``(seen_floor_cells(...), seen_obstacle_cells(...))`` of one frame, back-projecting it once."""
    z, pts = _frame_points(depth, pose, camera, floor_z)
    return _floor_mask(z, pts, pose, camera, grid, floor_z, config), _obstacle_mask(z, pts, pose, grid, floor_z, config)
