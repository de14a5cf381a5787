"""What one depth frame shows of the floor grid: the floor cells it sees and the cells it shows as obstacle.

Per-frame geometry shared by the exploring expert (its own seen map) and the evaluation's coverage
(the evaluation's coverage tracker re-exports these names). A floor cell is *seen* when the depth camera
sees the floor there (not occluded, within ``max_range`` metres of the robot; see
:func:`seen_floor_cells`); a cell is an *obstacle* cell when a depth point above the floor (a wall,
furniture) lands in it (:func:`seen_obstacle_cells`). Grids are (M, M) planning cells of a
:class:`GridLike` (``nue.scene.navgrid.NavGrid`` fits).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from nue.sim.camera import depth_to_points, pixel_directions, world_from_camera
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
    occlusion_rows: float | None = 0.5
    """A cell whose centre projects onto a floor-seeing pixel counts only if that pixel's depth is within
    ``floor_tolerance`` plus this many pixel rows' floor span of the centre's own depth. The centre projects within
    half a pixel of the pixel's centre, so true floor passes at 0.5; the foot of a wall (which sees "floor" within
    the tolerance) does not pass for the floor behind the wall that projects onto it. None = no depth check (as
    seen cells were counted before: floor up to ~1 m behind walls, and under them, counted as seen)."""


def cell_area(grid: GridLike) -> float:
    """Area of one grid cell, m²."""
    return float(grid.cell) ** 2


class _Frame:
    """One depth frame back-projected as :func:`nue.sim.camera.depth_to_points` does it, lazily: the world z
    of every pixel, world (x, y) only of the pixels asked for.

    The values are those of the full back-projection, bit for bit. The camera's y axis is the world's -z
    (level camera), so the matmul's z row has a single non-zero term and equals ``t_z - y_cam`` exactly; x
    and y come from the same matmul on the chosen rows only (BLAS computes each row on its own: the
    rows do not depend on which others are in the call; ``tests/test_explorer.py`` checks this against the
    full back-projection). Depth that would overflow (an inf depth became the largest float in
    ``nan_to_num``) falls back to the full back-projection.
    """

    def __init__(self, depth: np.ndarray, pose, camera: CameraConfig, floor_z: float):
        z = np.array(depth, dtype=np.float64).reshape(camera.height, camera.width)
        # nan_to_num makes six passes over the frame; one finiteness test spares them when there is nothing to replace
        self.z = z if np.isfinite(z).all() else np.nan_to_num(z, copy=False, nan=0.0)
        self.m = world_from_camera(pose, camera, floor_z)
        self._dirs = _pixel_directions(camera).reshape(-1, 3)
        level = self.m[2, 0] == 0.0 and self.m[2, 1] == -1.0 and self.m[2, 2] == 0.0
        full = not (level and self.z.max() < 1e30)
        self._points = depth_to_points(self.z, pose, camera, floor_z).reshape(-1, 3) if full else None

    def world_z(self) -> np.ndarray:
        """(H, W) world z of every pixel's point."""
        if self._points is not None:
            return self._points[:, 2].reshape(self.z.shape)
        return self.m[2, 3] - self._dirs[:, 1].reshape(self.z.shape) * self.z

    def world_xy(self, flat: np.ndarray) -> np.ndarray:
        """(K, 2) world (x, y) of the pixels with flat indices ``flat (K,)``."""
        if self._points is not None:
            return self._points[flat, :2]
        # np.take gathers rows ~2x faster than fancy indexing (the same values)
        p_cam = np.take(self._dirs, flat, axis=0) * np.take(self.z.reshape(-1), flat)[:, None]
        return (p_cam @ self.m[:3, :3].T + self.m[:3, 3])[:, :2]


@functools.lru_cache(maxsize=8)
def _pixel_directions(camera: CameraConfig) -> np.ndarray:
    """:func:`nue.sim.camera.pixel_directions`, computed once per camera (read-only)."""
    d = pixel_directions(camera)
    d.flags.writeable = False
    return d


def _mark(mask: np.ndarray, grid: GridLike, xy: np.ndarray) -> None:
    """Set the cells containing world points ``xy`` (K, 2) (those inside the grid) of a fresh ``mask`` (written
    through flat indices, cheaper than a 2-d fancy write)."""
    rc = np.asarray(grid.cell_of(xy)).reshape(-1, 2)
    r, c = rc[:, 0], rc[:, 1]
    ok = (r >= 0) & (r < mask.shape[0]) & (c >= 0) & (c < mask.shape[1])
    np.ravel(mask)[np.compress(ok, r * mask.shape[1] + c)] = True


