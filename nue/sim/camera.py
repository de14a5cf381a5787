"""The one camera model: robot pose -> camera frame, pixel rays, depth back-projection, GL matrices.

Shared by the renderer (GL matrices), the environment and the NeRF memory (rays), so that a ray's
point at the rendered depth lands on the mesh.

Conventions: world z up, metres. A robot pose is ``(x, y, yaw)`` with yaw counter-clockwise from
+x; the camera sits ``mount_height`` above the floor and looks along the robot's +x. Camera frame
is OpenCV's: x right, y down, z forward. Pixel (row v, col u) has its centre at
``(u + 0.5, v + 0.5)``. Depth is z-depth: a unit ray at angle theta from the optical axis meets the
surface at ``t = z / cos(theta)``.
"""

from __future__ import annotations

import math

import numpy as np

from nue.sim.task import CameraConfig


def wrap_angle(a):
    """Wrap angle(s) in radians to (-pi, pi]."""
    w = np.mod(np.asarray(a, dtype=np.float64) + np.pi, 2 * np.pi) - np.pi
    w = np.where(w <= -np.pi, w + 2 * np.pi, w)
    return float(w) if np.ndim(w) == 0 else w


def quat_from_yaw(yaw: float) -> np.ndarray:
    """Quaternion (x, y, z, w) of a rotation by ``yaw`` about +z."""
    return np.array([0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)])


def yaw_from_quat(q) -> float:
    """Yaw of a quaternion (x, y, z, w): ``atan2(2(wz + xy), 1 - 2(y^2 + z^2))``."""
    x, y, z, w = (float(v) for v in q)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def world_from_camera(pose, camera: CameraConfig, floor_z: float = 0.0) -> np.ndarray:
    """4x4 transform from the (OpenCV) camera frame to world, for robot pose ``(x, y, yaw)``."""
    x, y, yaw = (float(v) for v in pose[:3])
    c, s = math.cos(yaw), math.sin(yaw)
    forward = np.array([c, s, 0.0])
    right = np.array([s, -c, 0.0])
    down = np.array([0.0, 0.0, -1.0])
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2] = right, down, forward
    m[:3, 3] = (x, y, floor_z + camera.mount_height)
    return m


def pixel_directions(camera: CameraConfig) -> np.ndarray:
    """Camera-frame ray directions with unit z for every pixel centre: (H, W, 3) float64.

    The norm of a direction is ``1 / cos(theta)``, so ``t = z * norm`` converts z-depth to range.
    """
    u = (np.arange(camera.width) + 0.5 - camera.cx) / camera.fx
    v = (np.arange(camera.height) + 0.5 - camera.cy) / camera.fy
    uu, vv = np.meshgrid(u, v)
    return np.stack([uu, vv, np.ones_like(uu)], axis=-1)


def camera_rays(pose, camera: CameraConfig, floor_z: float = 0.0):
    """World rays through every pixel centre.

    Returns ``(origin (3,), directions (H, W, 3) unit vectors, range_per_z (H, W))``, where
    ``range_per_z = 1 / cos(theta)``: the ray parameter of a surface at z-depth ``z`` is
    ``t = z * range_per_z``.
    """
    m = world_from_camera(pose, camera, floor_z)
    d_cam = pixel_directions(camera)
    norm = np.linalg.norm(d_cam, axis=-1)
    d_world = (d_cam / norm[..., None]) @ m[:3, :3].T
    return m[:3, 3].copy(), d_world, norm


def depth_to_points(depth: np.ndarray, pose, camera: CameraConfig, floor_z: float = 0.0) -> np.ndarray:
    """Back-project a z-depth image (H, W) or (H, W, 1), metres, to world points (H, W, 3)."""
    z = np.asarray(depth, dtype=np.float64).reshape(camera.height, camera.width)
    m = world_from_camera(pose, camera, floor_z)
    p_cam = pixel_directions(camera) * z[..., None]
    return p_cam @ m[:3, :3].T + m[:3, 3]


def gl_view_matrix(pose, camera: CameraConfig, floor_z: float = 0.0) -> np.ndarray:
    """4x4 OpenGL view matrix (world -> GL eye frame: x right, y up, looking down -z)."""
    cv_to_gl = np.diag([1.0, -1.0, -1.0, 1.0])
    return cv_to_gl @ np.linalg.inv(world_from_camera(pose, camera, floor_z))


def gl_projection_matrix(camera: CameraConfig) -> np.ndarray:
    """4x4 OpenGL projection matching the pinhole intrinsics exactly (principal point at the centre)."""
    n, f = camera.near, camera.far
    p = np.zeros((4, 4))
    p[0, 0] = 2.0 * camera.fx / camera.width
    p[1, 1] = 2.0 * camera.fy / camera.height
    p[0, 2] = 1.0 - 2.0 * camera.cx / camera.width
    p[1, 2] = 2.0 * camera.cy / camera.height - 1.0
    p[2, 2] = -(f + n) / (f - n)
    p[2, 3] = -2.0 * f * n / (f - n)
    p[3, 2] = -1.0
    return p
