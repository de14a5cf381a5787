"""Last mile (SLING-style): goal pose from a rendered pair, no acceptance across houses, the controller on its own
seen map, hand-back when the estimate is dropped, and ``nue eval -c sling+fr=...`` end to end."""

from __future__ import annotations

import json
import math
from types import SimpleNamespace
from unittest import mock

import numpy as np
import pytest
import torch
import trimesh
from PIL import Image, ImageDraw

from nue.nerf.config import get_memory
from nue.policy import build_model
from nue.policy.checkpoint import policy_meta, save_checkpoint
from nue.policy.config import get_model_config
from nue.policy.goal_pose import GoalMeasurement, GoalPoseEstimator, GoalTracker, TrackerConfig
from nue.policy.last_mile import LastMileAgent, LastMileConfig
from nue.rollout import run_episode
from nue.scene.navgrid import NavGrid
from nue.sim.camera import quat_from_yaw
from nue.sim.env import ImageNavEnv
from nue.sim.episode_gen import EpisodeGenConfig, generate_episodes
from nue.sim.episodes import Episode, save_episodes
from nue.sim.renderer import Renderer
from nue.sim.task import get_task

from .conftest import FIXTURES, nue_here

TASK = get_task("paper")
CAM = TASK.camera
FORWARD, LEFT = TASK.action_id("MOVE_FORWARD"), TASK.action_id("TURN_LEFT")


def _poster(rng: np.random.Generator, size: int = 256) -> Image.Image:
    """A non-repeating texture: 60 random ellipses and rectangles on a random background."""
    img = Image.new("RGB", (size, size), tuple(int(v) for v in rng.integers(40, 215, 3)))
    draw = ImageDraw.Draw(img)
    for _ in range(60):
        x0, y0 = rng.integers(0, size - 20, 2)
        w, h = rng.integers(8, 60, 2)
        box = [int(x0), int(y0), int(x0 + w), int(y0 + h)]
        colour = tuple(int(v) for v in rng.integers(0, 256, 3))
        (draw.ellipse if rng.random() < 0.5 else draw.rectangle)(box, fill=colour)
    return img


def _textured_room(seed: int) -> trimesh.Scene:
    """A 6 m x 6 m room, walls 2.6 m high: every wall and the floor carry their own random poster texture."""
    rng = np.random.default_rng(seed)
    faces = [  # four corners of each quad, counter-clockwise seen from inside
        [(-3, -3, 0), (3, -3, 0), (3, -3, 2.6), (-3, -3, 2.6)],
        [(3, -3, 0), (3, 3, 0), (3, 3, 2.6), (3, -3, 2.6)],
        [(3, 3, 0), (-3, 3, 0), (-3, 3, 2.6), (3, 3, 2.6)],
        [(-3, 3, 0), (-3, -3, 0), (-3, -3, 2.6), (-3, 3, 2.6)],
        [(-3, -3, 0), (-3, 3, 0), (3, 3, 0), (3, -3, 0)],
    ]
    meshes = []
    for quad in faces:
        for k in range(3):  # three panels per face: more texture per metre
            a, b, c, d = (np.asarray(p, dtype=float) for p in quad)
            lo, hi = k / 3, (k + 1) / 3
            verts = np.array([a + (b - a) * lo, a + (b - a) * hi, d + (c - d) * hi, d + (c - d) * lo])
            m = trimesh.Trimesh(verts, [[0, 1, 2], [0, 2, 3]], process=False)
            m.visual = trimesh.visual.TextureVisuals(uv=np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float),
                                                     image=_poster(rng))
            meshes.append(m)
    return trimesh.Scene(meshes)


@pytest.fixture(scope="module")
def rooms():
    return Renderer(_textured_room(1), CAM), Renderer(_textured_room(2), CAM)


def test_goal_pose_from_a_rendered_pair_within_5cm_and_2deg(rooms):
    room, _ = rooms
    goal = np.array([0.4, -0.3, 0.35])
    goal_rgb, _ = room.render(goal)
    est = GoalPoseEstimator(CAM)
    est.set_goal(goal_rgb)
    # 1.2 m behind the goal, 0.3 m to its right, turned 12 deg: a known relative pose
    back, right, turn = 1.2, 0.3, math.radians(12)
    c, s = math.cos(goal[2]), math.sin(goal[2])
    pose = np.array([goal[0] - back * c + right * s, goal[1] - back * s - right * c, goal[2] + turn])
    rgb, depth = room.render(pose)
    m = est.estimate(rgb, depth, pose)
    assert m is not None, est.report
    assert np.linalg.norm(m.xy - goal[:2]) < 0.05
    assert abs(math.remainder(m.yaw - goal[2], 2 * math.pi)) < math.radians(2)
    assert m.distance == pytest.approx(math.hypot(back, right), abs=0.05)
    assert m.inliers >= est.config.min_inliers and m.agreement > 0.9