def _within(dx: np.ndarray, dy: np.ndarray, r: float) -> np.ndarray:
    """``np.hypot(dx, dy) <= r``, evaluating hypot only where ``dx^2 + dy^2`` is within 1e-9 of ``r^2``
    (elsewhere the squared distance decides the same way: both are accurate to a few ulp)."""
    d2 = dx * dx + dy * dy
    out = d2 <= r * r * (1.0 - 1e-9)
    edge = ~out & (d2 <= r * r * (1.0 + 1e-9))
    if edge.any():
        out[edge] = np.hypot(dx[edge], dy[edge]) <= r
    return out


def _view_box(pose, camera: CameraConfig, radius: float):
    """World ``((x_lo, y_lo), (x_hi, y_hi))`` around every floor point within ``radius`` (xy) of the camera
    whose bearing lies within the image's horizontal field of view (+ 0.01 rad), or None if that field is
    too wide to bound this way."""
    half = math.atan(max(camera.cx, camera.width - camera.cx) / camera.fx) + 0.01
    if half >= math.pi / 2:
        return None
    x0, y0, yaw = float(pose[0]), float(pose[1]), float(pose[2])
    angles = [yaw - half, yaw + half]
    angles += [k * math.pi / 2 for k in range(4) if abs(math.remainder(k * math.pi / 2 - yaw, 2 * math.pi)) <= half]
    xs = [x0] + [x0 + radius * math.cos(t) for t in angles]
    ys = [y0] + [y0 + radius * math.sin(t) for t in angles]
    return (min(xs), min(ys)), (max(xs), max(ys))


def seen_floor_cells(depth: np.ndarray, pose, camera: CameraConfig, grid: GridLike, floor_z: float = 0.0,
                     config: CoverageConfig = CoverageConfig(), *, known: np.ndarray | None = None,
                     centres: np.ndarray | None = None) -> np.ndarray:
    """Grid cells whose floor this depth frame sees: an (M, M) bool mask.

    ``depth``: (H, W) or (H, W, 1) z-depth, metres (0 or NaN = no surface), at the camera's
    resolution; ``pose``: robot ``(x, y, yaw)``; ``grid``: (M, M) cells (see :class:`GridLike`).

    Every pixel is back-projected (:func:`nue.sim.camera.depth_to_points`); a pixel *sees floor*
    when its point lies within ``floor_tolerance`` of the floor plane. A cell is seen when its
    centre is within ``max_range`` (xy) of the robot, projects (on the floor plane) into the image,
    and the pixel it lands in sees floor (so occluded floor does not count), or when a floor point
    falls inside it. Projecting cell centres leaves no holes where far floor rows are sparse.

    For a caller accumulating the union over frames: ``known`` (M, M) are cells already seen, which are
    then not projected (they may be missing from the mask, so only ``mask | known`` is the same as
    without ``known``); ``centres`` (M, M, 2) = ``grid.cell_centre`` of every cell, computed once.
    """
    return _floor_mask(_Frame(depth, pose, camera, floor_z), pose, camera, grid, floor_z, config, centres, known)


