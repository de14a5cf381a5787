"""The exploitation head (issue 37): its loss by hand, the model's outputs and config, the learned goal locator's
measurement, and the ``commit+`` wrapper driving to where the heads say the goal is."""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from nue.nerf.config import get_memory
from nue.policy import build_model
from nue.policy.base import PolicyOutput
from nue.policy.checkpoint import policy_meta, save_checkpoint
from nue.policy.commit import LearnedGoalLocator, LearnedLocatorConfig
from nue.policy.config import ModelConfig, get_model_config
from nue.policy.inputs import PolicyInput
from nue.policy.last_mile import COMMIT_LAST_MILE, LastMileAgent, LastMileConfig
from nue.rollout import run_episode
from nue.sim.camera import quat_from_yaw
from nue.sim.env import ImageNavEnv
from nue.sim.episodes import Episode
from nue.sim.task import get_task
from nue.train.bc import goal_head_loss

from .conftest import FIXTURES, nue_here

TASK = get_task("paper")
LEFT = TASK.action_id("TURN_LEFT")


def test_goal_head_loss_by_hand():
    # logits 0 and 2 for labels 1 and 0; distances: the in-view step predicts log 2 for a true 1 m
    out = PolicyOutput(torch.zeros(2, 3), None, None, torch.tensor([0.0, 2.0]), torch.tensor([math.log(2.0), 5.0]))
    batch = SimpleNamespace(goal_in_view=torch.tensor([1.0, 0.0]), goal_distance=torch.tensor([1.0, 7.0]))
    bce = (math.log(2.0) + math.log(1 + math.exp(2.0))) / 2
    assert float(goal_head_loss(out, batch)) == pytest.approx(bce + math.log(2.0), rel=1e-6)
    weighted = (3 * math.log(2.0) + math.log(1 + math.exp(2.0))) / 2  # the in-view step counts 3 times
    assert float(goal_head_loss(out, batch, pos_weight=3.0)) == pytest.approx(weighted + math.log(2.0), rel=1e-6)
    batch.goal_in_view = torch.tensor([0.0, 0.0])  # no in-view step: the distance term is left out
    bce0 = (math.log(2.0) + math.log(1 + math.exp(2.0))) / 2
    assert float(goal_head_loss(out, batch)) == pytest.approx(bce0, rel=1e-6)


def test_action_loss_weighs_the_in_view_steps_by_hand():
    """Two steps with equal class weights: cross-entropies ln 3 (uniform logits, goal not in view) and
    ln(1 + 2 e^2) (the label's logit 2 below the others', in view). exploit_weight 3: (ln 3 + 3 ln(1 + 2 e^2)) / 4;
    at weight 1 (or without labels) it is F.cross_entropy with the class weights."""
    from nue.train.losses import action_loss

    logits, action = torch.tensor([[0.0, 0.0, 0.0], [0.0, 2.0, 2.0]]), torch.tensor([1, 0])
    view, w = torch.tensor([0, 1], dtype=torch.int8), torch.ones(3)
    ce0, ce1 = math.log(3.0), math.log(1 + 2 * math.exp(2.0))
    assert float(action_loss(logits, action, w, view, 3.0)) == pytest.approx((ce0 + 3 * ce1) / 4, rel=1e-6)
    assert float(action_loss(logits, action, w, view, 1.0)) == pytest.approx((ce0 + ce1) / 2, rel=1e-6)
    assert float(action_loss(logits, action, w, None, 3.0)) == pytest.approx((ce0 + ce1) / 2, rel=1e-6)
    cw = torch.tensor([2.0, 1.0, 1.0])  # class weights multiply in: the in-view step's label 0 weighs 2 x 3
    assert float(action_loss(logits, action, cw, view, 3.0)) == pytest.approx((ce0 + 6 * ce1) / 7, rel=1e-6)


def test_in_view_weight_is_the_ratio_of_other_steps_to_in_view_steps():
    from nue.train.bc import in_view_weight

    data = SimpleNamespace(episodes=[{"goal_in_view": np.array([0, 0, 1], np.int8)}, {"goal_in_view": np.array([0, 0, 0, 1], np.int8)}])
    assert in_view_weight(data) == 2.5
    assert in_view_weight(SimpleNamespace(episodes=[{"goal_in_view": np.zeros(4, np.int8)}])) == 1.0


