"""Test helper for the NeRF tests (imported, not collected): an analytic box room ray-cast in numpy (RGB-D frames + a trajectory).

Not a renderer for the package: a closed-form scene whose geometry is known exactly, for unit tests
of the memory that must run without the EGL renderer.
"""

from __future__ import annotations

import math

import numpy as np

from nue.sim.camera import camera_rays
from nue.sim.task import CameraConfig

ROOM = (np.array([-3.0, -2.5, 0.0]), np.array([3.0, 2.5, 2.5]))
BOX = (np.array([0.4, 0.2, 0.0]), np.array([1.2, 1.2, 0.9]))
FACE_COLOURS = np.array(
    [[0.8, 0.3, 0.2], [0.2, 0.6, 0.8], [0.3, 0.7, 0.3], [0.8, 0.7, 0.2], [0.6, 0.5, 0.4], [0.9, 0.9, 0.85], [0.5, 0.2, 0.6]]
)


def _texture(points: np.ndarray, face: np.ndarray) -> np.ndarray:
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    pattern = 0.75 + 0.25 * np.sin(2 * np.pi * (x + y) / 1.3) * np.cos(2 * np.pi * z / 0.9 + x)
    return np.clip(FACE_COLOURS[face] * pattern[..., None], 0.0, 1.0)


def box_room_frame(pose, camera: CameraConfig = CameraConfig(), floor_z: float = 0.0):
    """Ray-cast the box room from a robot pose: ``(rgb (H, W, 3) uint8, depth (H, W) float32 z-depth)``."""
    origin, dirs, range_per_z = camera_rays(pose, camera, floor_z)
    d = np.where(np.abs(dirs) < 1e-12, 1e-12, dirs)
    lo, hi = ROOM
    t_exit = np.where(d > 0, (hi - origin) / d, (lo - origin) / d)  # (H, W, 3)
    t_room = t_exit.min(axis=-1)
    face = np.argmin(t_exit, axis=-1) * 2 + (np.take_along_axis(d, np.argmin(t_exit, axis=-1)[..., None], -1)[..., 0] > 0)
    blo, bhi = BOX
    t1, t2 = (blo - origin) / d, (bhi - origin) / d
    t_in, t_out = np.minimum(t1, t2).max(axis=-1), np.maximum(t1, t2).min(axis=-1)
    hit_box = (t_in < t_out) & (t_in > 0) & (t_in < t_room)
    t = np.where(hit_box, t_in, t_room)
    face = np.where(hit_box, 6, face)
    points = origin + t[..., None] * dirs
    rgb = (_texture(points, face) * 255).round().astype(np.uint8)
    depth = (t / range_per_z).astype(np.float32)
    return rgb, depth


def box_room_trajectory(n_steps: int = 24) -> list[np.ndarray]:
    """Robot poses (x, y, yaw) like an expert's: turn left 15 deg x 6, forward 0.25 m x 8, turn right
    15 deg x 6, forward x 4, repeated; stays inside the room and clear of the box."""
    plan = ["L"] * 6 + ["F"] * 8 + ["R"] * 6 + ["F"] * 4
    poses, pose = [], np.array([-2.0, -1.6, 0.0])
    for i in range(n_steps):
        poses.append(pose.copy())
        a = plan[i % len(plan)]
        if a == "F":
            pose[:2] += 0.25 * np.array([math.cos(pose[2]), math.sin(pose[2])])
        else:
            pose[2] += math.radians(15.0) * (1 if a == "L" else -1)
    return poses

