"""Tests of the procedural house generator: layout rules, file format, determinism, mesh/map agreement."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image
from scipy import ndimage

from nue.errors import ConfigError, SceneError
from nue.scene import generator
from nue.scene.generator import SPLITS, HouseConfig, generate_house, generate_split

SEEDS = SPLITS["train"][:4] + SPLITS["val"][:4]
FOUR = ndimage.generate_binary_structure(2, 1)


@pytest.fixture(scope="module")
def houses(tmp_path_factory) -> dict[int, Path]:
    root = tmp_path_factory.mktemp("houses")
    return {seed: generate_house(seed, root / f"h{seed}") for seed in SEEDS}


def _meta(folder: Path) -> dict:
    return json.loads((folder / "house.json").read_text())


def _trav(folder: Path) -> np.ndarray:
    return np.array(Image.open(folder / "floor_trav_0.png"))


def _pix(xy, n: int) -> tuple[int, int]:
    """World (x, y) -> (row, col), iGibson convention."""
    return int(np.floor(xy[1] / 0.01 + n / 2)), int(np.floor(xy[0] / 0.01 + n / 2))


def _slice(rect, n: int):
    x0, y0, x1, y1 = (int(round(v * 100)) + n // 2 for v in rect)
    return slice(y0, y1), slice(x0, x1)


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_splits_fixed_and_disjoint():
    assert len(SPLITS["train"]) == 21 and len(SPLITS["val"]) == 14
    assert len(set(SPLITS["train"])) == 21 and len(set(SPLITS["val"])) == 14
    assert not set(SPLITS["train"]) & set(SPLITS["val"])


def test_rooms_and_floor_area(houses):
    for folder in houses.values():
        meta = _meta(folder)
        rooms = meta["rooms"]
        assert 3 <= len(rooms) <= 8
        assert len([r for r in rooms if r["kind"] != "hallway"]) >= 3
        area = sum((r["rect"][2] - r["rect"][0]) * (r["rect"][3] - r["rect"][1]) for r in rooms)
        assert 40.0 <= area <= 150.0
        assert abs(area - meta["floor_area"]) < 0.05
        assert len({r["name"] for r in rooms}) == len(rooms)


def test_trav_map_format(houses):
    for folder in houses.values():
        img = Image.open(folder / "floor_trav_0.png")
        assert img.mode == "L" and img.size[0] == img.size[1] and img.size[0] % 2 == 0
        trav = np.array(img)
        assert set(np.unique(trav)) == {0, 255}
        assert ndimage.label(trav > 0, structure=FOUR)[1] == 1  # largest component only
        n = trav.shape[0]
        fp = _meta(folder)["footprint"]
        assert max(abs(v) for v in fp) * 100 < n / 2  # the house fits and is centred on the origin
        assert (folder / "floors.txt").read_text().split() == ["0.0"]


def test_doors_wide_and_open(houses):
    for folder in houses.values():
        meta, trav = _meta(folder), _trav(folder)
        n = trav.shape[0]
        assert len(meta["doors"]) >= len(meta["rooms"]) - 1
        for door in meta["doors"]:
            assert door["width"] >= 0.9
            patch = trav[_slice(door["rect"], n)] > 0
            assert patch.all()
            across = patch.shape[0] if door["axis"] == "x" else patch.shape[1]
            assert across >= 90


def test_free_space_connected_reaches_rooms_and_is_long(houses):
    for folder in houses.values():
        meta, trav = _meta(folder), _trav(folder)
        n = trav.shape[0]
        core = ndimage.distance_transform_edt(trav > 0) * 0.01 > 0.18
        labels, count = ndimage.label(core, structure=FOUR)
        assert count == 1
        for room in meta["rooms"]:
            assert core[_slice(room["rect"], n)].any(), room["name"]
        for door in meta["doors"]:
            x0, y0, x1, y1 = door["rect"]
            assert core[_pix(((x0 + x1) / 2, (y0 + y1) / 2), n)]
        rows, cols = np.nonzero(core)
        assert max(np.ptp(rows), np.ptp(cols)) * 0.01 >= 9.0


def test_furniture_and_pictures(houses):
    for folder in houses.values():
        meta, trav = _meta(folder), _trav(folder)
        n = trav.shape[0]
        assert len(meta["furniture"]) >= len(meta["rooms"])
        for item in meta["furniture"]:
            assert not trav[_slice(item["rect"], n)].any()
        pics = meta["pictures"]
        assert len(pics) >= 3
        for pic in pics:
            assert 1.1 - 1e-6 <= pic["z"][0] < pic["z"][1] <= 1.9 + 1e-6
        digests = {hashlib.sha256((folder / "textures" / f"{p['texture']}.png").read_bytes()).hexdigest() for p in pics}
        assert len(digests) == len(pics)
        for kind in ("wall_texture", "floor_texture"):
            images = [np.array(Image.open(folder / "textures" / f"{r[kind]}.png")) for r in meta["rooms"]]
            assert len({im.tobytes() for im in images}) == len(images)


def test_mesh_loads_with_textures(houses):
    folder = houses[SEEDS[0]]
    scene = trimesh.load(folder / "mesh_z_up.obj", force="scene")
    mtl = (folder / "mesh_z_up.mtl").read_text()
    assert len(scene.geometry) == mtl.count("newmtl ") >= 10
    faces = 0
    for geom in scene.geometry.values():
        assert isinstance(geom.visual.material.image, Image.Image)
        assert geom.visual.uv is not None and len(geom.visual.uv) == len(geom.vertices)
        faces += len(geom.faces)
    assert faces == _meta(folder)["triangles"] < 5000
    lo, hi = scene.bounds
    assert lo[2] == pytest.approx(0.0) and hi[2] == pytest.approx(2.6)


def test_trav_map_agrees_with_mesh(houses):
    folder = houses[SEEDS[1]]
    meta, trav = _meta(folder), _trav(folder)
    n = trav.shape[0]
    mesh = trimesh.load(folder / "mesh_z_up.obj", force="mesh")
    tri = mesh.triangles[np.abs(mesh.face_normals[:, 2]) > 0.5]  # what a vertical ray can hit
    rng = np.random.default_rng(0)

    def first_hit_z(pixels):
        """z of the first surface met by a ray cast down from z = 2.08 (under door tops) at each
        pixel centre (NaN: none)."""
        pixels = np.asarray(pixels)
        xy = (pixels[:, ::-1] + 0.5 - n / 2) * 0.01  # pixel centre (col, row) -> (x, y)
        a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
        d = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
        px, py = xy[:, None, 0] - a[None, :, 0], xy[:, None, 1] - a[None, :, 1]
        u = (px * (c[:, 1] - a[:, 1]) - py * (c[:, 0] - a[:, 0])) / d
        v = (py * (b[:, 0] - a[:, 0]) - px * (b[:, 1] - a[:, 1])) / d
        hit = (u >= -1e-9) & (v >= -1e-9) & (u + v <= 1 + 1e-9)
        z = a[:, 2] + u * (b[:, 2] - a[:, 2]) + v * (c[:, 2] - a[:, 2])
        z = np.where(hit & (z < 2.08), z, -np.inf).max(axis=1)
        return np.where(np.isfinite(z), z, np.nan)

    free = np.argwhere(trav > 0)
    assert np.allclose(first_hit_z(free[rng.choice(len(free), 40, replace=False)]), 0.0, atol=1e-6)
    inside, outside = [], []
    for item in meta["furniture"][:12]:
        rs, cs = _slice(item["rect"], n)
        r0, r1, c0, c1 = rs.start, rs.stop, cs.start, cs.stop
        inside += [(r0, c0), (r1 - 1, c1 - 1), ((r0 + r1) // 2, (c0 + c1) // 2)]
        for r, c in ((r0 - 1, c0), (r1, c1 - 1), (r0, c0 - 1), (r1 - 1, c1)):
            if trav[r, c]:
                outside.append((r, c))
    assert np.all(first_hit_z(inside) > 0.3)  # furniture tops, all above the floor
    assert outside and np.allclose(first_hit_z(outside), 0.0, atol=1e-6)  # the pixel next to it is floor
    floor = np.zeros_like(trav, dtype=bool)  # room interiors and door openings
    for rect in [r["rect"] for r in meta["rooms"]] + [d["rect"] for d in meta["doors"]]:
        floor[_slice(rect, n)] = True
    walls = np.argwhere(~floor)
    z = first_hit_z(walls[rng.choice(len(walls), 200, replace=False)])
    assert not np.any(np.isclose(z, 0.0, atol=1e-6))  # walls and outside show no floor


def test_same_seed_same_bytes_different_seed_different_house(houses, tmp_path):
    seed = SEEDS[2]
    again = generate_house(seed, tmp_path / "again")
    assert _files(again) == _files(houses[seed])
    a, b = houses[SEEDS[2]], houses[SEEDS[3]]
    assert (a / "mesh_z_up.obj").read_bytes() != (b / "mesh_z_up.obj").read_bytes()
    assert _meta(a)["rooms"] != _meta(b)["rooms"]


def test_generate_split(tmp_path, monkeypatch):
    with pytest.raises(ConfigError):
        generate_split("test", tmp_path)
    monkeypatch.setitem(generator.SPLITS, "tiny", (SEEDS[0],))
    (tmp_path / ".tiny_00.tmp-999999999").mkdir()  # left by a killed run (no such process)
    (paths,) = generate_split("tiny", tmp_path, progress=False)
    assert paths == tmp_path / "tiny_00" and _meta(paths)["seed"] == SEEDS[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tiny_00"]  # no temporary folder left
    stamp = (paths / "mesh_z_up.obj").stat().st_mtime_ns
    assert generate_split("tiny", tmp_path, progress=False) == [paths]
    assert (paths / "mesh_z_up.obj").stat().st_mtime_ns == stamp  # complete house kept
    monkeypatch.setitem(generator.SPLITS, "tiny", (SEEDS[1],))
    with pytest.raises(SceneError):  # a complete folder holding another house is refused
        generate_split("tiny", tmp_path, progress=False)


def test_ensure_house_keeps_the_copy_another_process_renamed_in_first(tmp_path, monkeypatch):
    """Two evaluations starting on a machine without scenes both generate a missing house: the copy renamed
    into place first is kept whole (never removed under the other's reader) and the late copy is dropped."""
    monkeypatch.setitem(generator.SPLITS, "tiny", (SEEDS[0],))
    real = generator.generate_house
    winner = {}

    def racing(seed, out, config=None):  # the other process finishes first, mid-way through this generation
        winner["folder"] = real(seed, tmp_path / "tiny_00", config)
        winner["stamp"] = (tmp_path / "tiny_00" / "mesh_z_up.obj").stat().st_mtime_ns
        return real(seed, out, config)

    monkeypatch.setattr(generator, "generate_house", racing)
    folder = generator.ensure_house("tiny", 0, tmp_path)
    assert folder == winner["folder"] and _meta(folder)["seed"] == SEEDS[0]
    assert (folder / "mesh_z_up.obj").stat().st_mtime_ns == winner["stamp"]  # the first copy, untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tiny_00"]  # the late temporary copy is gone


def test_config_validation(tmp_path):
    with pytest.raises(ConfigError):
        generate_house(1, tmp_path, HouseConfig(door_width=(1.2, 0.9)))
    with pytest.raises(ConfigError):
        generate_house(1, tmp_path, HouseConfig(min_passage=0.2))