def test_no_acceptance_on_a_goal_photo_from_another_house(rooms):
    room, other = rooms
    est = GoalPoseEstimator(CAM)
    est.set_goal(other.render((0.4, -0.3, 0.35))[0])
    tracker = GoalTracker()
    reasons = set()
    for x, y in [(-1.5, -1.5), (0.0, 0.0), (1.5, 1.0)]:
        for k in range(8):
            pose = np.array([x, y, k * math.pi / 4])
            rgb, depth = room.render(pose)
            m = est.estimate(rgb, depth, pose)
            assert m is None, (pose, m)
            reasons.add(est.report.reason)
    assert not tracker.accepted and reasons <= {"few_matches", "pnp_failed", "few_inliers", "tilted", "height",
                                                "range", "disagrees", "ambiguous"}


def test_tracker_refines_accepts_and_drops_on_inconsistent_measurements():
    tr = GoalTracker(TrackerConfig(accept_inliers=20, consistency_radius=0.5, max_strikes=2))

    def meas(x, y, n):
        return GoalMeasurement(np.array([x, y]), 0.0, n, n, 1.0, 0.5, 0.9)

    assert tr.update(meas(1.0, 1.0, 12)) == "new" and not tr.accepted
    assert tr.update(meas(1.2, 1.0, 12)) == "accepted" and tr.accepted
    np.testing.assert_allclose(tr.xy, [1.1, 1.0])
    assert tr.update(meas(3.0, 1.0, 30)) == "strike" and tr.accepted
    assert tr.update(meas(3.0, 1.1, 30)) == "dropped"
    np.testing.assert_allclose(tr.xy, [3.0, 1.1])  # the last one starts the new estimate (30 inliers: accepted)
    tr.drop(disproved=True)
    assert tr.xy is None and tr.update(meas(3.1, 1.1, 50)) == "ignored"


class _Inner:
    """A wrapped agent that always turns left and counts its calls."""

    def __init__(self):
        self.calls = 0

    def reset(self, env, obs, seed=0):
        self.calls = 0

    def act(self, obs, maps):
        self.calls += 1
        return LEFT


class _Blindfolded:
    """Runs a :class:`LastMileAgent` given only what the robot knows of the env (task, floor height): any read of the
    scene, its navigation grid or the goal fails. ``estimate``: world (x, y) injected as a strong measurement."""

    def __init__(self, agent: LastMileAgent, estimate):
        self.agent, self.estimate = agent, np.asarray(estimate, dtype=float)

    def reset(self, env, obs, seed=0):
        self.agent.reset(SimpleNamespace(task=env.task, floor_z=env.floor_z), obs, seed)
        self.agent.tracker.update(GoalMeasurement(self.estimate, 0.0, 100, 100, 1.0, 0.5, 0.9))

    def act(self, obs, maps):
        return self.agent.act(obs, maps)


def _episode(start, yaw, goal) -> Episode:
    return Episode("lm", "box_room", (start[0], start[1], 0.0), tuple(quat_from_yaw(yaw)), (goal[0], goal[1], 0.0),
                   tuple(quat_from_yaw(0.0)), float(np.hypot(*np.subtract(goal, start))), 0.0)


def test_controller_reaches_an_estimated_goal_round_the_corridor_on_its_own_map(box_scene, box_nav, box_renderer):
    # start in the 2 m wide west corridor (x < -1), facing south; the goal is behind the inner wall, reached
    # only through the gap at its north end (y > 1.5): the straight line is blocked
    ep = _episode((-2.0, -2.0), -math.pi / 2, (0.0, -1.5))
    env = ImageNavEnv(box_scene, TASK, navgrid=box_nav, renderer=box_renderer)
    agent = LastMileAgent(_Inner())
    with mock.patch.object(NavGrid, "shortest_path", side_effect=AssertionError("planned on the scene's grid")):
        rec = run_episode(env, _Blindfolded(agent, (0.0, -1.5)), episode=ep)
    assert rec.success and rec.steps < 120, (rec.steps, agent.events)
    assert agent.control_steps == rec.steps and agent.inner_actions == 0
    assert agent.map.obstacle.any() and agent.map.floor.any()
    assert rec.collisions <= 2


