"""Gibson-layout reader: pixel convention on a hand-written asymmetric fixture, content hash, bad input."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from PIL import Image

from nue.errors import SceneError
from nue.scene.scene import Scene, trav_pixel_from_world, world_from_trav_pixel

from .conftest import BOX_ROOM


def test_igibson_pixel_convention():
    assert tuple(trav_pixel_from_world((1.0, -2.0), 1000)) == (300, 600)
    np.testing.assert_allclose(world_from_trav_pixel((300, 600), 1000), (1.005, -1.995))


def test_fixture_map_puts_the_obstacle_at_world_1_minus_2(box_scene):
    trav = box_scene.trav_maps[0]
    assert trav.shape == (1000, 1000)
    assert not trav[300, 600]  # the obstacle at world (1.0, -2.0)
    assert trav[600, 300]  # its mirror image (-2.0, 1.0) is free floor: a transposed reader fails
    assert trav[700, 600]  # (1.0, 2.0): open floor
    assert box_scene.floor_heights == (0.0,)


def test_rendered_depth_hits_the_obstacle_where_the_map_says(box_renderer):
    # Standing at (1.0, -0.5) looking along -y, the obstacle's face at y = -1.7 is 1.2 m ahead.
    _, depth = box_renderer.render((1.0, -0.5, -np.pi / 2))
    assert depth[90, 120] == pytest.approx(1.2, abs=1e-4)
    # Where a transposed reader would put it, (-2.0, 1.0), there is nothing: looking along -y from
    # (-2.0, 2.5), the ray passes (-2.0, 1.0) and meets the south wall at y = -3.
    _, depth = box_renderer.render((-2.0, 2.5, -np.pi / 2))
    assert depth[90, 120] == pytest.approx(5.5, abs=1e-4)


def test_content_hash_is_stable_and_sees_changes(tmp_path, box_scene):
    copy = tmp_path / "room"
    shutil.copytree(BOX_ROOM, copy)
    assert Scene.load(copy).content_hash == box_scene.content_hash
    (copy / "mesh_z_up.mtl").write_text((copy / "mesh_z_up.mtl").read_text().replace("Kd 0.1", "Kd 0.2"))
    assert Scene.load(copy).content_hash != box_scene.content_hash


def _broken_copy(tmp_path):
    copy = tmp_path / "broken"
    shutil.copytree(BOX_ROOM, copy)
    return copy


def test_missing_folder(tmp_path):
    with pytest.raises(SceneError, match="scene folder not found"):
        Scene.load(tmp_path / "nope")


def test_missing_mesh(tmp_path):
    d = _broken_copy(tmp_path)
    (d / "mesh_z_up.obj").unlink()
    with pytest.raises(SceneError, match=r"mesh_z_up.obj: mesh file not found"):
        Scene.load(d)


def test_corrupt_mesh(tmp_path):
    d = _broken_copy(tmp_path)
    (d / "mesh_z_up.obj").write_bytes(b"\x00\x01garbage\xff" * 50)
    scene = Scene.load(d)
    with pytest.raises(SceneError, match=r"mesh_z_up.obj: .*(cannot read mesh|no triangles)"):
        scene.load_mesh()


def test_missing_floors(tmp_path):
    d = _broken_copy(tmp_path)
    (d / "floors.txt").unlink()
    with pytest.raises(SceneError, match=r"floors.txt: floors.txt not found"):
        Scene.load(d)


def test_bad_floors(tmp_path):
    d = _broken_copy(tmp_path)
    (d / "floors.txt").write_text("zero\n")
    with pytest.raises(SceneError, match=r"floors.txt: line 1: not a number"):
        Scene.load(d)


def test_trav_map_wrong_mode(tmp_path):
    d = _broken_copy(tmp_path)
    Image.new("RGB", (100, 100), (255, 255, 255)).save(d / "floor_trav_0.png")
    with pytest.raises(SceneError, match=r"floor_trav_0.png: .*mode 'L'.*'RGB'"):
        Scene.load(d)


def test_trav_map_not_square(tmp_path):
    d = _broken_copy(tmp_path)
    Image.new("L", (100, 80), 255).save(d / "floor_trav_0.png")
    with pytest.raises(SceneError, match=r"floor_trav_0.png: .*square, got 100 x 80"):
        Scene.load(d)


def test_missing_trav_map_for_a_listed_floor(tmp_path):
    d = _broken_copy(tmp_path)
    (d / "floors.txt").write_text("0.0\n3.0\n")
    with pytest.raises(SceneError, match=r"floor_trav_1.png: traversability map not found"):
        Scene.load(d)


def test_floor_of(box_scene):
    assert box_scene.floor_of(0.39) == 0
