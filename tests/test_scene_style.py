"""The held-out ``plain`` scene style: measured on generated houses it differs from ``gibson`` in the expected
direction (texture variance, wall colours, furniture proportions, wall height, room sizes), generation is
deterministic from the seed (arrays and meshes compared), and gibson houses are what they were."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from nue.scene import generator
from nue.scene.generator import SPLITS, generate_house, generate_split, house_problem, split_config
from nue.scene.house_config import ADDED_FIELDS, STYLES, HouseConfig, config_dict
from nue.scene.house_furnish import TEMPLATES

N = 2  # houses per style


@pytest.fixture(scope="module")
def houses(tmp_path_factory) -> dict[str, list[Path]]:
    root = tmp_path_factory.mktemp("styles")
    return {
        "gibson": [generate_house(SPLITS["val"][i], root / f"val_{i:02d}") for i in range(N)],
        "plain": [generate_house(SPLITS["val_plain"][i], root / f"val_plain_{i:02d}", STYLES["plain"]) for i in range(N)],
    }


def _meta(folder: Path) -> dict:
    return json.loads((folder / "house.json").read_text())


def _texture(folder: Path, name: str) -> np.ndarray:
    return np.asarray(Image.open(folder / "textures" / f"{name}.png"), dtype=np.float64) / 255.0


def _vertices(folder: Path) -> np.ndarray:
    lines = (folder / "mesh_z_up.obj").read_text().splitlines()
    return np.array([[float(v) for v in line.split()[1:]] for line in lines if line.startswith("v ")])


def _surfaces(folder: Path, key: str) -> list[np.ndarray]:
    return [_texture(folder, room[key]) for room in _meta(folder)["rooms"]]


def test_plain_surfaces_have_far_less_texture_variance(houses):
    """Within-texture standard deviation of every room's wall and floor texture."""
    spread = {style: np.mean([t.reshape(-1, 3).std(0).mean() for f in folders for key in ("wall_texture", "floor_texture")
                              for t in _surfaces(f, key)]) for style, folders in houses.items()}
    assert spread["plain"] < 0.25 * spread["gibson"], spread
    for folder in houses["plain"]:
        assert {r["wall_pattern"] for r in _meta(folder)["rooms"]} == {"plain"}


def test_plain_rooms_share_their_wall_colours(houses):
    """Rooms of a plain house take one of its two wall colours; every gibson room has its own."""
    for style, folders in houses.items():
        for folder in folders:
            means = np.array([t.reshape(-1, 3).mean(0) for t in _surfaces(folder, "wall_texture")])
            distinct = len({tuple(np.round(m, 2)) for m in means})
            if style == "plain":
                assert distinct <= 2 < len(means)
            else:
                assert distinct == len(means)


def test_plain_furniture_proportions_walls_and_rooms_differ(houses):
    def size_ratios(folder):
        """Per piece: height and elongation (long / short side) over its template's mid-range values, for the
        pieces whose template is clearly longer than deep (so the long side is the width before and after)."""
        out = []
        for it in _meta(folder)["furniture"]:
            (w, d, h, *_), (x0, y0, x1, y1) = TEMPLATES[it["kind"]], it["rect"]
            if np.mean(w) >= 1.5 * np.mean(d):
                long, short = max(x1 - x0, y1 - y0), min(x1 - x0, y1 - y0)
                out.append([100 * it["height"] / np.mean(h), (long / short) / (np.mean(w) / np.mean(d))])
        return np.array(out)

    ratios = {s: np.concatenate([size_ratios(f) for f in folders]).mean(0) for s, folders in houses.items()}
    assert ratios["plain"][0] < ratios["gibson"][0] - 0.1, ratios  # lower (heights x 0.8)
    assert ratios["plain"][1] > 1.2 * ratios["gibson"][1], ratios  # wider for their depth (x 1.25 / 0.85)
    top = {s: max(_vertices(f)[:, 2].max() for f in folders) for s, folders in houses.items()}
    assert top == {"gibson": pytest.approx(2.6), "plain": pytest.approx(2.8)}
    room_area = {s: np.mean([r["area"] for f in folders for r in _meta(f)["rooms"]]) for s, folders in houses.items()}
    assert room_area["plain"] < room_area["gibson"], room_area


def test_generation_is_deterministic_from_the_seed(houses, tmp_path):
    first = houses["plain"][0]
    again = generate_house(SPLITS["val_plain"][0], tmp_path / "again", STYLES["plain"])
    assert np.array_equal(_vertices(first), _vertices(again))
    names = sorted(p.name for p in (first / "textures").iterdir())
    assert names == sorted(p.name for p in (again / "textures").iterdir())
    for name in names:
        assert np.array_equal(_texture(first, name[:-4]), _texture(again, name[:-4])), name
    for f in ("floor_trav_0.png",):
        assert np.array_equal(np.asarray(Image.open(first / f)), np.asarray(Image.open(again / f)))
    assert _meta(first) == _meta(again)
    other = generate_house(SPLITS["val_plain"][1], tmp_path / "other", STYLES["plain"])
    assert _vertices(other).shape != _vertices(first).shape or not np.array_equal(_vertices(other), _vertices(first))


def test_the_held_out_split_is_generated_in_its_style(houses, tmp_path, monkeypatch):
    assert split_config("val_plain") == STYLES["plain"] and split_config("val") == HouseConfig()
    assert not set(SPLITS["val_plain"]) & (set(SPLITS["train"]) | set(SPLITS["val"]))
    monkeypatch.setitem(generator.SPLITS, "val_plain", SPLITS["val_plain"][:1])
    (folder,) = generate_split("val_plain", tmp_path, progress=False)
    assert _meta(folder)["config"]["style"] == "plain"
    assert house_problem(folder, SPLITS["val_plain"][0], STYLES["plain"]) is None
    assert "config differs" in house_problem(folder, SPLITS["val_plain"][0], HouseConfig())


def test_gibson_houses_record_the_config_they_always_did(houses):
    """Fields added for styles stay out of a gibson house's record, so houses made before are still intact."""
    assert not set(config_dict(HouseConfig())) & set(ADDED_FIELDS)
    assert set(ADDED_FIELDS) - {"layout"} <= set(config_dict(STYLES["plain"]))  # plain keeps the default layout mix
    assert config_dict(HouseConfig(layout="l_hall"))["layout"] == "l_hall"
    for folder in houses["gibson"]:
        assert set(_meta(folder)["config"]) == set(config_dict(HouseConfig()))
