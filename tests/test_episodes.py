"""Episode generation (bins, rejection rules, seeding), both file formats, and bad episodes."""

from __future__ import annotations

import dataclasses
import json
import math
import subprocess
import sys

import numpy as np
import pytest

from nue.errors import EpisodeError, EpisodeGenerationError
from nue.sim.episode_gen import EpisodeGenConfig, generate_episodes, goal_region_is_open
from nue.sim.episodes import Episode, load_episodes, save_episodes, validate_episode
from nue.sim.task import DifficultyBins, get_task


@pytest.fixture(scope="module")
def box_episodes(box_scene, box_nav, box_renderer):
    return generate_episodes(box_scene, "paper", EpisodeGenConfig(per_bin=4), seed=3, navgrid=box_nav, renderer=box_renderer)


def test_bins_distances_and_labels(box_episodes, box_nav, box_renderer):
    task = get_task("paper")
    assert [e.difficulty for e in box_episodes] == ["easy"] * 4 + ["medium"] * 4 + ["hard"] * 4
    for e in box_episodes:
        lo, hi = task.bins.range_of(e.difficulty)
        euc = math.dist(e.start_position[:2], e.goal_position[:2])
        assert e.euclidean_distance == pytest.approx(euc) and lo <= euc <= hi
        geo = box_nav.geodesic_distance(e.start_position[:2], e.goal_position[:2])
        assert e.geodesic_distance == pytest.approx(geo) and geo >= euc - 0.1
        assert e.path_type == ("straight" if geo / euc < 1.2 else "curved")
        validate_episode(e, box_nav)
        _, depth = box_renderer.render(e.goal_pose)
        assert np.median(depth) >= 1.0
        assert e.scene_hash == "2605e2c96d9050bd" or len(e.scene_hash) == 16


def test_goal_region_rule_rejects_goals_behind_a_wall(box_nav):
    # 0.35 m east of the interior wall (x = -1): cells west of it, within 0.8 m, are ~9 m away by path.
    goal = np.array([-0.6, -1.0])
    assert not goal_region_is_open(box_nav, box_nav.distance_field(goal), goal, 0.8, 0.5)
    goal = np.array([1.5, 1.0])  # open floor
    assert goal_region_is_open(box_nav, box_nav.distance_field(goal), goal, 0.8, 0.5)


def test_generator_gives_up_naming_the_house_and_bin(box_scene, box_nav, box_renderer):
    task = dataclasses.replace(get_task("paper"), bins=DifficultyBins(edges=(("huge", 20.0, 30.0),)))
    with pytest.raises(EpisodeGenerationError, match=r"box_room: could not fill difficulty bin 'huge'"):
        generate_episodes(box_scene, task, EpisodeGenConfig(per_bin=1, tries_per_episode=20), navgrid=box_nav, renderer=box_renderer)


_SUBPROCESS = """
import json, sys
from nue.scene.scene import Scene
from nue.sim.episode_gen import generate_episodes, EpisodeGenConfig
eps = generate_episodes(Scene.load(sys.argv[1]), "paper", EpisodeGenConfig(per_bin=2), seed=11)
print(json.dumps([[e.start_position, e.start_rotation, e.goal_position, e.goal_rotation] for e in eps]))
"""


def test_same_seed_same_episodes_across_processes(box_scene):
    outs = [
        subprocess.run([sys.executable, "-c", _SUBPROCESS, str(box_scene.path)], capture_output=True, text=True, check=True).stdout
        for _ in range(2)
    ]
    assert outs[0] == outs[1] and len(json.loads(outs[0])) == 6
    other = generate_episodes(box_scene, "paper", EpisodeGenConfig(per_bin=2), seed=12)
    assert json.loads(outs[0])[0][0] != list(other[0].start_position)


def test_round_trip_in_both_formats(tmp_path, box_episodes, box_scene):
    p = save_episodes(tmp_path / "eps.json", box_episodes, "paper")
    assert load_episodes(p, box_scene) == box_episodes
    a = save_episodes(tmp_path / "authors.json", box_episodes, fmt="authors")
    items = json.loads(a.read_text())
    assert set(items[0]) == {"startXYZ", "startQuat", "endXYZ", "endQuat", "dist", "pathDist"}
    back = load_episodes(a, box_scene)
    for e, b in zip(box_episodes, back):
        assert b.start_position == e.start_position and b.goal_rotation == e.goal_rotation
        assert b.difficulty == e.difficulty and b.path_type == e.path_type and b.scene == "box_room"
        np.testing.assert_allclose(b.start_pose, e.start_pose)


def test_authors_format_with_base_height(tmp_path, box_scene):
    item = {"startXYZ": [0.0, 0.0, 0.39], "startQuat": [0, 0, 0.7071068, 0.7071068], "endXYZ": [2.0, 1.0, 0.39],
            "endQuat": [0, 0, 0, 1], "dist": math.hypot(2, 1), "pathDist": 2.3}
    p = tmp_path / "a.json"
    p.write_text(json.dumps([item]))
    (e,) = load_episodes(p, box_scene)
    assert e.start_pose[2] == pytest.approx(math.pi / 2, abs=1e-6)
    assert e.difficulty == "easy" and e.path_type == "straight"
    assert box_scene.floor_of(e.start_position[2]) == 0


def test_scene_hash_mismatch_is_refused(tmp_path, box_episodes, box_scene):
    eps = [dataclasses.replace(e, scene_hash="0123456789abcdef") for e in box_episodes]
    p = save_episodes(tmp_path / "eps.json", eps)
    with pytest.raises(EpisodeError, match=r"eps.json: episode easy_000 was made for scene content 0123456789abcdef"):
        load_episodes(p, box_scene)


def test_nan_pose_is_refused(tmp_path, box_episodes):
    doc = json.loads(save_episodes(tmp_path / "eps.json", box_episodes).read_text())
    doc["episodes"][1]["goal_position"][0] = float("nan")
    (tmp_path / "eps.json").write_text(json.dumps(doc))
    with pytest.raises(EpisodeError, match=r"eps.json: episode easy_001: goal_position is not finite"):
        load_episodes(tmp_path / "eps.json")


def test_start_in_wall_and_unreachable_goal(box_nav):
    wall = Episode.from_poses("w", "box_room", (-1.0, 0.0, 0.0), (2.0, 2.0, 0.0), euclidean_distance=1, geodesic_distance=1)
    with pytest.raises(EpisodeError, match=r"episode w: start .* inside an obstacle"):
        validate_episode(wall, box_nav)
    unreachable = Episode.from_poses("u", "box_room", (0.0, 0.0, 0.0), (1.0, -2.0, 0.0), euclidean_distance=1, geodesic_distance=1)
    with pytest.raises(EpisodeError, match=r"episode u: goal .* unreachable"):
        validate_episode(unreachable, box_nav)


def test_malformed_files(tmp_path):
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(EpisodeError, match=r"bad.json: not valid JSON"):
        load_episodes(tmp_path / "bad.json")
    (tmp_path / "odd.json").write_text('{"hello": 1}')
    with pytest.raises(EpisodeError, match=r"odd.json: unknown episode file format"):
        load_episodes(tmp_path / "odd.json")
    with pytest.raises(EpisodeError, match=r"missing.json: episode file not found"):
        load_episodes(tmp_path / "missing.json")
