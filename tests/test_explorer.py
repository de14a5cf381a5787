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


def _reference_floor_obstacle(depth, pose, cam, grid, floor_z, config):
    """The seen-cell geometry written out plainly (full back-projection, every cell in range projected)."""
    from nue.sim.camera import depth_to_points, world_from_camera

    z = np.nan_to_num(np.asarray(depth, dtype=np.float64).reshape(cam.height, cam.width), nan=0.0)
    pts = depth_to_points(z, pose, cam, floor_z)
    x0, y0 = float(pose[0]), float(pose[1])
    near_px = np.hypot(pts[..., 0] - x0, pts[..., 1] - y0) <= config.max_range
    floor_px = (z > 0) & (np.abs(pts[..., 2] - floor_z) <= config.floor_tolerance) & near_px

    def mark(mask, xy):
        rc = np.asarray(grid.cell_of(xy)).reshape(-1, 2)
        ok = (rc >= 0).all(axis=1) & (rc[:, 0] < mask.shape[0]) & (rc[:, 1] < mask.shape[1])
        mask[rc[ok, 0], rc[ok, 1]] = True

    floor = np.zeros(grid.free.shape, dtype=bool)
    mark(floor, pts[floor_px][:, :2])
    rr, cc = np.meshgrid(np.arange(floor.shape[0]), np.arange(floor.shape[1]), indexing="ij")
    cells = np.stack([rr.ravel(), cc.ravel()], axis=-1)
    centres = np.asarray(grid.cell_centre(cells))
    near = np.hypot(centres[:, 0] - x0, centres[:, 1] - y0) <= config.max_range
    cells, centres = cells[near], centres[near]
    m = world_from_camera(pose, cam, floor_z)
    p_cam = (np.c_[centres, np.full(len(centres), floor_z)] - m[:3, 3]) @ m[:3, :3]
    front = p_cam[:, 2] > 1e-6
    u = np.floor(cam.fx * p_cam[front, 0] / p_cam[front, 2] + cam.cx).astype(np.int64)
    v = np.floor(cam.fy * p_cam[front, 1] / p_cam[front, 2] + cam.cy).astype(np.int64)
    inside = (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
    cells = cells[front][inside]
    sees = floor_px[v[inside], u[inside]]
    if config.occlusion_rows is not None:  # the pixel's depth agrees with the cell centre's (not a wall's foot)
        zc = p_cam[front, 2][inside]
        h_cam = m[2, 3] - floor_z
        tol = config.floor_tolerance + config.occlusion_rows * (zc**2 + h_cam**2) / (h_cam * cam.fy)
        sees &= np.abs(z[v[inside], u[inside]] - zc) <= tol
    floor[cells[sees, 0], cells[sees, 1]] = True
    height = pts[..., 2] - floor_z
    hit = (z > 0) & (height >= config.obstacle_min_height) & (height <= config.obstacle_max_height) & near_px
    obstacle = np.zeros(grid.free.shape, dtype=bool)
    mark(obstacle, pts[hit][:, :2])
    return floor, obstacle


def test_seen_cells_equal_the_plain_geometry_and_the_tracker_the_union(box_nav, box_renderer):
    """The fast path (world z without the matmul, x/y of the chosen pixels only, cells seen before not
    projected again) gives exactly the masks of the plain full back-projection, also with NaN / inf / 0 depth."""
    from nue.evaluate.coverage import CoverageTracker
    from nue.rollout import StepData
    from nue.sim import seen

    cam, cfg = box_renderer.camera, seen.CoverageConfig()
    rng = np.random.default_rng(3)
    tracker, union, areas = CoverageTracker(cam, box_nav, 0.0), None, []
    for i in range(12):
        pose = np.array([rng.uniform(-1.5, 0.3), rng.uniform(-2.8, 1.0), rng.uniform(-np.pi, np.pi)])
        _, depth = box_renderer.render(pose, 0.0)
        if i % 3 == 2:
            depth = depth.copy()
            depth[:10], depth[10:14], depth[14:16] = np.nan, np.inf, 0.0
        with np.errstate(over="ignore", invalid="ignore"):  # inf depth overflows in the back-projection
            floor, obstacle = seen.seen_cells(depth, pose, cam, box_nav, 0.0, cfg)
            ref_floor, ref_obstacle = _reference_floor_obstacle(depth, pose, cam, box_nav, 0.0, cfg)
            assert np.array_equal(seen.seen_floor_cells(depth, pose, cam, box_nav, 0.0, cfg), ref_floor)
            tracker(StepData(i, {"depth": depth, "pose": pose}, None, 0, {}, None))
        assert np.array_equal(floor, ref_floor) and np.array_equal(obstacle, ref_obstacle)
        union = ref_floor if union is None else union | ref_floor
        areas.append(round(seen.cell_area(box_nav) * float(np.count_nonzero(union)), 6))
    assert np.array_equal(tracker.seen, union) and tracker.areas == areas and areas[-1] > areas[0]


def test_floor_behind_a_wall_is_not_seen(box_nav, box_renderer):
    """Facing the box room's inner wall (x = -1, y < 1.5) from 3.5 m, no floor cell behind it counts as seen; without
    the depth check (``occlusion_rows=None``) the floor just behind the wall's foot did (300 cells, 0.75 m²)."""
    from nue.sim import seen

    cam = box_renderer.camera
    pose = np.array([2.5, -1.0, np.pi])
    _, depth = box_renderer.render(pose, 0.0)
    centres = np.asarray(box_nav.cell_centre(np.argwhere(np.ones(box_nav.free.shape, dtype=bool)))).reshape(
        *box_nav.free.shape, 2)
    behind = (centres[..., 0] < -1.1) & (centres[..., 1] < 1.3)
    now = seen.seen_floor_cells(depth, pose, cam, box_nav, 0.0)
    before = seen.seen_floor_cells(depth, pose, cam, box_nav, 0.0, seen.CoverageConfig(occlusion_rows=None))
    assert now.sum() > 100 and not (now & behind).any()
    assert (before & behind).sum() > 100


def test_explorer_succeeds_on_the_ci_episodes(paper_runs):
    env, runs = paper_runs
    for i, (rec, _actions, _modes, st) in enumerate(runs):
        assert rec.success, (i, st)
        assert rec.collisions <= 2, (i, rec.collisions)
        assert st["explore_steps"] <= 250


def test_goal_out_of_view_explores_frontiers_then_switches_for_good(paper_runs):
    _, runs = paper_runs
    out_of_view = [r for r in runs if not r[3]["goal_in_view_at_start"]]
    assert len(out_of_view) >= 3  # the inner wall hides most goals at the start
    for _rec, _actions, modes, st in out_of_view:
        assert st["targets_reached"] >= 1, st  # at least one frontier target completed while exploring
        k = modes.index("geodesic") if "geodesic" in modes else len(modes)
        assert k >= 1 and set(modes[:k]) == {"explore"} and set(modes[k:]) <= {"geodesic"}  # never back
        assert st["explore_steps"] == k
    for _rec, _actions, _modes, st in runs:
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
