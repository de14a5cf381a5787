"""ImageNavEnv: gymnasium contract, motion and collisions, success / truncation, cross-process determinism."""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import nue
from nue.sim import make_env
from nue.sim.env import ImageNavEnv
from nue.sim.episodes import Episode
from nue.sim.task import get_task

from .conftest import BOX_ROOM


def _episode(start, goal, **kw):
    return Episode.from_poses("t", "box_room", start, goal, euclidean_distance=math.dist(start[:2], goal[:2]),
                              geodesic_distance=0.0, difficulty="easy", **kw)


@pytest.fixture()
def env(box_scene, box_nav, box_renderer):
    return ImageNavEnv(box_scene, "paper", navgrid=box_nav, renderer=box_renderer)


def test_check_env(env):
    check_env(env, skip_render_check=True)


def test_gym_make_and_make_env():
    """``import nue`` registers ``nue/ImageNav-v0``; gym.make and make_env give the same episode as ImageNavEnv."""
    made = gym.make(nue.ENV_ID, scene=str(BOX_ROOM), task="paper")
    assert isinstance(made.unwrapped, ImageNavEnv) and made.unwrapped.task.name == "paper"
    plain = make_env(BOX_ROOM, "paper", max_steps=7)
    assert plain.task.max_steps == 7 and plain.task.success_radius == get_task("paper").success_radius
    a, _ = made.reset(seed=3)
    b, _ = plain.reset(seed=3)
    for key in ("rgb", "depth", "pose", "goal"):
        np.testing.assert_array_equal(a[key], b[key])
    check_env(made.unwrapped, skip_render_check=True)


def test_observation_contents(env):
    obs, info = env.reset(options={"episode": _episode((1.0, -0.5, -math.pi / 2), (2.0, 2.0, 0.0))})
    assert obs["rgb"].shape == (180, 240, 3) and obs["rgb"].dtype == np.uint8
    assert obs["depth"].shape == (180, 240, 1) and obs["depth"].dtype == np.float32
    assert obs["goal"].shape == (180, 240, 3) and obs["pose"].dtype == np.float32
    assert obs["depth"][90, 120, 0] == pytest.approx(1.2, abs=1e-4)  # the obstacle ahead
    np.testing.assert_allclose(obs["pose"], (1.0, -0.5, -math.pi / 2), atol=1e-6)


def test_actions_move_and_turn(env):
    env.reset(options={"episode": _episode((0.0, 0.0, 0.0), (2.5, 2.5, 0.0))})
    env.step(0)  # forward 0.25 m along +x
    np.testing.assert_allclose(env.pose, (0.25, 0.0, 0.0), atol=1e-9)
    env.step(1)  # left = counter-clockwise
    assert env.pose[2] == pytest.approx(math.radians(15))
    env.step(2)
    env.step(2)
    assert env.pose[2] == pytest.approx(-math.radians(15))
    assert env.goal_angle() == pytest.approx(math.atan2(2.5, 2.25) + math.radians(15))


def test_walls_stop_the_disc_and_count_collisions(env):
    env.reset(options={"episode": _episode((2.0, 0.0, 0.0), (-2.0, 2.5, 0.0))})
    for _ in range(8):  # drive into the east wall at x = 3
        _, _, _, _, info = env.step(0)
        assert env.navgrid.is_free(env.pose[:2])
    assert env.pose[0] < 3.0 - 0.18 and env.pose[0] > 2.7
    assert info["collisions"] >= 4 and info["collided"]
    assert env.path_length == pytest.approx(env.pose[0] - 2.0, abs=1e-9)


def test_slide_along_a_wall(env):
    env.reset(options={"episode": _episode((2.7, 0.0, math.radians(30)), (-2.0, 2.5, 0.0))})
    y0 = env.pose[1]
    for _ in range(4):
        env.step(0)
    assert env.pose[1] > y0 + 0.3 and env.collisions >= 1  # keeps gliding along +y


def test_stop_mode_does_not_slide(box_scene, box_nav, box_renderer):
    task = dataclasses.replace(get_task("paper"), collision="stop")
    env = ImageNavEnv(box_scene, task, navgrid=box_nav, renderer=box_renderer)
    env.reset(options={"episode": _episode((2.7, 0.0, math.radians(30)), (-2.0, 2.5, 0.0))})
    for _ in range(4):
        env.step(0)
    assert env.pose[1] < 0.3


def test_success_terminates_and_step_limit_truncates(box_scene, box_nav, box_renderer):
    env = ImageNavEnv(box_scene, "paper", navgrid=box_nav, renderer=box_renderer)
    env.reset(options={"episode": _episode((0.0, 0.0, 0.0), (1.25, 0.0, 0.0))})
    _, r1, term, trunc, info = env.step(0)  # 1.0 m away
    assert not term and not info["success"]
    _, r2, term, trunc, info = env.step(0)  # 0.75 m: inside the radius
    assert term and not trunc and info["success"] and r2 > 2.5
    assert env.episode_record().success
    short = dataclasses.replace(get_task("paper"), max_steps=3)
    env = ImageNavEnv(box_scene, short, navgrid=box_nav, renderer=box_renderer)
    env.reset(options={"episode": _episode((0.0, 0.0, 0.0), (2.5, 2.5, 0.0))})
    results = [env.step(1)[2:4] for _ in range(3)]
    assert results == [(False, False), (False, False), (False, True)]
    with pytest.raises(RuntimeError):
        env.step(1)


def test_habitat_needs_stop(box_scene, box_nav, box_renderer):
    env = ImageNavEnv(box_scene, "habitat", navgrid=box_nav, renderer=box_renderer)
    assert env.action_space.n == 4
    env.reset(options={"episode": _episode((0.0, 0.0, 0.0), (1.2, 0.0, 0.0))})
    _, _, term, _, info = env.step(1)  # forward: inside 1.0 m, but no STOP yet
    assert not term
    _, _, term, _, info = env.step(0)  # STOP
    assert term and info["success"]
    env.reset(options={"episode": _episode((0.0, 0.0, 0.0), (2.5, 2.5, 0.0))})
    _, _, term, _, info = env.step(0)  # STOP far away: failure
    assert term and not info["success"]


_SUBPROCESS = """
import sys, numpy as np
from nue.sim.env import ImageNavEnv
env = ImageNavEnv(sys.argv[1], "paper")
obs, _ = env.reset(seed=7)
frames = [obs]
for a in [0, 1, 0, 2, 0]:
    obs, *_ = env.step(a)
    frames.append(obs)
np.savez(sys.argv[2], **{f"{k}_{i}": v for i, f in enumerate(frames) for k, v in f.items()})
"""


def test_same_seed_identical_observations_across_processes(tmp_path, box_scene):
    paths = [tmp_path / f"run{i}.npz" for i in range(2)]
    for p in paths:
        subprocess.run([sys.executable, "-c", _SUBPROCESS, str(box_scene.path), str(p)], check=True)
    a, b = np.load(paths[0]), np.load(paths[1])
    assert sorted(a.files) == sorted(b.files) and len(a.files) == 24
    for k in a.files:
        assert np.array_equal(a[k], b[k]), k
