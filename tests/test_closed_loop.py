"""The closed-loop recipe's parts: per-step trajectories in records, DART noise injection, map dropout,
closed-loop model selection."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch

from nue.errors import DataError
from nue.policy.agent import ExpertAgent, NoisyAgent
from nue.rollout import run_episode
from nue.selection import CandidateScore, SelectConfig, pick_best, select_checkpoint
from nue.sim.env import ImageNavEnv
from nue.sim.episode_gen import EpisodeGenConfig, generate_episodes
from nue.sim.episodes import save_episodes
from nue.sim.record import EpisodeRecord, Trajectory
from nue.train.collect import CollectConfig, collect
from nue.train.dataset import Batch, DemoSet, swap_maps
from nue.policy.inputs import PolicyInput

from .conftest import BOX_ROOM


@pytest.fixture(scope="module")
def box_episodes(box_scene, box_nav, box_renderer):
    return generate_episodes(box_scene, "paper", EpisodeGenConfig(per_bin=1), seed=3, navgrid=box_nav,
                             renderer=box_renderer, bins=("easy", "medium"))


@pytest.fixture(scope="module")
def box_env(box_scene, box_nav, box_renderer, box_episodes):
    return ImageNavEnv(box_scene, "paper", box_episodes, navgrid=box_nav, renderer=box_renderer)


# --- per-step trajectories ------------------------------------------------------------------------
def test_trajectory_encoding_round_trips_to_stored_precision():
    poses = np.array([[1.234, -5.678, 3.1], [1.484, -5.678, 3.1], [1.484, -5.678, -2.9]])
    traj = Trajectory(np.array([0, 1]), np.array([True, False]), poses)
    d = json.loads(json.dumps(traj.encode()))
    assert d["actions"] == "01" and d["collided"] == [0]
    back = Trajectory.decode(d)
    assert np.array_equal(back.actions, [0, 1]) and np.array_equal(back.collided, [True, False])
    assert np.abs(back.poses - poses).max() <= 0.005 + 1e-12
    with pytest.raises(ValueError):
        Trajectory(np.array([0]), np.array([False]), poses)  # T + 1 poses needed


def test_records_carry_the_per_step_trajectory(box_env):
    executed = []

    class Recorder(ExpertAgent):
        def act(self, obs, maps):
            executed.append(super().act(obs, maps))
            return executed[-1]

    rec = run_episode(box_env, Recorder(), episode_index=0, seed=0)
    back = EpisodeRecord.from_dict(json.loads(json.dumps(rec.to_dict())))
    traj = back.trajectory()
    assert list(traj.actions) == executed and len(traj.actions) == rec.steps
    assert int(traj.collided.sum()) == rec.collisions
    assert np.abs(traj.poses - np.array(box_env.trajectory)).max() <= 0.006
    assert EpisodeRecord.from_dict({**rec.to_dict(), "extra": {}}).trajectory() is None


# --- noise injection ------------------------------------------------------------------------------
class Replay:
    """Executes a given action sequence (to replay a noisy episode)."""

    def __init__(self, actions):
        self.actions = list(actions)

    def reset(self, env, obs, seed=0):
        self.t = 0

    def act(self, obs, maps):
        self.t += 1
        return self.actions[self.t - 1]


def test_noise_injection_keeps_expert_labels_and_repeats_from_the_seed(box_env):
    def noisy_run(seed):
        agent = NoisyAgent(ExpertAgent(), 0.4, box_env.task.actions)
        labels, executed = [], []

        def on_step(s):
            labels.append(agent.last_expert_action)
            executed.append(s.action)

        run_episode(box_env, agent, episode_index=1, seed=seed, on_step=on_step)
        return labels, executed, agent.noisy_steps

    labels, executed, noisy = noisy_run(5)
    assert noisy > 0 and labels != executed
    assert noisy_run(5) == (labels, executed, noisy)  # reproducible from the seed
    assert noisy_run(6)[1] != executed
    # every label is what the expert says in the state the noisy run reached: replay the executed actions
    # while an expert (told what was executed) labels each state
    expert = ExpertAgent()
    replay_labels = []

    class Labeller(Replay):
        def reset(self, env, obs, seed=0):
            super().reset(env, obs, seed)
            expert.reset(env, obs, seed)

        def act(self, obs, maps):
            replay_labels.append(expert.act(obs, maps))
            a = super().act(obs, maps)
            expert.executed(a)
            return a

    run_episode(box_env, Labeller(executed), episode_index=1, seed=5)
    assert replay_labels == labels
    assert "STOP" not in [box_env.task.actions[a] for a in executed]


def test_noisy_collection_records_labels_and_executed_actions(tmp_path):
    scene = tmp_path / "room"
    shutil.copytree(BOX_ROOM, scene)
    cfg = CollectConfig(scene_dirs=(str(scene),), episodes_per_bin=1, heldout_per_bin=0, noise=0.3)
    collect(tmp_path / "demos", cfg, tmp_path / "scenes", progress=False)
    manifest = json.loads((tmp_path / "demos" / "manifest.json").read_text())
    assert manifest["noise"] == 0.3 and "expert" not in manifest  # the default expert is not recorded
    data = DemoSet(tmp_path / "demos", "train")
    differs = sum(int((a["action"] != a["executed"]).sum()) for a in data.episodes)
    assert differs > 0
    assert all(m["success"] for m in data.metas)
    with pytest.raises(DataError, match="noise"):
        CollectConfig(noise=1.5)


# --- map dropout ----------------------------------------------------------------------------------
def _batch(n):
    i_u = torch.arange(n, dtype=torch.float32).reshape(1, n, 1, 1, 1).expand(1, n, 1, 2, 2).clone()
    i_cog = i_u.expand(1, n, 3, 2, 2).clone() * 10
    inp = PolicyInput(rgbd=torch.zeros(1, n, 4, 2, 2), goal=torch.zeros(1, n, 3, 2, 2), i_u=i_u, i_cog=i_cog)
    return Batch(inp, torch.zeros(1, n, dtype=torch.long), torch.zeros(1, n))


def test_map_dropout_swaps_whole_samples_reproducibly():
    b = _batch(64)
    assert swap_maps(b, np.random.default_rng(0), 0.0) is b
    out = swap_maps(b, np.random.default_rng(0), 0.5)
    src = out.inp.i_u[0, :, 0, 0, 0]
    assert torch.equal(out.inp.i_cog[0, :, :, 0, 0], src[:, None].expand(64, 3) * 10)  # I_u and I_cog move together
    moved = (src != torch.arange(64)).sum().item()
    assert 15 < moved < 50
    assert torch.equal(out.inp.rgbd, b.inp.rgbd)
    again = swap_maps(b, np.random.default_rng(0), 0.5)
    assert torch.equal(again.inp.i_u, out.inp.i_u)


# --- closed-loop selection -----------------------------------------------------------------------
def _rec(method, i, ok, coll=0, path=5.0):
    return EpisodeRecord(f"e{i}", "s", "easy", ok, 4.0, path if ok else 9.0, 0.0 if ok else 3.0, 0.5, 0.8,
                         collisions=coll, method=method)


def test_pick_best_prefers_success_then_spl_then_fewer_collisions():
    recs = {"step_000100": [_rec("step_000100", i, i < 3, coll=9) for i in range(4)],
            "step_000200": [_rec("step_000200", i, i < 2) for i in range(4)],
            "step_000300": [_rec("step_000300", i, i < 3, coll=1) for i in range(4)]}
    paths = {k: f"{k}.pt" for k in recs}
    ranked = pick_best(recs, paths, {k: int(k[5:]) for k in recs})
    assert [c.name for c in ranked] == ["step_000300", "step_000100", "step_000200"]
    assert isinstance(ranked[0], CandidateScore) and ranked[0].sr == 0.75
    with pytest.raises(DataError, match="other episodes"):
        pick_best({"a": recs["step_000100"], "b": recs["step_000200"][:2]}, {"a": "", "b": ""}, {"a": 1, "b": 2})


def test_closed_loop_selection_runs_snapshots_and_copies_the_winner(tmp_path, box_scene, box_episodes):
    """Two "snapshots" of a run — the expert-like checkpoint is faked by two real tiny policies; the one with
    the higher SR on the selection episodes becomes best.pt."""
    from nue.policy import build_model
    from nue.policy.checkpoint import policy_meta, save_checkpoint
    from nue.policy.config import get_model_config
    from nue.sim.task import get_task
    from nue.nerf.config import get_memory

    scene = tmp_path / "scenes" / "room"
    shutil.copytree(BOX_ROOM, scene)
    (tmp_path / "sel").mkdir()
    save_episodes(tmp_path / "sel" / "room.json", box_episodes[:1], "paper")
    task = get_task("paper")
    cfg = get_model_config("fr").for_task(task)
    meta = policy_meta(task, get_memory("fast"), cfg, {"room": box_scene.content_hash})
    torch.manual_seed(0)
    good, bad = build_model(cfg), build_model(cfg)
    with torch.no_grad():  # "good" always drives forward toward ... whatever is ahead; "bad" always turns
        for m, a in ((good, 0), (bad, 1)):
            last = m.policy[-1]
            last.weight.zero_()
            last.bias.copy_(torch.tensor([-50.0, -50.0, -50.0]))
            last.bias[a] = 50.0
    run = tmp_path / "run"
    save_checkpoint(run / "snapshots" / "step_000010.pt", {**meta, "model_state": bad.state_dict(), "step": 10})
    save_checkpoint(run / "snapshots" / "step_000020.pt", {**meta, "model_state": good.state_dict(), "step": 20})
    # the episode's goal must be straight ahead for "always forward" to succeed: check and rely on it
    env = ImageNavEnv(box_scene, "paper", box_episodes[:1])
    fwd = run_episode(env, Replay([0] * 800), episode_index=0, seed=0)
    ranked = select_checkpoint(run, SelectConfig(episodes_dir=str(tmp_path / "sel"), scenes_root=str(tmp_path / "scenes"),
                                                 candidates=2, max_steps=60), progress=False)
    assert {c.name for c in ranked} == {"step_000010", "step_000020"}
    assert ranked[0].sr >= ranked[1].sr
    if fwd.success:
        assert ranked[0].name == "step_000020"
    best = torch.load(run / "best.pt", weights_only=True)
    winner = torch.load(ranked[0].path, weights_only=True)
    assert all(torch.equal(best["model_state"][k], winner["model_state"][k]) for k in winner["model_state"])
    assert json.loads((run / "selection.json").read_text())["selected"] == ranked[0].name


# --- memory lag -----------------------------------------------------------------------------------
def test_memory_lag_delays_frames_by_k_steps(box_env):
    from nue.nerf.config import get_memory
    from nue.nerf.online import OnlineNeRF

    cfg = get_memory("fast")
    assert "lag" not in cfg.to_dict()  # dicts of configs from before the option are unchanged
    lagged_cfg = cfg.replace(lag=2)
    assert type(cfg).from_dict(lagged_cfg.to_dict()) == lagged_cfg
    cam = box_env.task.camera
    lagged, plain = OnlineNeRF(lagged_cfg, cam), OnlineNeRF(cfg, cam)
    obs, _ = box_env.reset(seed=0, options={"episode_index": 0})
    lagged.reset(0, obs["pose"], box_env.floor_z)
    plain.reset(0, obs["pose"], box_env.floor_z)
    frames = []
    for t in range(5):
        frames.append(obs)
        lagged.step(obs["rgb"], obs["depth"], obs["pose"], box_env.floor_z)
        if t >= 2:  # the plain memory gets frame t - 2 at step t
            f = frames[t - 2]
            plain.step(f["rgb"], f["depth"], f["pose"], box_env.floor_z)
        obs, *_ = box_env.step(1)
    assert lagged.replay_len == plain.replay_len == 3
    a = lagged.render_maps(obs["pose"], obs["depth"], box_env.floor_z)
    b = plain.render_maps(obs["pose"], obs["depth"], box_env.floor_z)
    assert torch.equal(a.i_u, b.i_u) and torch.equal(a.i_cog, b.i_cog)


@pytest.mark.parametrize("kind", ["geodesic", "explore"])
def test_both_experts_label_dagger_rollouts_under_noise(box_env, kind):
    """DAgger's mix (policy + expert) wrapped in noise injection, with either expert: labels are the expert's,
    the executed actions differ from them somewhere, and the expert finishes the episode."""
    from nue.policy import build_model
    from nue.policy.agent import MixedAgent, PolicyAgent
    from nue.policy.config import get_model_config

    torch.manual_seed(0)
    policy = PolicyAgent(build_model(get_model_config("fr").for_task(box_env.task)))
    mixed = MixedAgent(policy, ExpertAgent(kind=kind), beta=0.5, policy_steps=15)
    agent = NoisyAgent(mixed, 0.3, box_env.task.actions)
    pairs = []
    rec = run_episode(box_env, agent, episode_index=1, seed=2,
                      on_step=lambda s: pairs.append((agent.last_expert_action, mixed.last_expert_action, s.action)))
    assert rec.success
    assert all(a == b for a, b, _ in pairs)
    assert any(a != c for a, _, c in pairs)


def test_training_for_closed_loop_selection_needs_the_selector(tmp_path):
    """Training does not import the evaluation that selection runs: a closed-loop run without a selector
    (``nue.selection.select_run``) is refused before anything is read or written."""
    from nue.errors import ConfigError
    from nue.train.bc import TrainConfig, train

    with pytest.raises(ConfigError, match="select_run"):
        train(TrainConfig(data=str(tmp_path / "none"), out=str(tmp_path / "run"), select="closed_loop"), progress=False)
    assert not (tmp_path / "run").exists()
