"""Style distributions (issue 43): the sampler is deterministic per seed and covers its documented ranges,
the held-out families lie outside the training distribution's support (on the generated splits' configs),
the new layouts have the hallway / open-plan shapes they claim, a house of each new split builds and the
expert solves its episodes, and ``nue scenes stats`` separates the families."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from nue.evaluate.metrics import aggregate
from nue.policy.agent import ExpertAgent
from nue.rollout import run_episode
from nue.scene.generator import SPLITS, generate_house, house_config
from nue.scene.house_config import STYLES, HouseConfig
from nue.scene.house_plans import LAYOUTS
from nue.scene.house_styles import STYLE_DISTRIBUTIONS, outside_support, sample_style
from nue.scene.navgrid import NavGrid
from nue.scene.scene import Scene
from nue.scene.style_stats import house_stats, nearest_look, srgb_to_lab
from nue.sim.env import ImageNavEnv
from nue.sim.episode_gen import EpisodeGenConfig, generate_episodes
from nue.sim.renderer import Renderer

DIVERSE, PALE = STYLE_DISTRIBUTIONS["diverse"], STYLE_DISTRIBUTIONS["pale"]
DRAWS = range(100_000, 100_400)  # seeds of no split: many draws of each distribution


def _meta(folder: Path) -> dict:
    return json.loads((folder / "house.json").read_text())


def test_sampling_is_deterministic_per_seed_and_varies_across_seeds():
    assert sample_style(DIVERSE, 4000) == sample_style(DIVERSE, 4000) == house_config("train_diverse", 0)
    assert len({sample_style(DIVERSE, s) for s in range(4000, 4010)}) == 10
    assert house_config("val_pale", 3) == sample_style(PALE, SPLITS["val_pale"][3])
    assert house_config("val", 0) == HouseConfig() and house_config("val_plain", 0) == STYLES["plain"]


def test_training_draws_stay_in_and_cover_the_documented_ranges():
    cfgs = [sample_style(DIVERSE, s) for s in DRAWS]
    assert all(outside_support(DIVERSE, c) == [] for c in cfgs)
    for c in cfgs:
        c.validate()
    assert {c.layout for c in cfgs} == set(LAYOUTS)
    assert {c.appearance.surfaces for c in cfgs} == {"textured", "plain"}
    assert {c.appearance.wall_colours for c in cfgs} == {0, 1, 2, 3}
    assert {c.pictures_per_room for c in cfgs} == set(DIVERSE.pictures_per_room)
    near_white = [c for c in cfgs if c.appearance.wall_saturation[1] <= 0.08]
    assert near_white and all(c.appearance.surfaces == "textured" for c in near_white)
    low_contrast = [c for c in cfgs if c.appearance.floor_value[1] == c.appearance.wall_value[0]]
    assert 0.1 < len(low_contrast) / len(cfgs) < 0.3  # low_contrast_prob 0.2
    heights = [c.wall_height for c in cfgs]
    assert 2.4 <= min(heights) < 2.45 and 2.7 < max(heights) <= 2.75
    widths = [c.furniture_scale[0] for c in cfgs]
    assert 0.85 <= min(widths) < 0.9 and 1.1 < max(widths) <= 1.15
    flat_sat = [c.appearance.wall_saturation[0] for c in cfgs if c.appearance.surfaces == "plain"]
    assert min(flat_sat) >= 0.3


def test_held_out_families_never_fall_inside_the_training_support():
    """On the configs of the generated splits and on 400 more draws of the pale family."""
    pale = [house_config("val_pale", i) for i in range(len(SPLITS["val_pale"]))] + [sample_style(PALE, s) for s in DRAWS]
    for c in pale:
        out = outside_support(DIVERSE, c)
        assert {"plain_wall_colour", "wall_height", "door_height", "furniture_scale[0]", "furniture_scale[2]"} <= set(out)
        assert c.appearance.wall_colours == 1 and c.layout in ("open_plan", "l_hall")
    assert {"plain_wall_colour", "wall_height", "door_height", "furniture_scale[0]",
            "furniture_scale[2]"} <= set(outside_support(DIVERSE, STYLES["plain"]))
    training = [house_config("train_diverse", i) for i in range(len(SPLITS["train_diverse"]))]
    assert all(outside_support(DIVERSE, c) == [] for c in training)
    assert outside_support(DIVERSE, HouseConfig()) == []  # the old training style lies inside the new one
    assert not set(SPLITS["train_diverse"]) & set(SPLITS["val_pale"])
    assert not (set(SPLITS["train_diverse"]) | set(SPLITS["val_pale"])) & (
        set(SPLITS["train"]) | set(SPLITS["val"]) | set(SPLITS["val_plain"]))


@pytest.mark.parametrize("layout", ["l_hall", "t_hall", "open_plan"])
def test_new_layouts_have_their_shapes(layout, tmp_path):
    """Two hallway rectangles joined wall to wall (L, T); open zones joined by openings >= 1.5 m."""
    for seed in (11, 12):
        meta = _meta(generate_house(seed, tmp_path / f"{layout}{seed}", HouseConfig(layout=layout, rooms=(3, 11),
                                                                                    texture_size=64)))
        assert meta["layout"] == layout
        rooms = meta["rooms"]
        if layout == "open_plan":
            zones = [i for i, r in enumerate(rooms) if r["kind"] in ("living room", "kitchen", "dining room")]
            opens = [d for d in meta["doors"] if set(d["rooms"]) <= set(zones)]
            assert len(opens) == len(zones) - 1 >= 1 and all(d["width"] >= 1.5 for d in opens)
            continue
        halls = [i for i, r in enumerate(rooms) if r["kind"] == "hallway"]
        assert len(halls) == 2
        (joint,) = [d for d in meta["doors"] if sorted(d["rooms"]) == halls]
        a, b = (rooms[i]["rect"] for i in halls)
        axis = 0 if joint["axis"] == "x" else 1  # the opening spans the narrower hallway piece's whole width
        narrow = min(b[2 + 1 - axis] - b[1 - axis], a[2 + 1 - axis] - a[1 - axis])
        assert joint["width"] == pytest.approx(narrow, abs=0.011)


@pytest.fixture(scope="module")
def new_houses(tmp_path_factory):
    root = tmp_path_factory.mktemp("styled")
    picks = (("train_diverse", 1), ("train_diverse", 5), ("val_pale", 0))
    return [generate_house(SPLITS[s][i], root / f"{s}_{i:02d}", house_config(s, i).replace(texture_size=64))
            for s, i in picks]


def test_a_house_of_each_new_split_builds_and_the_expert_solves_it(new_houses):
    assert [_meta(f)["layout"] for f in new_houses] == ["l_hall", "t_hall", "open_plan"]
    records = []
    for folder in new_houses:
        scene = Scene.load(folder)
        nav, renderer = NavGrid.from_scene(scene), Renderer(scene)
        eps = generate_episodes(scene, "paper", EpisodeGenConfig(per_bin=2), seed=2, navgrid=nav, renderer=renderer)
        env = ImageNavEnv(scene, "paper", eps, navgrid=nav, renderer=renderer)
        records += [run_episode(env, ExpertAgent(), episode_index=i) for i in range(len(eps))]
    total = aggregate(records)["total"]
    assert total.n == 18 and total.sr >= 0.99, [r for r in records if not r.success]


def test_stats_tell_the_pale_family_from_the_training_houses(new_houses):
    assert np.allclose(srgb_to_lab(np.array([255, 255, 255])), [100, 0, 0], atol=0.05)
    assert np.allclose(srgb_to_lab(np.array([0, 0, 0])), [0, 0, 0], atol=1e-6)
    train, pale = [house_stats(f) for f in new_houses[:2]], house_stats(new_houses[2])
    assert pale["surfaces"] == "plain" and pale["wall_colours"] == 1 and pale["flat_pale"]
    assert pale["wall_chroma"] < 7 and pale["wall_L"] > 85 and pale["outside_training"]
    assert all(t["outside_training"] == [] for t in train)
    assert pale["wall_chroma"] < min(t["wall_chroma"] for t in train)
    textured = [t for t in train if t["surfaces"] == "textured"]
    assert textured and pale["pattern_std"] < 0.5 * min(t["pattern_std"] for t in textured)


def test_look_distance_is_scaled_by_the_reference_spread_and_skips_the_house_itself():
    a, b = ({"house": n, "wall_L": v, "wall_chroma": v, "pattern_std": v} for n, v in (("a", 0.0), ("b", 2.0)))
    c = {"house": "c", "wall_L": 1.0, "wall_chroma": 1.0, "pattern_std": 1.0}
    assert nearest_look([a, b], [a, b]) == [3.46, 3.46]  # sqrt(12): each feature's spread (std) is 1
    assert nearest_look([c], [a, b]) == [1.73]  # sqrt(3)


def test_scenes_stats_refuses_an_unknown_split(tmp_path, capsys):
    from nue.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["scenes", "stats", "--splits", "val,nope", "--scenes-root", str(tmp_path)])
    err = capsys.readouterr().err.strip()
    assert exc.value.code == 2 and err.startswith("error: --splits: must be one of") and "\n" not in err
    assert not any(tmp_path.iterdir())  # nothing generated
