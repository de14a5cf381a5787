"""Episodes from other tools: starts / goals next to walls are snapped, bad episodes are named together, --skip-invalid.

Box room (tests/fixtures/box_room): the east wall's face is at x = 3.0. A robot centre (radius 0.18 m)
may stand at x = 2.81 (0.19 m from it), but the 5 cm planning cell [2.80, 2.85) also holds pixels
within 0.18 m of the wall, so it is blocked; the next cell west, [2.75, 2.80), is free: centre 2.775.
"""

from __future__ import annotations

import dataclasses
import json
import math

import pytest

from nue.errors import EpisodeError, InvalidEpisodesError
from nue.policy.agent import ExpertAgent
from nue.rollout import run_episode
from nue.sim.env import ImageNavEnv
from nue.sim.episodes import Episode, Snap, read_episodes, validate_episode

from .conftest import BOX_ROOM, nue_here
from .test_cli import assert_clean_error

NEAR_WALL = (2.81, 0.025)  # 0.19 m from the east wall face
IN_WALL = (3.6, 0.025)  # 0.6 m beyond the east wall face (inside the wall / outside the room)


def _episode(eid, start, goal):
    return Episode.from_poses(eid, "box_room", (*start, 0.0), (*goal, 0.0), euclidean_distance=math.dist(start, goal),
                              geodesic_distance=math.dist(start, goal))


def _authors_file(path, pairs):
    items = [{"startXYZ": [*s, 0.0], "startQuat": [0, 0, 0, 1], "endXYZ": [*g, 0.0], "endQuat": [0, 0, 0, 1]}
             for s, g in pairs]
    path.write_text(json.dumps(items))
    return path


def test_snap_goal_next_to_a_wall_to_the_nearest_free_cell(box_nav):
    assert box_nav.is_free(NEAR_WALL)  # the disc fits ...
    assert box_nav.geodesic_distance((0.0, 0.025), NEAR_WALL) == math.inf  # ... but its planning cell is blocked
    xy, d = box_nav.snap(NEAR_WALL, on_cell=True)
    assert tuple(xy) == pytest.approx((2.775, 0.025)) and d == pytest.approx(0.035)
    assert box_nav.snap(NEAR_WALL)[1] == 0.0  # as a start it needs no snapping (the robot may stand there)
    xy, d = box_nav.snap((2.9, -1.025))  # a start 0.10 m from the wall: inside the erosion margin
    assert tuple(xy) == pytest.approx((2.775, -1.025)) and d == pytest.approx(0.125)
    # on free cells nothing moves (our own episodes are unchanged, bit for bit)
    assert box_nav.snap((1.5, 1.0), on_cell=True) == (pytest.approx((1.5, 1.0)), 0.0)
    xy, d = box_nav.snap(IN_WALL, on_cell=True)
    assert xy is None and d == pytest.approx(math.hypot(3.6 - 2.775, 0.0), abs=0.03)


def test_snapped_goal_expert_succeeds_and_the_record_says_so(box_scene, box_nav, box_renderer):
    ep = _episode("near_wall", (0.0, 0.025), NEAR_WALL)
    assert validate_episode(ep, box_nav) == Snap(start=0.0, goal=pytest.approx(0.035))
    env = ImageNavEnv(box_scene, "paper", [ep], navgrid=box_nav, renderer=box_renderer)
    rec = run_episode(env, ExpertAgent(), episode_index=0)
    assert tuple(env.goal_xy) == NEAR_WALL and tuple(env.nav_goal_xy) == pytest.approx((2.775, 0.025))
    assert rec.success and rec.final_euclidean <= 0.8  # success measured to the goal as given
    assert rec.geodesic_start == pytest.approx(2.775, abs=0.01)  # to the snapped goal
    assert rec.extra["goal_snap"] == pytest.approx(0.035) and "start_snap" not in rec.extra
    assert ep.goal_position[:2] == NEAR_WALL  # the episode keeps its position


def test_snapped_start_places_the_robot_on_the_free_cell(box_scene, box_nav, box_renderer):
    env = ImageNavEnv(box_scene, "paper", navgrid=box_nav, renderer=box_renderer)
    obs, _ = env.reset(options={"episode": _episode("s", (2.9, -1.025), (0.5, 1.0))})
    assert tuple(obs["pose"][:2]) == pytest.approx((2.775, -1.025)) and env.snap == {"start_snap": 0.125}


