"""Exploring expert: seen-map geometry moved to nue.sim, success on the CI episodes, explore -> geodesic, determinism."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from nue.policy.agent import ExpertAgent
from nue.rollout import run_episode
from nue.sim.env import ImageNavEnv
from nue.sim.episode_gen import EpisodeGenConfig, generate_episodes

SIM = Path(__file__).parents[1] / "nue" / "sim"


def _run(env, agent, i):
    """(record, actions, per-step modes, stats) of episode i."""
    actions, modes = [], []

    def on_step(s):
        actions.append(s.action)
        modes.append(agent.expert.mode)

    rec = run_episode(env, agent, episode_index=i, on_step=on_step)
    return rec, actions, modes, dict(agent.expert.stats)


@pytest.fixture(scope="module")
def paper_runs(box_scene, box_nav, box_renderer):
    """The exploring expert on the paper-preset episodes of tests/test_expert.py."""
    eps = generate_episodes(box_scene, "paper", EpisodeGenConfig(per_bin=3), seed=5, navgrid=box_nav, renderer=box_renderer)
    env = ImageNavEnv(box_scene, "paper", eps, navgrid=box_nav, renderer=box_renderer)
    agent = ExpertAgent(kind="explore")
    return env, [_run(env, agent, i) for i in range(len(eps))]


def test_seen_geometry_lives_in_sim_and_is_reexported(box_nav, box_renderer):
    from nue.evaluate import coverage
    from nue.sim import seen

    for name in ("CoverageConfig", "GridLike", "cell_area", "seen_floor_cells"):
        assert getattr(coverage, name) is getattr(seen, name)
    upward = re.compile(r"^\s*(from|import)\s+nue\.(evaluate|nerf|policy|train)\b", re.M)
    assert not [p.name for p in SIM.glob("*.py") if upward.search(p.read_text())]  # imports point down
    cam = box_renderer.camera
    pose = np.array([-0.5, -2.0, 0.0])  # facing +x, the 0.6 m box (x 0.7..1.3, y -2.3..-1.7) ahead
    _, depth = box_renderer.render(pose, 0.0)
    floor = coverage.seen_floor_cells(depth, pose, cam, box_nav, 0.0)
    obstacle = seen.seen_obstacle_cells(depth, pose, cam, box_nav, 0.0)
    both = seen.seen_cells(depth, pose, cam, box_nav, 0.0)
    assert np.array_equal(both[0], floor) and np.array_equal(both[1], obstacle)
    cell = lambda x, y: tuple(box_nav.cell_of((x, y)))  # noqa: E731
    assert floor[cell(0.3, -2.0)] and not obstacle[cell(0.3, -2.0)]  # open floor in front of the box
    assert obstacle[cell(0.71, -2.0)] and not floor[cell(1.5, -2.0)]  # its face; the floor behind it is hidden


def test_explorer_succeeds_on_the_ci_episodes(paper_runs):
    env, runs = paper_runs
    for i, (rec, actions, modes, st) in enumerate(runs):
        assert rec.success, (i, st)
        assert rec.collisions <= 2, (i, rec.collisions)
        assert st["explore_steps"] <= 250


def test_goal_out_of_view_explores_frontiers_then_switches_for_good(paper_runs):
    _, runs = paper_runs
    out_of_view = [r for r in runs if not r[3]["goal_in_view_at_start"]]
    assert len(out_of_view) >= 3  # the inner wall hides most goals at the start
    for rec, actions, modes, st in out_of_view:
        assert st["targets_reached"] >= 1, st  # at least one frontier target completed while exploring
        k = modes.index("geodesic") if "geodesic" in modes else len(modes)
        assert k >= 1 and set(modes[:k]) == {"explore"} and set(modes[k:]) <= {"geodesic"}  # never back
        assert st["explore_steps"] == k
    for rec, actions, modes, st in runs:
        if st["goal_in_view_at_start"]:
            assert st["explore_steps"] == 0 and st["switch"] == "goal_in_view"


def test_explorer_is_deterministic(paper_runs):
    env, runs = paper_runs
    i = min((j for j, r in enumerate(runs) if r[3]["explore_steps"] > 0), key=lambda j: len(runs[j][1]))
    _, actions, _, _ = _run(env, ExpertAgent(kind="explore"), i)
    assert actions == runs[i][1]


def test_explorer_stops_in_the_habitat_preset(box_scene, box_nav, box_renderer):
    eps = generate_episodes(box_scene, "habitat", EpisodeGenConfig(per_bin=3), seed=5, navgrid=box_nav, renderer=box_renderer)
    env = ImageNavEnv(box_scene, "habitat", eps, navgrid=box_nav, renderer=box_renderer)
    agent = ExpertAgent(kind="explore")
    for i in (0, 4):  # an easy and a medium one (goal out of view at the start in both)
        rec, actions, modes, st = _run(env, agent, i)
        assert rec.success, (i, st)
        assert actions[-1] == env.task.action_id("STOP") and modes[-1] == "geodesic"


def test_expert_agent_kind_is_checked():
    with pytest.raises(ValueError):
        ExpertAgent(kind="oracle")
