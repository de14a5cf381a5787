"""habitat-lab's episode format: y-up <-> z-up by hand-computed values, round trips both ways, many-scene files."""

from __future__ import annotations

import gzip
import json
import math

import numpy as np
import pytest

from nue.sim import habitat_format as H
from nue.sim.episodes import Episode, load_episodes, save_episodes

S = math.sqrt(0.5)


def test_frame_change_by_hand():
    assert H.position_from_habitat([1.0, 0.2, -2.0]) == (1.0, 2.0, 0.2)  # (x_h, -z_h, y_h)
    assert H.position_to_habitat((1.0, 2.0, 0.2)) == [1.0, 0.2, -2.0]
    # identity: the agent looks along -z_h = our +y
    assert H.yaw_from_habitat_rotation([0, 0, 0, 1]) == pytest.approx(math.pi / 2)
    # +90 deg about +y_h: looks along -x_h = our -x
    assert abs(H.yaw_from_habitat_rotation([0, S, 0, S])) == pytest.approx(math.pi)
    # -90 deg about +y_h: looks along +x_h = our +x
    assert H.yaw_from_habitat_rotation([0, -S, 0, S]) == pytest.approx(0.0, abs=1e-12)
    assert H.habitat_rotation_from_yaw(0.0) == pytest.approx([0, -S, 0, S])
    for yaw in np.linspace(-3.1, 3.1, 13):
        assert H.yaw_from_habitat_rotation(H.habitat_rotation_from_yaw(yaw)) == pytest.approx(yaw, abs=1e-12)


def _habitat_file(path, scenes=("box_room",)):
    """Written as habitat-lab's PointNav generator writes them: goals without rotation, only a geodesic distance."""
    eps = []
    for k, scene in enumerate(scenes):
        eps += [
            {"episode_id": str(10 * k), "scene_id": f"data/scene_datasets/gibson/{scene}.glb",
             "start_position": [0.0, 0.0, 0.5], "start_rotation": [0, 0, 0, 1],
             "goals": [{"position": [2.0, 0.0, -1.0], "radius": 0.2}], "info": {"geodesic_distance": 2.55},
             "start_room": None, "shortest_paths": None},
            {"episode_id": str(10 * k + 1), "scene_id": f"data/scene_datasets/gibson/{scene}.glb",
             "start_position": [-2.0, 0.0, 2.0], "start_rotation": [0, S, 0, S],
             "goals": [{"position": [2.5, 0.0, -2.5], "radius": 0.2}], "info": {"geodesic_distance": 10.0},
             "start_room": None, "shortest_paths": None},
        ]
    path.write_bytes(gzip.compress(json.dumps({"episodes": eps}).encode()))
    return path, eps


def test_habitat_file_reads_into_our_frame_and_writes_back_unchanged(tmp_path, box_scene, box_nav):
    path, items = _habitat_file(tmp_path / "box_room.json.gz")
    eps = load_episodes(path, box_scene, "habitat", navgrid=box_nav)  # valid in the box room, in our frame
    a, b = eps
    assert a.episode_id == "0" and a.scene == "box_room"
    assert a.start_position == (0.0, -0.5, 0.0) and a.goal_position == (2.0, 1.0, 0.0)
    assert a.start_pose[2] == pytest.approx(math.pi / 2) and abs(b.start_pose[2]) == pytest.approx(math.pi)
    assert a.geodesic_distance == 2.55 and a.euclidean_distance == pytest.approx(math.hypot(2.0, 1.5))
    assert a.difficulty == "easy" and b.difficulty == "hard" and b.path_type == "curved"  # habitat's geodesic bins
    assert load_episodes(path, box_scene, "habitat")[0].goal_rotation == a.goal_rotation  # reproducible goal yaw
    out = save_episodes(tmp_path / "back.json.gz", eps, "habitat", fmt="habitat")
    back = json.loads(gzip.decompress(out.read_bytes()))["episodes"]
    for orig, new in zip(items, back):
        assert new["start_position"] == orig["start_position"]  # exactly, after two frame changes
        assert new["goals"][0]["position"] == orig["goals"][0]["position"]
        assert new["episode_id"] == orig["episode_id"] and new["scene_id"] == orig["scene_id"]
        assert new["info"]["geodesic_distance"] == orig["info"]["geodesic_distance"]
        q, r = np.array(new["start_rotation"]), np.array(orig["start_rotation"])
        assert min(np.abs(q - r).max(), np.abs(q + r).max()) < 1e-12  # same rotation (q ~ -q)


def test_our_episodes_round_trip_through_habitat(tmp_path, box_scene):
    eps = [Episode.from_poses("e1", "box_room", (0.5, -0.5, 0.0), (2.0, 1.0, 1.2), z=0.0, euclidean_distance=2.12,
                              geodesic_distance=2.2, difficulty="easy", path_type="straight", scene_hash=box_scene.content_hash),
           Episode.from_poses("e2", "box_room", (-2.0, -2.0, -2.5), (2.5, -2.5, 3.0), euclidean_distance=4.53,
                              geodesic_distance=10.1, difficulty="hard", path_type="curved")]
    path = save_episodes(tmp_path / "h.json", eps, fmt="habitat")  # plain JSON without .gz
    assert json.loads(path.read_text())["episodes"][0]["start_position"] == [0.5, 0.0, 0.5]
    back = load_episodes(path, box_scene, "paper")
    for e, b in zip(eps, back):
        assert (b.episode_id, b.scene, b.scene_hash) == (e.episode_id, e.scene, e.scene_hash)
        assert b.start_position == e.start_position and b.goal_position == e.goal_position
        np.testing.assert_allclose(b.start_pose, e.start_pose, atol=1e-12)
        np.testing.assert_allclose(b.goal_pose, e.goal_pose, atol=1e-12)  # the goal yaw travels in info
        assert (b.euclidean_distance, b.geodesic_distance) == (e.euclidean_distance, e.geodesic_distance)


def test_a_many_scene_file_gives_this_scenes_episodes(tmp_path, box_scene):
    path, _ = _habitat_file(tmp_path / "all.json.gz", scenes=("Adrian", "box_room"))
    assert [e.episode_id for e in load_episodes(path, box_scene, "habitat")] == ["10", "11"]
    assert {e.scene for e in load_episodes(path, task="habitat")} == {"Adrian", "box_room"}
