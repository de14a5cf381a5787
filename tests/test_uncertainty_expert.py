"""The uncertainty-seeking expert: it heads for the most uncertain drivable view of the panorama, skips views
facing a wall, switches to the geodesic expert when the goal is in view, and finishes the CI episodes through the
agent loop with its own memory."""

from __future__ import annotations

import numpy as np
import pytest

from nue.policy.uncertainty_expert import UncertaintyExpert, UncertaintyExpertConfig
from nue.sim.task import get_task

from .conftest import FIXTURES, nue_here


def _panorama(hot: int, k: int = 4) -> np.ndarray:
    p = np.full((k, 6, 8), 0.1)
    p[hot] = 0.9
    return p


def test_heads_for_the_most_uncertain_drivable_view(box_nav):
    task = get_task("paper")
    far_goal = (2.5, 2.5)
    expert = UncertaintyExpert(box_nav, task)
    expert.reset(far_goal)
    pose, depth = np.array([0.5, -1.0, 0.0]), np.zeros((task.camera.height, task.camera.width))  # sees nothing
    assert expert.act(pose, depth, _panorama(1)) == task.action_id("TURN_LEFT")  # view 1 = +90 deg: open floor north
    assert expert.target[1] > -1.0 + 1.5 and abs(expert.target[0] - 0.5) < 1e-6
    expert.reset(far_goal)
    assert expert.act(pose, depth, _panorama(0)) == task.action_id("MOVE_FORWARD")
    # facing the inner wall (x = -1) from 0.2 m: the most uncertain view is the wall's, so the next one is chosen
    expert.reset(far_goal)
    near_wall = np.array([-0.7, -1.0, np.pi])
    scores = _panorama(0)
    scores[3] = 0.5  # view 3 = -90 deg (north when facing west)
    expert.act(near_wall, depth, scores)
    assert expert.target[1] > -1.0 + 1.0 and expert.stats["targets"] == 1
    assert expert.heading_scores(scores).shape == (4,)


def test_switches_when_the_goal_is_in_view(box_scene):
    from nue.sim.env import make_env

    env = make_env(box_scene, "paper")
    expert = UncertaintyExpert(env.navgrid, env.task, floor_z=env.floor_z)
    pose = np.array([1.5, -1.0, 0.0])  # facing +x, goal 1 m ahead on open floor
    _, depth = env.renderer.render(pose, env.floor_z)
    expert.reset((2.5, -1.0))
    expert.act(pose, depth, _panorama(2))
    assert expert.mode == "geodesic" and expert.stats["switch"] == "goal_in_view"
    budget = UncertaintyExpert(env.navgrid, env.task, UncertaintyExpertConfig(max_explore_steps=0))
    budget.reset((2.5, 2.5))
    budget.act(np.array([-2.0, -2.0, 0.0]), np.zeros_like(depth), _panorama(0))
    assert budget.stats["switch"] == "budget"


@pytest.mark.timeout(300)
def test_expert_uncertainty_finishes_the_ci_episodes(tmp_path):
    from nue.evaluate.diagnose import read_records
    from nue.sim.episode_gen import EpisodeGenConfig, generate_episodes
    from nue.sim.episodes import save_episodes
    from nue.scene.scene import Scene

    scene = Scene.load(FIXTURES / "box_room")
    eps = generate_episodes(scene, "paper", EpisodeGenConfig(per_bin=1), seed=4)[:2]
    save_episodes(tmp_path / "box_room.json", eps, "paper")
    out = tmp_path / "r.jsonl"
    res = nue_here("eval", "-c", "expert-uncertainty", "--out", out, "--episodes-dir", tmp_path,
                   "--scenes-root", FIXTURES, "--max-steps", 300)
    assert res.returncode == 0, res.stderr
    recs = read_records(out)
    assert len(recs) == 2 and all(r.success for r in recs) and {r.method for r in recs} == {"expert-uncertainty"}
