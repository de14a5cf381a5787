"""Lock-step batched episodes (``nue.rollout.lockstep``, ``nue eval --batch``): a freed slot is refilled by the next
job, batched agents get one call per step, batched and single runs of the same episodes and seeds agree, a killed
batched run resumes without losing or redoing an episode, and another batch size is refused on resume."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch

from nue.jobs import FAIL_AFTER_ENV
from nue.nerf.config import get_memory
from nue.nerf.slots import MemoryList
from nue.policy import build_model
from nue.policy.checkpoint import policy_meta, save_checkpoint
from nue.policy.config import get_model_config
from nue.rollout import EpisodeJob, lockstep, run_episodes
from nue.sim.env import ImageNavEnv
from nue.sim.episode_gen import EpisodeGenConfig, generate_episodes
from nue.sim.episodes import save_episodes
from nue.sim.task import get_task

from .conftest import FIXTURES, nue_here

TINY = get_memory("fast").replace(name="tiny", train_rays=32, iters_per_update=1)
"""A cheap memory for the checkpoints of these tests (the loop, not the memory, is under test)."""


# --- the loop -----------------------------------------------------------------------------------------
class StopAfter:
    """Turns left ``n - 1`` times, then STOPs (habitat preset: the episode ends after exactly ``n`` steps)."""

    def __init__(self, n: int):
        self.n = n

    def reset(self, env, obs, seed=0):
        self.t = 0

    def act(self, obs, maps):
        self.t += 1
        return 0 if self.t >= self.n else 2  # STOP, TURN_LEFT


class BatchedStopAfter(StopAfter):
    """The same with a batched method that logs each call: (slots' positions, rows)."""

    calls: list = []

    def batch_key(self):
        return "stop-after"

    @staticmethod
    def act_batch(agents, obs_list, maps_list, rows=0, positions=None):
        BatchedStopAfter.calls.append((list(positions), rows))
        return [StopAfter.act(a, o, m) for a, o, m in zip(agents, obs_list, maps_list)]


class CountingMemory:
    """A single memory that logs which slot it serves and what it is asked."""

    def __init__(self, slot: int, log: list):
        self.slot, self.log = slot, log

    def reset(self, seed, start_pose, floor_z):
        self.log.append(("reset", self.slot, seed))

    def render_maps(self, pose, depth, floor_z):
        self.log.append(("render", self.slot))
        return self.slot

    def step(self, rgb, depth, pose, floor_z):
        self.log.append(("step", self.slot))


@pytest.fixture(scope="module")
def habitat_envs(box_scene, box_nav, box_renderer):
    return [ImageNavEnv(box_scene, "habitat", navgrid=box_nav, renderer=box_renderer) for _ in range(2)]


def test_a_freed_slot_takes_the_next_job(habitat_envs):
    """5 jobs of 3, 8, 2, 5, 4 steps on 2 slots: job 2 starts in slot 0 when job 0 ends (step 3), job 3 in slot 0 at
    step 5, job 4 in slot 1 at step 8 (job 1's end); records come back in job order, episodes end in the order
    0, 2, 1, 3, 4 (at steps 3, 5, 8, 10, 12), and each step the memory is asked once for all running slots."""
    lengths = [3, 8, 2, 5, 4]
    took: list[tuple[int, int]] = []
    log: list = []
    memory = MemoryList([CountingMemory(0, log), CountingMemory(1, log)])
    seen_maps: list[tuple[int, int]] = []

    def job(i):
        def take(slot):
            took.append((i, slot))
            return EpisodeJob(habitat_envs[slot], StopAfter(lengths[i]), seed=10 + i, method=f"j{i}", slot_memory=True,
                              on_step=lambda s: seen_maps.append((i, s.maps)))
        return take

    ended = [index for index, _ in lockstep([job(i) for i in range(5)], slots=2, memory=memory)]
    assert ended == [0, 2, 1, 3, 4]
    assert took == [(0, 0), (1, 1), (2, 0), (3, 0), (4, 1)]
    assert dict(seen_maps[:2]) == {0: 0, 1: 1} and all(m == dict(took)[i] for i, m in seen_maps)  # each slot its own maps
    renders = [e for e in log if e[0] == "render"]
    assert len(renders) == sum(lengths)
    assert [e[2] for e in log if e[0] == "reset"] == [10, 11, 12, 13, 14]
    records = run_episodes([job(i) for i in range(5)], slots=2, memory=memory)
    assert [r.steps for r in records] == lengths and [r.method for r in records] == [f"j{i}" for i in range(5)]


def test_batched_agents_share_one_call_per_step(habitat_envs):
    """Agents with ``act_batch`` are asked together, in their slots' rows, the batch padded to the slot count."""
    BatchedStopAfter.calls = []
    lengths = [2, 4, 1]
    jobs = [lambda slot, n=n: EpisodeJob(habitat_envs[slot], BatchedStopAfter(n), seed=n) for n in lengths]
    records = run_episodes(jobs, slots=2)
    assert [r.steps for r in records] == lengths
    # steps 0-1: jobs 0 and 1; job 2 takes slot 0 at step 2 and ends there; step 3: job 1 alone
    assert BatchedStopAfter.calls == [([0, 1], 2), ([0, 1], 2), ([0, 1], 2), ([1], 2)]


def test_a_single_slot_calls_act_not_act_batch(habitat_envs):
    BatchedStopAfter.calls = []
    (record,) = run_episodes([EpisodeJob(habitat_envs[0], BatchedStopAfter(3), seed=1)], slots=1)
    assert record.steps == 3 and BatchedStopAfter.calls == []


def test_padded_batch_forward_matches_the_single_forward():
    """``PolicyAgent.act_batch``: each agent keeps its own state and generator; with a sampled (not greedy) policy
    the actions drawn in a padded batch of 4 equal those of each agent alone for 5 steps."""
    from nue.policy.agent import PolicyAgent

    task = get_task("habitat")
    cfg = get_model_config("nav_a3c").for_task(task)  # recurrent: its state must travel with each agent
    torch.manual_seed(0)
    model = build_model(cfg)
    rng = np.random.default_rng(0)
    h, w = task.camera.height, task.camera.width
    obs = [{"rgb": rng.integers(0, 255, (h, w, 3), dtype=np.uint8), "depth": rng.random((h, w, 1), dtype=np.float32) * 3,
            "goal": rng.integers(0, 255, (h, w, 3), dtype=np.uint8), "pose": np.zeros(3)} for _ in range(3)]
    single, batched = PolicyAgent(model), PolicyAgent(model)
    twins = [batched.twin() for _ in range(3)]
    alone = []
    for k in range(3):
        single.reset(None, obs[k], seed=k)
        alone.append([single.act(obs[k], None) for _ in range(5)])
    for k, a in enumerate(twins):
        a.reset(None, obs[k], seed=k)
    together = [PolicyAgent.act_batch(twins, obs, [None] * 3, rows=4, positions=[2, 0, 3]) for _ in range(5)]
    assert [list(x) for x in zip(*together)] == alone


# --- nue eval --batch -----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def episodes_dir(tmp_path_factory, box_scene, box_nav, box_renderer):
    d = tmp_path_factory.mktemp("episodes")
    eps = generate_episodes(box_scene, "paper", EpisodeGenConfig(per_bin=2), seed=4, navgrid=box_nav, renderer=box_renderer)
    save_episodes(d / "box_room.json", eps, "paper")  # 2 easy, 2 medium, 2 hard
    return d


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    t = get_task("paper")
    cfg = get_model_config("nue").for_task(t)
    torch.manual_seed(0)
    model = build_model(cfg)
    meta = policy_meta(t, TINY, cfg, {})
    return save_checkpoint(tmp_path_factory.mktemp("ckpt") / "nue.pt", {**meta, "model_state": model.state_dict(), "step": 0})


def _eval(checkpoint, episodes_dir, out, *extra, fail_after: int = 0, expert: bool = False):
    args = ["eval", *(["-c", "expert"] if expert else []), "-c", f"nue={checkpoint}", "--out", out, "--episodes-dir", episodes_dir, "--scenes-root", FIXTURES,
            "--max-steps", 16, *extra]
    return nue_here(*args, env={FAIL_AFTER_ENV: str(fail_after)} if fail_after else None)


def _records(path) -> dict[str, dict]:
    return {r["extra"]["key"]: r for r in map(json.loads, path.read_text().splitlines())}


def _actions(rec: dict) -> str:
    return rec["extra"]["trajectory"]["actions"]


def test_batched_and_single_runs_agree(tmp_path, checkpoint, episodes_dir):
    """4 episodes of the expert and of a (random) checkpoint on 3 slots (so slots are refilled; the expert's episodes
    end at different steps) against the plain loop, same seeds. Agreement asked: the same actions for the first 10
    steps of every episode and the same success and step count for every episode (on this CPU the records are
    identical but for the batch setting and the slot: a 3-row forward rounds differently from a 1-row one only in
    the last bits of a logit, too little to change the paper preset's argmax here)."""
    single, batched = tmp_path / "b1.jsonl", tmp_path / "b3.jsonl"
    assert _eval(checkpoint, episodes_dir, single, "--max-episodes", 4, expert=True).returncode == 0
    res = _eval(checkpoint, episodes_dir, batched, "--batch", 3, "--max-episodes", 4, expert=True)
    assert res.returncode == 0, res.stderr
    one, three = _records(single), _records(batched)
    assert one.keys() == three.keys() and len(one) == 8
    assert len({r["steps"] for r in one.values() if r["method"] == "expert"}) > 2  # unequal lengths
    for key, r in three.items():
        assert r["extra"]["settings"]["batch"] == 3 and "batch" not in one[key]["extra"]["settings"]
        assert r["extra"]["slot"] in (0, 1, 2)
        assert _actions(r)[:10] == _actions(one[key])[:10], key
        assert (r["success"], r["steps"]) == (one[key]["success"], one[key]["steps"]), key


def test_killed_batched_run_resumes_without_losing_or_redoing(tmp_path, checkpoint, episodes_dir):
    """Killed after 2 of 4 records (injected failure): the rerun writes exactly the other 2; the records equal an
    uninterrupted run's (trajectories, outcome)."""
    out, whole = tmp_path / "r.jsonl", tmp_path / "whole.jsonl"
    first = _eval(checkpoint, episodes_dir, out, "--batch", 3, "--max-episodes", 4, fail_after=2)
    assert first.returncode == 3, first.stderr
    assert len(out.read_text().splitlines()) == 2
    kept = out.read_text()
    second = _eval(checkpoint, episodes_dir, out, "--batch", 3, "--max-episodes", 4)
    assert second.returncode == 0, second.stderr
    lines = out.read_text().splitlines()
    assert out.read_text().startswith(kept) and len(lines) == 4 and len({json.loads(x)["extra"]["key"] for x in lines}) == 4
    assert _eval(checkpoint, episodes_dir, whole, "--batch", 3, "--max-episodes", 4).returncode == 0
    resumed, straight = _records(out), _records(whole)
    for key, r in straight.items():
        assert (_actions(resumed[key]), resumed[key]["success"]) == (_actions(r), r["success"]), key


def test_another_batch_size_is_refused_on_resume(tmp_path, checkpoint, episodes_dir):
    out = tmp_path / "r.jsonl"
    assert _eval(checkpoint, episodes_dir, out, "--batch", 2, "--max-episodes", 1).returncode == 0
    before = out.read_text()
    for other in ("3", "1"):  # 1: the key is left out of the new records' settings and still compared
        res = _eval(checkpoint, episodes_dir, out, "--batch", other, "--max-episodes", 1)
        assert res.returncode == 2 and "batch differ" in res.stderr and "Traceback" not in res.stderr, res.stderr
    assert out.read_text() == before
    again = _eval(checkpoint, episodes_dir, out, "--batch", 2, "--max-episodes", 1)  # the same settings: nothing to do
    assert again.returncode == 0 and out.read_text() == before


def test_cli_eval_batch_smoke(tmp_path, checkpoint, episodes_dir):
    """``nue eval --batch 2`` with the expert and a checkpoint: one record per (method, episode), the summary table."""
    out = tmp_path / "r.jsonl"
    res = nue_here("eval", "-c", "expert", "-c", f"nue={checkpoint}", "--batch", 2, "--max-episodes", 2, "--out", out,
                   "--episodes-dir", episodes_dir, "--scenes-root", FIXTURES, "--max-steps", 16)
    assert res.returncode == 0, res.stderr
    recs = list(_records(out).values())
    assert len(recs) == 4 and {r["method"] for r in recs} == {"expert", "nue"}
    assert all(r["extra"]["settings"]["batch"] == 2 and r["steps"] == len(r["extra"]["coverage"]) for r in recs)
    assert "## expert" in res.stdout and "## nue" in res.stdout
    bad = nue_here("eval", "-c", "expert", "--batch", 0, "--out", tmp_path / "x.jsonl", "--episodes-dir", episodes_dir,
                   "--scenes-root", FIXTURES)
    assert bad.returncode == 2 and "--batch" in bad.stderr


def test_action_temperature():
    """softmax(logits / T): logits (0, 1, 0.5) give action 1 with probability e / (1 + e + e^0.5) = 0.507 at T = 1 and
    e^2 / (1 + e^2 + e) = 0.665 at T = 0.5; T = 0 is the argmax. 4,000 seeded draws each (standard error 0.008)."""
    from nue.policy.base import choose_actions

    logits = torch.tensor([[0.0, 1.0, 0.5]]).expand(4000, 3)
    for t, want in ((1.0, 0.5065), (0.5, 0.6652)):
        got = choose_actions(logits, generator=torch.Generator().manual_seed(0), temperature=t)
        assert float((got == 1).float().mean()) == pytest.approx(want, abs=0.03), t
    assert bool((choose_actions(logits, temperature=0.0) == 1).all())


def test_cli_eval_temperature_is_a_recorded_setting(tmp_path, checkpoint, episodes_dir):
    """``nue eval --temperature 0``: the policy's records store it (the expert's do not: it does not apply); a rerun at
    another temperature is refused; a negative one is a one-line error."""
    out = tmp_path / "r.jsonl"
    res = _eval(checkpoint, episodes_dir, out, "--temperature", 0, "--max-episodes", 1, expert=True)
    assert res.returncode == 0, res.stderr
    recs = {r["method"]: r for r in _records(out).values()}
    assert recs["nue"]["extra"]["settings"]["temperature"] == 0 and "temperature" not in recs["expert"]["extra"]["settings"]
    again = _eval(checkpoint, episodes_dir, out, "--temperature", 0.5, "--max-episodes", 1)
    assert again.returncode == 2 and "temperature differ" in again.stderr and "Traceback" not in again.stderr
    bad = _eval(checkpoint, episodes_dir, tmp_path / "x.jsonl", "--temperature", -1)
    assert bad.returncode == 2 and "--temperature" in bad.stderr and "Traceback" not in bad.stderr


def test_the_stacked_memory_drops_into_the_loop(box_scene, box_nav, box_renderer, episodes_dir):
    """The same 3 expert episodes on 2 slots with ``slot_memory(kind="stacked")`` and with the default list: the maps
    each episode is handed at each step agree within 1e-5 (the stacked memory's own tolerance)."""
    from nue.nerf.online import OnlineNeRF
    from nue.nerf.slots import slot_memory
    from nue.policy.agent import ExpertAgent

    from nue.sim.episodes import load_episodes

    small = TINY.replace(map_height=12, map_width=16)
    eps = load_episodes(episodes_dir / "box_room.json")
    envs = [ImageNavEnv(box_scene, dataclasses.replace(get_task("paper"), max_steps=8), eps, navgrid=box_nav,
                        renderer=box_renderer) for _ in range(2)]
    seen: dict[str, dict] = {"list": {}, "stacked": {}}
    for kind in seen:
        memory = slot_memory(OnlineNeRF(small, envs[0].task.camera), 2, kind)

        def job(i, kind=kind):
            return lambda slot: EpisodeJob(envs[slot], ExpertAgent(), seed=i, episode_index=i, slot_memory=True,
                                           on_step=lambda s: seen[kind].__setitem__((i, s.t), s.maps))
        run_episodes([job(i) for i in range(3)], slots=2, memory=memory)
    assert seen["list"].keys() == seen["stacked"].keys() and len(seen["list"]) > 10
    for key, a in seen["list"].items():
        b = seen["stacked"][key]
        assert float((a.i_u - b.i_u).abs().max()) <= 1e-5 and float((a.i_cog - b.i_cog).abs().max()) <= 1e-5, key