def test_wrapper_hands_back_control_when_the_estimate_is_dropped(box_scene, box_nav, box_renderer):
    # a wrong estimate 1.5 m ahead: the controller drives there, arrives with the episode still running,
    # drops it and the wrapped agent acts again
    ep = _episode((1.5, 1.5), math.pi, (2.2, -0.8))
    env = ImageNavEnv(box_scene, TASK, navgrid=box_nav, renderer=box_renderer)
    inner = _Inner()
    agent = LastMileAgent(inner)
    actions = []
    run_episode(env, _Blindfolded(agent, (0.0, 1.5)), episode=ep, on_step=lambda s: actions.append(s.action))
    drops = [e for e in agent.events if e[1].startswith("drop_")]
    assert drops and drops[0][1] == "drop_arrived", agent.events
    t = drops[0][0]
    assert FORWARD in actions[:t] and all(a == LEFT for a in actions[t:]), actions
    assert inner.calls == len(actions)  # asked every step, also while the controller drove
    assert agent.tracker.xy is None and not agent.driving and len(agent.tracker.rejected) == 1
    summary = agent.summary(goal_xy=env.goal_xy)
    assert summary["control_steps"] == t and summary["estimate"] is None
    json.dumps(summary)


class _Fixed:
    """An estimator that always measures the goal ``distance`` metres straight ahead."""

    def __init__(self, distance):
        self.distance, self.report = distance, SimpleNamespace(matches=50)

    def estimate(self, rgb, depth, pose):
        xy = np.asarray(pose[:2]) + self.distance * np.array([math.cos(pose[2]), math.sin(pose[2])])
        return GoalMeasurement(xy, 0.0, 30, 50, self.distance, 0.5, 0.9)


def test_a_goal_measured_inside_the_success_radius_is_rejected_when_that_is_asked(box_scene, box_nav, box_renderer):
    """Without STOP, success ends the episode, so a running episode's goal is never within the success radius: with
    ``reject_inside_success`` a measurement 0.5 m away (radius 0.8 m) is dropped, one 1.5 m away kept; off, both
    are kept (the default, which the recorded SLING rows ran with: their settings dict is unchanged)."""
    env = ImageNavEnv(box_scene, TASK, navgrid=box_nav, renderer=box_renderer)
    obs, _ = env.reset(options={"episode": _episode((-2.0, -2.0), 0.0, (0.0, -1.5))})
    assert not TASK.success_requires_stop and TASK.success_radius == 0.8
    for on, kept in ((True, [1.5]), (False, [0.5, 1.5])):
        agent = LastMileAgent(_Inner(), LastMileConfig(reject_inside_success=on))
        agent.reset(SimpleNamespace(task=env.task, floor_z=env.floor_z), obs, 0)
        for d in (0.5, 1.5):
            agent.estimator = _Fixed(d)
            agent._measure(obs, np.asarray(obs["pose"], dtype=float))
        assert [m[5] for m in agent.measurements] == kept
        assert any(e[1] == "reject_inside_success" for e in agent.events) == on
    assert "reject_inside_success" not in LastMileConfig().to_dict()
    assert LastMileConfig(reject_inside_success=True).to_dict()["reject_inside_success"] is True


@pytest.fixture(scope="module")
def episodes_dir(tmp_path_factory, box_scene, box_nav, box_renderer):
    d = tmp_path_factory.mktemp("episodes")
    eps = generate_episodes(box_scene, "paper", EpisodeGenConfig(per_bin=1), seed=4, navgrid=box_nav, renderer=box_renderer)
    save_episodes(d / "box_room.json", eps[:1], "paper")
    return d


