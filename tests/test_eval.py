"""``nue eval``: valid records for the expert and a policy checkpoint, resume after a kill without
duplicates, the swapped-maps control, and refusal of a mismatched checkpoint."""

from __future__ import annotations

import json

import pytest
import torch

from nue.jobs import FAIL_AFTER_ENV
from nue.nerf.config import get_memory
from nue.policy import build_model
from nue.policy.checkpoint import policy_meta, save_checkpoint
from nue.policy.config import get_model_config
from nue.sim.episode_gen import EpisodeGenConfig, generate_episodes
from nue.sim.episodes import save_episodes
from nue.sim.task import get_task

from .conftest import FIXTURES, nue_here


@pytest.fixture(scope="module")
def episodes_dir(tmp_path_factory, box_scene, box_nav, box_renderer):
    d = tmp_path_factory.mktemp("episodes")
    eps = generate_episodes(box_scene, "paper", EpisodeGenConfig(per_bin=1), seed=4, navgrid=box_nav, renderer=box_renderer)
    save_episodes(d / "box_room.json", eps[:2], "paper")  # one easy, one medium episode
    return d


def _checkpoint(path, task="paper", scenes=None):
    t = get_task(task)
    cfg = get_model_config("nue").for_task(t)
    torch.manual_seed(0)
    model = build_model(cfg)
    meta = policy_meta(t, get_memory("fast"), cfg, scenes or {})
    return save_checkpoint(path, {**meta, "model_state": model.state_dict(), "step": 0})


def _eval(*args, fail_after: int = 0):
    """``nue eval ARGS`` in this process; ``fail_after``: stop after that many records (as if killed)."""
    return nue_here("eval", *args, env={FAIL_AFTER_ENV: str(fail_after)} if fail_after else None)


def test_eval_writes_records_and_resumes_without_duplicates(tmp_path, episodes_dir):
    ckpt = _checkpoint(tmp_path / "nue.pt")
    out = tmp_path / "records.jsonl"
    args = ["-c", "expert", "-c", f"nue={ckpt}", "--out", out, "--episodes-dir", episodes_dir, "--scenes-root", FIXTURES,
            "--max-steps", 40]
    first = _eval(*args, fail_after=1)
    assert first.returncode == 3, first.stderr
    assert len(out.read_text().splitlines()) == 1
    with open(out, "a") as f:
        f.write('{"torn": ')  # a line cut by a kill mid-write
    second = _eval(*args)
    assert second.returncode == 0, second.stderr
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    keys = [r["extra"]["key"] for r in lines]
    assert len(lines) == 4 and len(set(keys)) == 4
    assert {r["method"] for r in lines} == {"expert", "nue"}
    for r in lines:
        assert r["difficulty"] in ("easy", "medium") and r["scene"] == "box_room"
        assert r["steps"] == len(r["extra"]["coverage"]) and r["extra"]["coverage"][-1] > 0
        assert r["wall_time"] > 0
    expert = [r for r in lines if r["method"] == "expert"]
    assert all(r["success"] for r in expert)
    assert "## expert" in second.stdout and "## nue" in second.stdout
    third = _eval(*args)  # nothing left to do
    assert third.returncode == 0 and len(out.read_text().splitlines()) == 4


def test_same_seeds_same_records(tmp_path, episodes_dir):
    from nue.evaluate.runner import EvalConfig, run_eval

    ckpt = _checkpoint(tmp_path / "nue.pt")
    cfg = EvalConfig(episodes_dir=str(episodes_dir), scenes_root=str(FIXTURES), coverage=False, max_episodes=1,
                     max_steps=40)
    recs = []
    for name in ("a", "b"):
        out = run_eval([f"nue={ckpt}"], tmp_path / f"{name}.jsonl", cfg, progress=False)
        recs.append(json.loads(out.read_text().splitlines()[0]))
    for k in ("success", "steps", "path_length", "final_geodesic", "collisions"):
        assert recs[0][k] == recs[1][k], k


def test_swap_maps_control_runs(tmp_path, episodes_dir):
    from nue.evaluate.runner import EvalConfig, run_eval

    ckpt = _checkpoint(tmp_path / "nue.pt")
    cfg = EvalConfig(episodes_dir=str(episodes_dir), scenes_root=str(FIXTURES), coverage=False, swap_maps=True,
                     max_episodes=2, max_steps=40)
    out = run_eval([f"nue={ckpt}"], tmp_path / "swap.jsonl", cfg, progress=False)
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    assert {r["method"] for r in lines} == {"nue+swap"} and len(lines) == 2


def test_mismatched_checkpoint_is_refused(tmp_path, episodes_dir):
    habitat = _checkpoint(tmp_path / "habitat.pt", task="habitat")
    res = _eval("-c", f"nue={habitat}", "--out", tmp_path / "r.jsonl", "--episodes-dir", episodes_dir,
                "--scenes-root", FIXTURES, "--max-steps", 40)
    assert res.returncode == 2 and "trained for task preset 'habitat'" in res.stderr and "Traceback" not in res.stderr
    stale = _checkpoint(tmp_path / "stale.pt", scenes={"box_room": "0123456789abcdef"})
    res = _eval("-c", f"nue={stale}", "--out", tmp_path / "r2.jsonl", "--episodes-dir", episodes_dir,
                "--scenes-root", FIXTURES, "--max-steps", 40)
    assert res.returncode == 2 and "scene box_room has content" in res.stderr


def test_resume_refuses_records_made_with_other_settings(tmp_path, episodes_dir):
    """A rerun into the same file with another checkpoint under the same name, or another step limit,
    is refused with one line naming the file; the same settings resume (nothing is rerun)."""
    a = _checkpoint(tmp_path / "a.pt")
    b = _checkpoint(tmp_path / "b.pt")
    state = torch.load(b, weights_only=True)
    state["step"] = 1  # another file under the same method name
    torch.save(state, b)
    out = tmp_path / "r.jsonl"
    common = ["--out", out, "--episodes-dir", episodes_dir, "--scenes-root", FIXTURES, "--max-episodes", 1]
    first = _eval("-c", f"nue={a}", *common, "--max-steps", 20)
    assert first.returncode == 0, first.stderr
    before = out.read_text()
    rec = json.loads(before.splitlines()[0])
    assert rec["extra"]["settings"]["max_steps"] == 20 and rec["extra"]["settings"]["task"] == "paper"
    for args, field in (([f"nue={a}", "--max-steps", 30], "max_steps"),
                        ([f"nue={b}", "--max-steps", 20], "agent")):
        res = _eval("-c", *args, *common)
        assert res.returncode == 2, res.stderr
        line = res.stderr.strip()
        assert "\n" not in line and str(out) in line and field in line and "Traceback" not in line
        assert out.read_text() == before  # nothing appended
    again = _eval("-c", f"nue={a}", *common, "--max-steps", 20)
    assert again.returncode == 0 and out.read_text() == before