def test_auroc_and_goal_head_scores_by_hand():
    from nue.policy.accuracy import auroc, goal_head_scores

    assert auroc(np.array([0.1, 0.4, 0.35, 0.8]), np.array([0, 0, 1, 1])) == 0.75
    assert auroc(np.array([0.5, 0.5]), np.array([0, 1])) == 0.5 and math.isnan(auroc(np.ones(3), np.ones(3)))
    s = goal_head_scores(np.array([0.9, 0.2, 0.6, 0.1]), np.log(np.array([2.0, 1.0, 1.0, 5.0])),
                         np.array([True, True, False, False]), np.array([1.0, 1.0, 3.0, 3.0]),
                         np.radians(np.array([10.0, 30.0, 0.0, 0.0])))
    assert s["goal_view_auroc"] == 0.75 and s["goal_view_precision"] == 0.5 and s["goal_view_recall"] == 0.5
    assert s["goal_log_distance_error"] == pytest.approx(math.log(2.0) / 2) and s["angle_error_in_view_deg"] == pytest.approx(20.0)


def _input(cfg: ModelConfig, b: int) -> PolicyInput:
    h, w = cfg.map_size
    return PolicyInput(rgbd=torch.rand(b, 4, *cfg.frame_size), goal=torch.rand(b, 3, *cfg.frame_size),
                       i_u=torch.rand(b, 1, h, w), i_cog=torch.rand(b, 64, h, w))


def test_nue_goal_outputs_both_heads_and_its_config_round_trips():
    cfg = get_model_config("nue_goal").for_task(TASK)
    torch.manual_seed(0)
    model = build_model(cfg).eval()
    out = model(_input(cfg, 2))
    assert out.goal_view.shape == (2,) and out.goal_log_distance.shape == (2,) and out.aux_angle.shape == (2,)
    inp = _input(cfg, 6)
    seq = model.forward_sequence(PolicyInput(*(x.reshape(3, 2, *x.shape[1:]) for x in
                                               (inp.rgbd, inp.goal, inp.i_u, inp.i_cog))))
    assert seq.goal_view.shape == (3, 2) and torch.allclose(seq.goal_view.reshape(-1), model(inp).goal_view, atol=1e-5)
    assert ModelConfig.from_dict(cfg.to_dict()) == cfg and cfg.to_dict()["goal_head"] is True
    assert "goal_head" not in get_model_config("nue").to_dict()  # older configs keep their exact dict
    assert build_model(get_model_config("nue")).goal_head is None
    with pytest.raises(Exception, match="goal_head"):
        get_model_config("fr").replace(goal_head=True)


class _Heads:
    """A stand-in policy with fixed head outputs."""

    def __init__(self, p, d, a):
        self.config = SimpleNamespace(goal_head=True, name="stub")
        self.last_goal_view, self.last_goal_distance, self.last_aux = p, d, a


def test_learned_locator_turns_the_heads_into_a_world_position():
    loc = LearnedGoalLocator(_Heads(0.8, 2.0, math.pi / 2), LearnedLocatorConfig(weight=10.0, bearing="aux"))
    m = loc.estimate(None, None, np.array([1.0, 1.0, math.pi / 2]))  # facing +y, goal 90 deg to the left: -x
    assert m is not None and np.allclose(m.xy, [-1.0, 1.0]) and m.inliers == 8 and m.distance == 2.0
    ahead = LearnedGoalLocator(_Heads(0.8, 2.0, math.pi / 2))  # default: straight ahead, the angle head ignored
    m = ahead.estimate(None, None, np.array([1.0, 1.0, math.pi / 2]))
    assert m is not None and np.allclose(m.xy, [1.0, 3.0])
    with pytest.raises(ValueError, match="bearing"):
        LearnedLocatorConfig(bearing="map")
    assert LearnedGoalLocator(_Heads(0.3, 2.0, 0.0)).estimate(None, None, np.zeros(3)) is None
    assert LearnedGoalLocator(_Heads(0.9, 9.0, 0.0)).estimate(None, None, np.zeros(3)) is None
    with pytest.raises(ValueError, match="goal_head"):
        LearnedGoalLocator(SimpleNamespace(config=get_model_config("nue")))


class _Oracle(_Heads):
    """Heads that see the goal within 3 m (from the env, for the test only) and otherwise turn left."""

    def __init__(self):
        super().__init__(None, None, None)
        self.calls = 0

    def reset(self, env, obs, seed=0):
        self.env = env

    def act(self, obs, maps):
        self.calls += 1
        env = self.env
        d = float(np.hypot(*(env.goal_xy - obs["pose"][:2])))
        self.last_goal_view = 0.95 if d <= 3.0 else 0.05
        self.last_goal_distance, self.last_aux = d, env.goal_angle()
        return LEFT