def test_nue_eval_runs_a_sling_row_and_refuses_other_wrapper_settings_on_resume(tmp_path, episodes_dir):
    from nue.errors import DataError
    from nue.evaluate.runner import EvalConfig, run_eval

    cfg = get_model_config("fr").for_task(TASK)
    torch.manual_seed(0)
    ckpt = save_checkpoint(tmp_path / "fr.pt", {**policy_meta(TASK, get_memory("fast"), cfg, {}),
                                                 "model_state": build_model(cfg).state_dict(), "step": 0})
    out = tmp_path / "records.jsonl"
    res = nue_here("eval", "-c", f"sling+fr={ckpt}", "--out", out, "--episodes-dir", episodes_dir,
                   "--scenes-root", FIXTURES, "--max-steps", 25)
    assert res.returncode == 0, res.stderr
    (rec,) = [json.loads(line) for line in out.read_text().splitlines()]
    assert rec["method"] == "sling+fr" and "## sling+fr" in res.stdout
    lm = rec["extra"]["last_mile"]
    assert {"first_match_step", "first_accept_step", "events", "control_steps", "estimate_error",
            "ms_per_step"} <= set(lm)
    assert rec["extra"]["settings"]["last_mile"] == LastMileConfig().to_dict()
    # --last-mile FILE: other settings, stored in the record; the same file's resume is refused
    settings = tmp_path / "lm.json"
    settings.write_text(json.dumps({"pose": {"contrast_threshold": 0.01}, "match_every": 3}))
    out2 = tmp_path / "records2.jsonl"
    res = nue_here("eval", "-c", f"sling+fr={ckpt}", "--out", out2, "--episodes-dir", episodes_dir,
                   "--scenes-root", FIXTURES, "--max-steps", 25, "--last-mile", settings)
    assert res.returncode == 0, res.stderr
    (rec2,) = [json.loads(line) for line in out2.read_text().splitlines()]
    stored = rec2["extra"]["settings"]["last_mile"]
    assert stored["pose"]["contrast_threshold"] == 0.01 and stored["match_every"] == 3
    assert stored["tracker"] == LastMileConfig().to_dict()["tracker"]
    res = nue_here("eval", "-c", f"sling+fr={ckpt}", "--out", out, "--episodes-dir", episodes_dir,
                   "--scenes-root", FIXTURES, "--max-steps", 25, "--last-mile", settings)
    assert res.returncode == 2 and "last_mile" in res.stderr and "Traceback" not in res.stderr
    other = EvalConfig(episodes_dir=str(episodes_dir), scenes_root=str(FIXTURES), max_steps=25,
                       last_mile=LastMileConfig(match_every=7))
    with pytest.raises(DataError, match="last_mile"):
        run_eval([f"sling+fr={ckpt}"], out, other, progress=False)


def test_last_mile_settings_round_trip_and_bad_ones_are_named():
    from nue.errors import ConfigError

    cfg = LastMileConfig(match_every=3, reject_inside_success=True)
    assert LastMileConfig.from_dict(cfg.to_dict()) == cfg
    assert LastMileConfig.from_dict({"pose": {"min_inliers": 8}}).pose.min_inliers == 8
    for bad, words in [({"pose": {"contrast": 0.01}}, "pose.contrast"), ({"match_every": "4"}, "match_every"),
                       ({"match_every": 2.5}, "integer"), ({"pose": 3}, "pose: expected an object"),
                       ({"locator": "orb"}, "locator")]:
        with pytest.raises(ConfigError, match=words) as e:
            LastMileConfig.from_dict(bad, "lm.json")
        assert str(e.value).startswith("lm.json: ")


def test_a_bad_last_mile_file_exits_2_naming_it(tmp_path):
    for text, words in [("{", "not a JSON file"), ('{"pose": {"contrast": 1}}', "pose.contrast")]:
        f = tmp_path / "lm.json"
        f.write_text(text)
        res = nue_here("eval", "-c", "expert", "--out", tmp_path / "r.jsonl", "--last-mile", f)
        assert res.returncode == 2 and str(f) in res.stderr and words in res.stderr and "Traceback" not in res.stderr
    res = nue_here("eval", "-c", "expert", "--out", tmp_path / "r.jsonl", "--last-mile", tmp_path / "none.json")
    assert res.returncode == 2 and "none.json" in res.stderr


def test_a_sling_spec_without_a_checkpoint_exits_2(tmp_path):
    res = nue_here("eval", "-c", "sling+", "--out", tmp_path / "r.jsonl")
    assert res.returncode == 2 and "sling+" in res.stderr and "Traceback" not in res.stderr
    missing = tmp_path / "missing.pt"
    res = nue_here("eval", "-c", f"sling+{missing}", "--out", tmp_path / "r.jsonl")
    assert res.returncode == 2 and str(missing) in res.stderr