def test_beyond_the_tolerance_and_inside_walls_stay_errors(box_nav):
    with pytest.raises(EpisodeError, match=r"episode g: goal \[3.6, 0.025\] is unreachable: inside an obstacle or wall \(0.8"):
        validate_episode(_episode("g", (0.0, 0.0), IN_WALL), box_nav)
    with pytest.raises(EpisodeError, match=r"episode s: start \[-1.0, 0.0\] is inside an obstacle or wall"):
        validate_episode(_episode("s", (-1.0, 0.0), (2.0, 2.0)), box_nav)


def test_two_bad_episodes_are_named_together(tmp_path, box_scene, box_nav):
    p = _authors_file(tmp_path / "eps.json", [((0.0, 0.025), NEAR_WALL), ((0.0, 0.0), IN_WALL), ((-1.0, 0.0), (2.0, 2.0))])
    with pytest.raises(InvalidEpisodesError) as err:
        read_episodes(p, box_scene, navgrid=box_nav)
    msg = str(err.value)
    assert msg.startswith(f"{p}: 2 invalid episodes: episode 1: goal [3.6, 0.025] is unreachable") and "\n" not in msg
    assert "; episode 2: start [-1.0, 0.0] is inside an obstacle or wall" in msg
    assert [eid for eid, _ in err.value.invalid] == ["1", "2"]
    got = read_episodes(p, box_scene, navgrid=box_nav, skip_invalid=True)
    assert [e.episode_id for e in got.episodes] == ["0"] and [e.episode_id for e in got.skipped] == ["1", "2"]
    assert got.snapped["0"].goal == pytest.approx(0.035)


def test_cli_goal_inside_a_wall_is_a_one_line_error(tmp_path):
    p = _authors_file(tmp_path / "eps.json", [((0.0, 0.025), IN_WALL)])
    assert_clean_error(nue_here("expert", "--scene", BOX_ROOM, "--episodes", p), "eps.json", "episode 0", "inside an obstacle")


def test_cli_skip_invalid_runs_the_rest_and_lists_the_skipped(tmp_path):
    p = _authors_file(tmp_path / "eps.json", [((0.0, 0.025), NEAR_WALL), ((0.0, 0.0), IN_WALL), ((-1.0, 0.0), (2.0, 2.0))])
    assert_clean_error(nue_here("expert", "--scene", BOX_ROOM, "--episodes", p), "2 invalid episodes", "episode 1", "episode 2")
    res = nue_here("expert", "--scene", BOX_ROOM, "--episodes", p, "--skip-invalid")
    assert res.returncode == 0, res.stderr
    assert "skipped 2 invalid episode(s)" in res.stdout
    assert f"{p}: episode 1: goal" in res.stdout and f"{p}: episode 2: start" in res.stdout
    assert "snapped to navigable cells: 0 (start 0.000 m, goal 0.035 m)" in res.stdout
    assert "| total | 1 | 100.0 |" in res.stdout


def test_eval_plan_skips_invalid_episodes_and_lists_them(tmp_path):
    from nue.evaluate.runner import EvalConfig, plan_eval

    from .conftest import FIXTURES

    (tmp_path / "eps").mkdir()
    p = _authors_file(tmp_path / "eps" / "box_room.json", [((0.0, 0.025), NEAR_WALL), ((0.0, 0.0), IN_WALL)])
    cfg = EvalConfig(episodes_dir=str(tmp_path / "eps"), scenes_root=str(FIXTURES), coverage=False)
    with pytest.raises(InvalidEpisodesError, match=r"box_room.json: episode 1: goal \[3.6, 0.025\] is unreachable"):
        plan_eval(["expert"], cfg)
    skipped: list = []
    jobs = plan_eval(["expert"], dataclasses.replace(cfg, skip_invalid=True), skipped)
    assert [j.key for j in jobs] == ["expert/box_room/0"]
    assert [(s.file, s.episode_id) for s in skipped] == [(str(p), "1")]
