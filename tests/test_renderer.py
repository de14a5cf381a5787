"""EGL renderer: analytic depth of planes (corners included), yaw convention, textures, PLY and y-up GLB."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from PIL import Image

from nue.sim.camera import camera_rays, depth_to_points
from nue.sim.renderer import Renderer
from nue.sim.task import CameraConfig

CAM = CameraConfig()


def _box(lo, hi, colour=(200, 200, 200, 255)):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    m = trimesh.creation.box(extents=hi - lo)
    m.apply_translation((lo + hi) / 2)
    m.visual.face_colors = colour
    return m


def test_depth_of_a_fronto_parallel_wall_is_constant_to_the_corners():
    wall = _box((2.5, -50, -50), (2.6, 50, 50))
    _, depth = Renderer(wall, CAM).render((0.0, 0.0, 0.0))
    assert depth.shape == (180, 240) and depth.dtype == np.float32
    np.testing.assert_allclose(depth, 2.5, atol=1e-5)  # z-depth, not range: the corners too


def test_depth_of_the_floor_matches_the_pinhole_formula_per_row():
    floor = _box((-50, -50, -0.1), (50, 50, 0.0))
    _, depth = Renderer(floor, CAM).render((0.0, 0.0, 0.3))
    v = np.arange(CAM.height)
    below = v + 0.5 > CAM.cy
    expected = CAM.mount_height * CAM.fy / (v[below] + 0.5 - CAM.cy)
    far_ok = expected < CAM.far
    got = depth[below]
    np.testing.assert_allclose(got[far_ok], np.repeat(expected[far_ok, None], CAM.width, 1), rtol=1e-4)
    assert np.all(depth[~below] == 0.0)  # the sky: no surface, depth 0
    assert depth[-1, 0] == pytest.approx(0.6 * 120 / 89.5, rel=1e-5)  # bottom-left corner


def test_back_projected_depth_lands_on_the_surface_at_corners():
    room = _box((-3, -3, 0), (3, 3, 2.6))
    pose = (0.4, -0.7, 0.9)
    _, depth = Renderer(room, CAM).render(pose)
    pts = depth_to_points(depth, pose, CAM)
    for r, c in [(0, 0), (0, 239), (179, 0), (179, 239), (90, 120)]:
        p = pts[r, c]
        # a point of the box room lies on one of its six faces
        dist = min(abs(p[0] - 3), abs(p[0] + 3), abs(p[1] - 3), abs(p[1] + 3), abs(p[2]), abs(p[2] - 2.6))
        assert dist < 2e-4, (r, c, p)
    origin, dirs, range_per_z = camera_rays(pose, CAM)
    np.testing.assert_allclose(origin + dirs[0, 0] * depth[0, 0] * range_per_z[0, 0], pts[0, 0], atol=1e-6)


def test_yaw_is_counter_clockwise_from_x_and_left_is_left():
    red = _box((-0.5, 2.0, 0.0), (0.5, 2.2, 2.0), (255, 0, 0, 255))
    blue = _box((2.0, 1.0, 0.0), (2.2, 3.0, 2.0), (0, 0, 255, 255))
    r = Renderer(trimesh.Scene([red, blue]), CAM)
    rgb, depth = r.render((0.0, 0.0, np.pi / 2))  # facing +y: red wall ahead
    assert rgb[90, 120, 0] > 150 and rgb[90, 120, 2] < 50
    assert depth[90, 120] == pytest.approx(2.0, abs=1e-4)
    # facing +y, +x is on the right: the blue box appears in the right half of the image
    blue_cols = np.nonzero((rgb[90, :, 2] > 150) & (rgb[90, :, 0] < 50))[0]
    assert blue_cols.size > 0 and blue_cols.min() > 120


def test_texture_is_not_upside_down():
    img = np.zeros((64, 64, 3), np.uint8)
    img[:32] = (255, 0, 0)  # top half of the image red
    img[32:] = (0, 0, 255)  # bottom half blue
    verts = np.array([[3, -3, 0], [3, 3, 0], [3, 3, 3], [3, -3, 3]], float)
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)  # OBJ convention: v = 1 is the image top
    quad = trimesh.Trimesh(verts, [[0, 1, 2], [0, 2, 3]], process=False)
    quad.visual = trimesh.visual.TextureVisuals(uv=uv, image=Image.fromarray(img))
    rgb, _ = Renderer(quad, CAM).render((0.0, 0.0, 0.0))
    assert rgb[10, 120, 0] > 150 and rgb[10, 120, 2] < 50  # looking up: top of the wall, red
    assert rgb[90, 120, 2] > 150 and rgb[90, 120, 0] < 50  # straight ahead: z = 0.6, v = 0.2, blue


def test_ply_with_vertex_colours(tmp_path):
    m = _box((2.0, -5, -5), (2.2, 5, 5))
    m.visual = trimesh.visual.ColorVisuals(m, vertex_colors=np.tile([[0, 255, 0, 255]], (len(m.vertices), 1)))
    path = tmp_path / "wall.ply"
    m.export(path)
    rgb, depth = Renderer(path, CAM).render((0.0, 0.0, 0.0))
    assert depth[90, 120] == pytest.approx(2.0, abs=1e-4)
    assert rgb[90, 120, 1] > 150 and rgb[90, 120, 0] < 50


def test_y_up_glb_renders_like_z_up(tmp_path):
    room = _box((-3, -2, 0), (4, 3, 2.6))
    yup = room.copy()
    yup.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))  # z-up -> y-up
    path = tmp_path / "room.glb"
    yup.export(path)
    pose = (0.5, 0.2, 2.0)
    _, d_ref = Renderer(room, CAM).render(pose)
    _, d_glb = Renderer(path, CAM, up_axis="y").render(pose)
    np.testing.assert_allclose(d_glb, d_ref, atol=1e-4)


def test_rendering_is_deterministic(box_renderer):
    a = box_renderer.render((0.3, 0.2, 1.0))
    b = box_renderer.render((0.3, 0.2, 1.0))
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
