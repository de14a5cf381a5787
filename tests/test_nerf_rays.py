"""The memory's rays follow the simulator's camera model: a ray's point at the rendered depth lies on
the mesh (corner pixels included), and the rays equal ``nue.sim.camera.camera_rays``."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from nue.nerf.rays import EpisodeFrame, PixelRays, map_pixels
from nue.sim.camera import camera_rays, depth_to_points
from nue.sim.task import CameraConfig

from .nerf_box_room import BOX, ROOM, box_room_frame

torch.set_num_threads(1)

WORLD = EpisodeFrame(origin=(0.0, 0.0, 0.0), yaw=0.0, radius=12.0)  # episode frame = world frame


def world_points(camera, pose, depth, floor_z=0.0):
    """Back-project a z-depth image with the memory's rays: (H * W, 3) world points (NaN where no depth)."""
    pr = PixelRays(camera)
    pix = torch.arange(camera.height * camera.width)
    ranges = pr.ranges_from_depth(depth)
    b = pr.bundle(pr.episode_from_camera(pose, WORLD, floor_z), pix, ranges)
    return (b.origins + b.ranges[:, None] * b.directions).double().numpy()


def distance_to_box_room(p):
    """Distance of points (N, 3) to the nearest face of ROOM (inside) or of BOX."""
    lo, hi = ROOM
    d_room = np.minimum(np.abs(p - lo), np.abs(hi - p)).min(axis=1)
    blo, bhi = BOX
    outside = np.maximum(np.maximum(blo - p, p - bhi), 0.0)
    d_box_out = np.linalg.norm(outside, axis=1)
    inside = np.all((p >= blo) & (p <= bhi), axis=1)
    d_box_in = np.minimum(p - blo, bhi - p).min(axis=1)
    d_box = np.where(inside, d_box_in, d_box_out)
    return np.minimum(d_room, d_box)


def box_room_mesh():
    trimesh = pytest.importorskip("trimesh")
    room = trimesh.creation.box(bounds=np.stack(ROOM))
    box = trimesh.creation.box(bounds=np.stack(BOX))
    room.visual.face_colors = [200, 120, 80, 255]
    box.visual.face_colors = [80, 120, 200, 255]
    return trimesh.util.concatenate([room, box])


@pytest.fixture(scope="module")
def renderer():
    try:
        from nue.sim.renderer import Renderer

        r = Renderer(box_room_mesh(), CameraConfig())
    except Exception as exc:  # no EGL on this machine
        pytest.skip(f"EGL renderer unavailable: {exc}")
    yield r
    r.release()


@pytest.mark.parametrize("pose", [(-2.0, -1.6, 0.0), (-1.0, 1.0, -0.9), (2.0, -1.0, 2.6), (-0.5, -0.6, math.radians(40))])
def test_rendered_depth_lands_on_the_mesh(renderer, pose):
    camera = renderer.camera
    rgb, depth = renderer.render(pose, floor_z=0.0)
    assert (depth > 0).all(), "the closed room is hit by every pixel"
    p = world_points(camera, pose, depth)
    err = distance_to_box_room(p)
    assert np.percentile(err, 99) < 0.01 and err.max() < 0.03
    h, w = camera.height, camera.width
    for r, c in [(0, 0), (0, w - 1), (h - 1, 0), (h - 1, w - 1)]:  # corner pixels: the largest angle off-axis
        assert err[r * w + c] < 0.01, (r, c, err[r * w + c])
    # the renderer and the analytic fixture agree, so fixture-based tests share the convention
    _, analytic = box_room_frame(pose, camera)
    close = np.abs(analytic - depth) < 0.01 * analytic
    assert close.mean() > 0.98


def test_floor_offset_and_map_pixels(renderer):
    """A floor at z = 0.5 raises the camera; rays built with the same floor_z still land on the mesh."""
    pose = (-1.5, 0.5, 0.4)
    camera = renderer.camera
    _, depth = renderer.render(pose, floor_z=0.5)
    assert distance_to_box_room(world_points(camera, pose, depth, floor_z=0.5)).max() < 0.03
    m = PixelRays(camera).episode_from_camera(pose, WORLD, floor_z=0.5)
    assert m[2, 3].item() == pytest.approx(0.5 + camera.mount_height)
    rows, cols = map_pixels(camera, 45, 60)
    assert rows[0] == 2 and cols[-1] == 238  # the pixel nearest each map-pixel centre
    assert (map_pixels(camera, 90, 120)[0] == np.arange(1, 180, 2)).all()  # every other pixel


def test_rays_equal_the_simulator_camera_rays():
    camera = CameraConfig()
    pose = (1.2, -0.7, 2.1)
    origin, dirs, range_per_z = camera_rays(pose, camera, 0.3)
    pr = PixelRays(camera)
    b = pr.bundle(pr.episode_from_camera(pose, WORLD, 0.3), torch.arange(camera.height * camera.width),
                  torch.zeros(camera.height * camera.width))
    assert np.allclose(b.origins[0].numpy(), origin, atol=1e-6)
    assert np.allclose(b.directions.numpy(), dirs.reshape(-1, 3), atol=1e-6)
    assert np.allclose(pr.range_per_z.numpy(), range_per_z.reshape(-1), atol=1e-6)


def test_episode_frame_is_the_start_camera():
    """Positions in the episode frame: the start camera at the origin looking along +x."""
    camera = CameraConfig()
    start = (2.0, 1.0, math.radians(90))
    frame = EpisodeFrame.from_pose(start, camera, floor_z=0.0, radius=12.0)
    pr = PixelRays(camera)
    m = pr.episode_from_camera(start, frame).numpy()
    assert np.allclose(m[:3, 3], 0.0, atol=1e-6)
    centre = camera.height // 2 * camera.width + camera.width // 2
    forward = pr.dirs[centre].numpy() @ m[:3, :3].T
    assert forward[0] > 0.99
    # a second pose 1 m ahead of the start (world +y here) sits at episode x = 1
    m2 = pr.episode_from_camera((2.0, 2.0, math.radians(90)), frame).numpy()
    assert np.allclose(m2[:3, 3], [1.0, 0.0, 0.0], atol=1e-6)


def test_box_room_points_lie_on_faces():
    """Fixture self-check: back-projected depth lands on the room's or the box's faces."""
    camera = CameraConfig().scaled(60, 45)
    pose = (-2.0, -1.6, 0.5)
    _, depth = box_room_frame(pose, camera)
    p = depth_to_points(depth, pose, camera)
    on_room = np.min(np.abs(np.concatenate([p - ROOM[0], ROOM[1] - p], -1)), -1) < 1e-6
    inside_box_slab = np.all((p >= BOX[0] - 1e-6) & (p <= BOX[1] + 1e-6), -1)
    assert np.all(on_room | inside_box_slab)