def _floor_mask(frame: _Frame, pose, camera: CameraConfig, grid: GridLike, floor_z: float, config: CoverageConfig,
                centres: np.ndarray | None = None, skip: np.ndarray | None = None) -> np.ndarray:
    h, w = camera.height, camera.width
    x0, y0 = float(pose[0]), float(pose[1])
    floor_px = (frame.z > 0) & (np.abs(frame.world_z() - floor_z) <= config.floor_tolerance)
    flat = np.flatnonzero(floor_px)
    xy = frame.world_xy(flat)
    near = _within(xy[:, 0] - x0, xy[:, 1] - y0, config.max_range)
    floor_px = np.zeros(h * w, dtype=bool)
    floor_px[np.compress(near, flat)] = True
    floor_px = floor_px.reshape(h, w)
    m_rows, m_cols = grid.free.shape
    mask = np.zeros((m_rows, m_cols), dtype=bool)
    # 1) cells containing a floor point
    _mark(mask, grid, np.compress(near, xy, axis=0))
    # 2) cells in range whose centre's floor point projects onto a pixel that sees floor
    lo = np.asarray(grid.cell_of((x0 - config.max_range, y0 - config.max_range)))
    hi = np.asarray(grid.cell_of((x0 + config.max_range, y0 + config.max_range)))
    lo, hi = np.clip(lo, 0, [m_rows - 1, m_cols - 1]), np.clip(hi, 0, [m_rows - 1, m_cols - 1])
    view = _view_box(pose, camera, config.max_range)
    if view is not None:  # only cells in the field of view can project into the image
        lo = np.maximum(lo, np.asarray(grid.cell_of(view[0])) - 1)
        hi = np.minimum(hi, np.asarray(grid.cell_of(view[1])) + 1)
        if (hi < lo).any():
            return mask
    box = (slice(lo[0], hi[0] + 1), slice(lo[1], hi[1] + 1))
    if centres is not None:
        box_centres = centres[box]
    else:
        rr, cc = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1), indexing="ij")
        box_centres = np.asarray(grid.cell_centre(np.stack([rr, cc], axis=-1)))
    keep = _within(box_centres[..., 0] - x0, box_centres[..., 1] - y0, config.max_range)
    if skip is not None:
        keep &= ~skip[box]
    sel = np.flatnonzero(keep)
    m = frame.m
    p = np.empty((sel.size, 3))
    p[:, 0] = box_centres[..., 0][keep]  # the cells of ``sel``, in its order, without copying the whole box first
    p[:, 1] = box_centres[..., 1][keep]
    p[:, 2] = floor_z
    p_cam = (p - m[:3, 3]) @ m[:3, :3]  # world -> camera (rotation is orthonormal)
    front = np.flatnonzero(p_cam[:, 2] > 1e-6)
    pf = np.take(p_cam, front, axis=0)
    u = np.floor(camera.fx * pf[:, 0] / pf[:, 2] + camera.cx).astype(np.int64)
    v = np.floor(camera.fy * pf[:, 1] / pf[:, 2] + camera.cy).astype(np.int64)
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    sees = np.zeros(front.size, dtype=bool)
    sees[inside] = floor_px[v[inside], u[inside]]
    if config.occlusion_rows is not None and sees.any():
        # one pixel row spans (z² + h²) / (h fy) metres of floor at z-depth z for a level camera h above the floor
        k = np.flatnonzero(sees)
        zc = pf[k, 2]
        h_cam = max(float(m[2, 3]) - floor_z, 1e-3)
        tol = config.floor_tolerance + config.occlusion_rows * (zc * zc + h_cam * h_cam) / (h_cam * camera.fy)
        sees[k] = np.abs(frame.z[v[k], u[k]] - zc) <= tol
    cells = sel[front[sees]]
    box_cols = hi[1] - lo[1] + 1
    mask[lo[0] + cells // box_cols, lo[1] + cells % box_cols] = True
    return mask


def seen_obstacle_cells(depth: np.ndarray, pose, camera: CameraConfig, grid: GridLike, floor_z: float = 0.0,
                        config: CoverageConfig = CoverageConfig()) -> np.ndarray:
    """Grid cells this depth frame shows as obstacle: an (M, M) bool mask.

    Same inputs as :func:`seen_floor_cells`. A cell is an obstacle cell when a back-projected point
    between ``obstacle_min_height`` and ``obstacle_max_height`` above the floor, within
    ``max_range`` (xy) of the robot, falls inside it (the faces of walls and furniture; ceilings
    and door lintels are above the band). A cell may be both floor-seen and obstacle (a wall's foot).
    """
    return _obstacle_mask(_Frame(depth, pose, camera, floor_z), pose, grid, floor_z, config)


def _obstacle_mask(frame: _Frame, pose, grid: GridLike, floor_z: float, config: CoverageConfig) -> np.ndarray:
    height = frame.world_z() - floor_z
    hit = (frame.z > 0) & (height >= config.obstacle_min_height) & (height <= config.obstacle_max_height)
    xy = frame.world_xy(np.flatnonzero(hit))
    near = _within(xy[:, 0] - float(pose[0]), xy[:, 1] - float(pose[1]), config.max_range)
    mask = np.zeros(grid.free.shape, dtype=bool)
    _mark(mask, grid, xy[near])
    return mask


def seen_cells(depth: np.ndarray, pose, camera: CameraConfig, grid: GridLike, floor_z: float = 0.0,
               config: CoverageConfig = CoverageConfig()) -> tuple[np.ndarray, np.ndarray]:
    """``(seen_floor_cells(...), seen_obstacle_cells(...))`` of one frame, back-projecting it once."""
    frame = _Frame(depth, pose, camera, floor_z)
    return _floor_mask(frame, pose, camera, grid, floor_z, config), _obstacle_mask(frame, pose, grid, floor_z, config)


def goal_in_view(depth: np.ndarray, pose, goal_cell: tuple[int, int], goal_xy, camera: CameraConfig, grid: GridLike,
                 floor_z: float = 0.0, view_range: float = 3.0, config: CoverageConfig = CoverageConfig()) -> bool:
    """Whether the goal is in view from ``pose`` (x, y, yaw): the robot is at most ``view_range`` metres from ``goal_xy``
    and ``depth`` (H, W[, 1]) metres sees the floor of ``goal_cell`` (row, col) — the exploring expert's switch."""
    if float(np.hypot(pose[0] - goal_xy[0], pose[1] - goal_xy[1])) > view_range:
        return False
    return bool(seen_floor_cells(depth, pose, camera, grid, floor_z, config)[goal_cell])
