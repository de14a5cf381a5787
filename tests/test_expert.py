"""Geodesic expert: succeeds on generated episodes, never thrashes, stops in the habitat preset."""

from __future__ import annotations

import pytest

from nue.policy.agent import ExpertAgent
from nue.rollout import run_episode
from nue.sim.env import ImageNavEnv
from nue.sim.episode_gen import EpisodeGenConfig, generate_episodes


def _thrashes(actions, left, right):
    return any((a, b, c) in ((left, right, left), (right, left, right)) for a, b, c in zip(actions, actions[1:], actions[2:]))


@pytest.mark.parametrize("task", ["paper", "habitat", "official"])
def test_expert_succeeds_in_the_box_room(task, box_scene, box_nav, box_renderer):
    eps = generate_episodes(box_scene, task, EpisodeGenConfig(per_bin=3), seed=5, navgrid=box_nav, renderer=box_renderer)
    env = ImageNavEnv(box_scene, task, eps, navgrid=box_nav, renderer=box_renderer)
    agent = ExpertAgent()
    for i in range(len(eps)):
        actions = []
        rec = run_episode(env, agent, episode_index=i, on_step=lambda s: actions.append(s.action))
        assert rec.success, (task, eps[i])
        assert rec.steps <= 3 * rec.geodesic_start / 0.25 + 30
        assert not _thrashes(actions, env.task.action_id("TURN_LEFT"), env.task.action_id("TURN_RIGHT"))
        if task == "habitat":
            assert actions[-1] == env.task.action_id("STOP")