def test_commit_wrapper_drives_to_where_the_heads_put_the_goal(box_scene, box_nav, box_renderer):
    ep = Episode("c", "box_room", (1.5, 1.5, 0.0), tuple(quat_from_yaw(math.pi)), (0.0, 1.5, 0.0),
                 tuple(quat_from_yaw(0.0)), 1.5, 0.0)
    env = ImageNavEnv(box_scene, TASK, navgrid=box_nav, renderer=box_renderer)
    inner = _Oracle()
    agent = LastMileAgent(inner, COMMIT_LAST_MILE)
    rec = run_episode(env, agent, episode=ep)
    assert rec.success and agent.control_steps > 0 and rec.steps < 60, agent.events
    summary = agent.summary(goal_xy=env.goal_xy)
    assert summary["first_accept_step"] is not None and summary["estimate_error"] < 0.3
    json.dumps(summary)


def test_last_mile_settings_keep_their_dict_for_sift_and_add_the_locator_otherwise():
    assert "locator" not in LastMileConfig().to_dict()
    assert COMMIT_LAST_MILE.to_dict()["locator"] == "learned"
    with pytest.raises(ValueError, match="locator"):
        LastMileConfig(locator="magic")


def test_nue_eval_runs_a_commit_row_and_refuses_a_model_without_the_head(tmp_path, episodes_dir):
    memory = get_memory("fast")
    paths = {}
    for name in ("nue_goal", "nue"):
        cfg = get_model_config(name).for_task(TASK)
        torch.manual_seed(0)
        paths[name] = save_checkpoint(tmp_path / f"{name}.pt", {**policy_meta(TASK, memory, cfg, {}),
                                                               "model_state": build_model(cfg).state_dict(), "step": 0})
    out = tmp_path / "records.jsonl"
    res = nue_here("eval", "-c", f"commit+nue_goal={paths['nue_goal']}", "--out", out, "--episodes-dir", episodes_dir,
                   "--scenes-root", FIXTURES, "--max-steps", 6)
    assert res.returncode == 0, res.stderr
    (rec,) = [json.loads(line) for line in out.read_text().splitlines()]
    assert rec["method"] == "commit+nue_goal" and rec["extra"]["settings"]["last_mile"]["locator"] == "learned"
    assert rec["extra"]["last_mile"]["match_calls"] == rec["steps"]
    res = nue_here("eval", "-c", f"commit+{paths['nue']}", "--out", tmp_path / "r2.jsonl", "--episodes-dir",
                   episodes_dir, "--scenes-root", FIXTURES, "--max-steps", 6)
    assert res.returncode == 2 and "goal head" in res.stderr and "Traceback" not in res.stderr


@pytest.fixture(scope="module")
def episodes_dir(tmp_path_factory, box_scene, box_nav, box_renderer):
    from nue.sim.episode_gen import EpisodeGenConfig, generate_episodes
    from nue.sim.episodes import save_episodes

    d = tmp_path_factory.mktemp("episodes")
    eps = generate_episodes(box_scene, "paper", EpisodeGenConfig(per_bin=1), seed=4, navgrid=box_nav, renderer=box_renderer)
    save_episodes(d / "box_room.json", eps[:1], "paper")
    return d


def test_goal_match_learns_to_tell_a_shifted_view_of_the_same_scene_from_another_scene():
    """f_match separates 'the goal shows this scene' (the frame shifted by a few pixels) from 'another scene' after a
    short training on random blob images; the best-match maps are cosines, in [-1, 1]."""
    from nue.policy.goal_match import GoalMatch

    torch.manual_seed(0)
    gen = torch.Generator().manual_seed(1)

    def scenes(n):
        x = torch.rand(n, 3, 8, 10, generator=gen)
        return torch.nn.functional.interpolate(x, size=(48, 64), mode="bilinear", align_corners=False)

    def pairs(n):
        a, b = scenes(n), scenes(n)
        shift = torch.roll(a, shifts=(3, 5), dims=(2, 3))
        y = (torch.rand(n, generator=gen) < 0.5).float()
        goal = torch.where(y[:, None, None, None] > 0, shift, b)
        return a, goal, y

    net = GoalMatch(8)
    clf = torch.nn.Linear(8, 1)
    opt = torch.optim.Adam([*net.parameters(), *clf.parameters()], lr=3e-3)
    for _ in range(150):
        a, g, y = pairs(32)
        loss = torch.nn.functional.binary_cross_entropy_with_logits(clf(net(a, g))[:, 0], y)
        opt.zero_grad()
        loss.backward()
        opt.step()
    a, g, y = pairs(200)
    with torch.no_grad():
        acc = float(((clf(net(a, g))[:, 0] > 0).float() == y).float().mean())
        m_goal, m_frame = net.correlation(a, g)
    assert acc > 0.85, acc
    assert m_goal.shape == (200, 48) and m_frame.shape == (200, 6, 8) and float(m_frame.abs().max()) <= 1.0 + 1e-5
