"""The exploration -> exploitation hand-off (first in-view step, closest approach, failure split) on hand-built
distance series and on the box room, its recomputation from records (resumable, refusing stale lines), and the
exploration benchmark (coverage grows, runs to the step limit, resumes after a kill, refuses other settings)."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
from unittest import mock

import numpy as np
import pytest

from nue.evaluate.handoff import HANDOFF_KEY, Handoff, HandoffConfig, format_handoff_markdown, handoff, handoff_summaries
from nue.jobs import FAIL_AFTER_ENV, InjectedFailure
from nue.sim.episode_gen import EpisodeGenConfig, generate_episodes
from nue.sim.episodes import save_episodes

from .conftest import FIXTURES, nue_here


# -- pure hand-off on hand-built series ----------------------------------------------------------------------
def test_docstring_example_approached_then_lost():
    h = handoff([4, 3, 1.5, 2.5, 2.6], None, success=False)
    assert h == Handoff(first_seen_step=None, first_near_step=2, closest_geodesic=1.5, closest_step=2, steps_near=1,
                        search_steps=4, exploit_steps=0, outcome="found_then_lost")
    seen = handoff([4, 3, 1.5, 2.5, 2.6], 1, success=False)
    assert (seen.search_steps, seen.exploit_steps, seen.outcome) == (1, 3, "found_then_lost")


def test_failure_classes():
    # seen but never within 2 m: still found, then lost
    assert handoff([5, 4, 3.5, 4], 2, False).outcome == "found_then_lost"
    # within 3 m, never within 2 m, never seen
    h = handoff([5, 4, 2.8, 2.9, 4], None, False)
    assert (h.outcome, h.closest_geodesic, h.closest_step, h.first_near_step) == ("near_unseen", 2.8, 2, None)
    # started within 2 m and never saw the goal: not an approach
    h = handoff([1.8, 1.9, 2.4, 3.5], None, False)
    assert (h.outcome, h.first_near_step, h.steps_near) == ("near_unseen", 0, 2)
    # never within 3 m (inf = a pose the distance field does not reach)
    assert handoff([6, math.inf, 3.2, 5], None, False).outcome == "never_near"
    # other radii
    assert handoff([5, 4, 2.8, 2.9, 4], None, False, HandoffConfig(near=3.0)).outcome == "found_then_lost"


def test_success_phases():
    h = handoff([6, 5, 4, 2.5, 1.5, 0.7], 3, success=True)
    assert (h.outcome, h.search_steps, h.exploit_steps, h.closest_step) == ("success", 3, 2, 5)
    with pytest.raises(ValueError):
        handoff([], None, False)


def test_summary_counts_and_markdown():
    from nue.sim.record import EpisodeRecord

    def rec(method, success, h):
        return EpisodeRecord("e", "s", "easy", success, 5.0, 1.0, 1.0, 1.0, 0.8, method=method,
                             extra={HANDOFF_KEY: h.to_dict()})

    recs = [rec("a", True, handoff([4, 2, 0.5], 1, True)), rec("a", False, handoff([4, 1.5, 3], None, False)),
            rec("a", False, handoff([9, 8, 9], None, False)), rec("b", False, handoff([2.5, 2.6], None, False))]
    s = handoff_summaries(recs)
    assert list(s) == ["a", "b"]
    a = s["a"]
    assert (a.episodes, a.successes, a.seen) == (3, 1, 1)
    assert a.outcomes == {"success": 1, "found_then_lost": 1, "near_unseen": 0, "never_near": 1}
    assert (a.median_search_success, a.median_exploit_success, a.median_closest_lost) == (1.0, 1.0, 1.5)
    assert s["b"].outcomes["near_unseen"] == 1
    md = format_handoff_markdown(s)
    assert md.count("\n") == 4 and "| a | 3 | 2 | 1 | 0 | 1 | 1 |" in md


# -- in the box room ------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def two_houses(tmp_path_factory, box_scene, box_nav, box_renderer):
    """Two copies of the box room (``box_a``, ``box_b``) with one easy and one medium episode each."""
    root = tmp_path_factory.mktemp("houses")
    eps_dir = tmp_path_factory.mktemp("episodes")
    eps = generate_episodes(box_scene, "paper", EpisodeGenConfig(per_bin=1), seed=4, navgrid=box_nav,
                            renderer=box_renderer)[:2]
    for name in ("box_a", "box_b"):
        shutil.copytree(FIXTURES / "box_room", root / name)
        save_episodes(eps_dir / f"{name}.json", [dataclasses.replace(e, scene=name) for e in eps], "paper")
    return root, eps_dir


def test_goal_sight_tracker_matches_the_exploring_expert(box_scene):
    """In every step of an exploring-expert episode the tracker's test and the expert's own switch agree: the
    expert leaves explore mode at the step the tracker first sees the goal (unless its budget ran out first)."""
    from nue.evaluate.handoff import GoalSightTracker
    from nue.policy.agent import ExpertAgent
    from nue.rollout import run_episode
    from nue.sim.env import make_env

    env = make_env(box_scene, "paper")
    eps = generate_episodes(box_scene, "paper", EpisodeGenConfig(per_bin=1), seed=7, navgrid=env.navgrid,
                            renderer=env.renderer)
    checked = 0
    for ep in eps:
        agent, sight = ExpertAgent(kind="explore"), GoalSightTracker()
        run_episode(env, agent, episode=ep, on_step=sight)
        st = agent.expert.stats
        if st["switch"] == "goal_in_view":
            assert sight.first_seen_step == st["switch_step"]
            checked += 1
    assert checked >= 1


def test_eval_records_the_handoff_and_recomputation_agrees(tmp_path, two_houses):
    """``nue eval`` stores the hand-off; recomputed from the record's trajectory (re-rendered at the stored
    poses) it is the same; the hand-off file resumes after a kill and refuses a line of another run."""
    from nue.evaluate.diagnose import read_records
    from nue.evaluate.handoff_job import handoff_path, load_records_with_handoff, run_handoff, trajectory_digest

    root, eps_dir = two_houses
    out = tmp_path / "records.jsonl"
    res = nue_here("eval", "-c", "expert", "-c", "random", "--out", out, "--episodes-dir", eps_dir,
                   "--scenes-root", root, "--max-steps", 60)
    assert res.returncode == 0, res.stderr
    recs = read_records(out)
    assert len(recs) == 8 and all(HANDOFF_KEY in r.extra for r in recs)
    expert = [r for r in recs if r.method == "expert"]
    assert all(r.extra[HANDOFF_KEY]["outcome"] == "success" for r in expert)
    bare = tmp_path / "bare.jsonl"  # the same records as if made before the hand-off was measured
    bare.write_text("".join(json.dumps({**r.to_dict(), "extra": {k: v for k, v in r.extra.items() if k != HANDOFF_KEY}})
                            + "\n" for r in recs))
    with mock.patch.dict(os.environ, {FAIL_AFTER_ENV: "1"}), pytest.raises(InjectedFailure):
        run_handoff(read_records(bare), handoff_path(bare), eps_dir, root, progress=False)  # killed after one job
    assert len(handoff_path(bare).read_text().splitlines()) == 2
    run_handoff(read_records(bare), handoff_path(bare), eps_dir, root, progress=False)
    lines = [json.loads(x) for x in handoff_path(bare).read_text().splitlines()]
    assert len(lines) == 8 and len({x["key"] for x in lines}) == 8
    again = {r.extra["key"]: r.extra[HANDOFF_KEY] for r in load_records_with_handoff(bare)}
    for r in recs:
        live, redone = r.extra[HANDOFF_KEY], again[r.extra["key"]]
        assert redone["outcome"] == live["outcome"] and redone["closest_step"] == live["closest_step"]
        assert abs(redone["closest_geodesic"] - live["closest_geodesic"]) <= 0.02
        if live["first_seen_step"] is None:
            assert redone["first_seen_step"] is None
        else:  # poses are stored to 1 cm / 1 mrad: a boundary frame may flip
            assert abs(redone["first_seen_step"] - live["first_seen_step"]) <= 1
    lines[0]["trajectory"] = "0" * 16  # a line computed from another run of the episode
    assert lines[0]["trajectory"] != trajectory_digest(recs[0])
    handoff_path(bare).write_text("".join(json.dumps(x) + "\n" for x in lines))
    res = nue_here("report", bare, "--out", tmp_path / "rep")
    assert res.returncode == 2 and "bare.handoff.jsonl" in res.stderr and "another run" in res.stderr


def test_diagnose_prints_the_handoff(tmp_path, two_houses):
    root, eps_dir = two_houses
    out = tmp_path / "r.jsonl"
    assert nue_here("eval", "-c", "expert", "--out", out, "--episodes-dir", eps_dir, "--scenes-root", root,
                    "--max-steps", 60, "--max-episodes", 1).returncode == 0
    res = nue_here("diagnose", "--records", out)
    assert res.returncode == 0, res.stderr
    assert "hand-off" in res.stdout and "| expert | 2 | 0 | 0 | 0 | 0 |" in res.stdout
    per_bin = tmp_path / "per_bin.jsonl"  # --per-bin 1 keeps the first episode of each bin: both of them here
    assert nue_here("eval", "-c", "random", "--out", per_bin, "--episodes-dir", eps_dir, "--scenes-root", root,
                    "--max-steps", 5, "--per-bin", 1).returncode == 0
    assert len(per_bin.read_text().splitlines()) == 4
    old = tmp_path / "old.jsonl"  # a record made before trajectories were stored: skipped, said so
    rec = json.loads(out.read_text().splitlines()[0])
    rec["extra"] = {k: v for k, v in rec["extra"].items() if k not in ("trajectory", HANDOFF_KEY)}
    old.write_text(json.dumps(rec) + "\n")
    res = nue_here("diagnose", "--records", old, "--handoff", "--episodes-dir", eps_dir, "--scenes-root", root)
    assert res.returncode == 0, res.stderr
    assert "1 record(s) without a trajectory" in res.stdout
    assert not (tmp_path / "old.handoff.jsonl").is_file() or not (tmp_path / "old.handoff.jsonl").read_text()
    bad = nue_here("diagnose", "--records", out, "--handoff")
    assert bad.returncode == 2 and "--episodes-dir" in bad.stderr


# -- the exploration benchmark -----------------------------------------------------------------------------
def test_exploration_benchmark_runs_resumes_and_refuses_other_settings(tmp_path, two_houses):
    from nue.evaluate.diagnose import read_records
    from nue.evaluate.exploration import exploration_summary

    root, eps_dir = two_houses
    out = tmp_path / "explore.jsonl"
    args = ["explore", "-c", "expert-explore", "-c", "random", "--out", out, "--episodes-dir", eps_dir,
            "--scenes-root", root, "--steps", 50, "--per-bin", 1, "--reference", "random"]
    first = nue_here(*args, env={FAIL_AFTER_ENV: "3"})
    assert first.returncode == 3 and len(out.read_text().splitlines()) == 3
    second = nue_here(*args)
    assert second.returncode == 0, second.stderr
    recs = read_records(out)
    assert len(recs) == 8 and len({r.extra["key"] for r in recs}) == 8
    for r in recs:
        cov = np.asarray(r.extra["coverage"])
        assert r.steps == 50 and not r.success and len(cov) == 50  # success never ends a run
        assert np.all(np.diff(cov) >= 0) and r.extra["explorable_area"] > 0
        assert r.extra["settings"]["explore_only"] and r.extra["settings"]["goal_from"]
    ex = [r for r in recs if r.method == "expert-explore"]
    assert all(r.extra["coverage"][-1] > r.extra["coverage"][0] for r in ex)  # the explorer sees more as it goes
    rows = {row.method: row for row in exploration_summary(recs, reference="random")}
    assert rows["expert-explore"].area[50] > rows["random"].area[50] and rows["random"].ratio == {}
    assert 0 < rows["expert-explore"].fraction[50] <= 1.0
    assert "ratio to random" in second.stdout
    other = nue_here(*[a if a != 50 else 40 for a in args])
    assert other.returncode == 2 and "explore.jsonl" in other.stderr and "max_steps" in other.stderr
    one = nue_here("explore", "-c", "random", "--out", tmp_path / "x.jsonl", "--episodes-dir", FIXTURES / "nowhere")
    assert one.returncode == 2 and "Traceback" not in one.stderr


def test_exploration_summary_pools_training_seeds():
    """``m`` and ``m@s1`` are two seeds of one method: one row of the seeds' mean, its ratio to the reference over
    the starts both seeds ran (a start only seed 0 ran is left out)."""
    from nue.evaluate.exploration import exploration_summary, format_exploration_markdown
    from nue.sim.record import EpisodeRecord

    def run(method, ep, curve):
        return EpisodeRecord(ep, "s", "easy", False, 5.0, 1.0, 1.0, 1.0, 0.8, method=method,
                             extra={"coverage": curve, "coverage_explorable": curve, "explorable_area": 10.0})

    recs = [run("ref", e, [1.0, 2.0]) for e in "abc"]
    recs += [run("m", e, [2.0, 4.0]) for e in "abc"] + [run("m@s1", e, [2.0, 8.0]) for e in "ab"]
    rows = {r.method: r for r in exploration_summary(recs, reference="ref", steps=(1, 2))}
    m = rows["m"]
    assert (m.seeds, m.runs) == (2, 2) and m.area == {1: 2.0, 2: 6.0} and m.fraction[2] == pytest.approx(0.6)
    assert m.ratio[2][0] == pytest.approx(3.0) and m.ratio[2][1:] == (2.0, 4.0)  # seeds' mean 4, 6 or 8 m² / 2 m²
    assert rows["ref"].seeds == 1 and rows["ref"].ratio == {}
    assert "| m | 2 x 2 seeds |" in format_exploration_markdown(list(rows.values()), "ref")


def test_paired_outcome_differences():
    from nue.evaluate.handoff import format_outcome_differences, outcome_differences
    from nue.sim.record import EpisodeRecord

    def rec(method, ep, h):
        return EpisodeRecord(ep, "s", "easy", h.outcome == "success", 5.0, 1.0, 1.0, 1.0, 0.8, method=method,
                             extra={HANDOFF_KEY: h.to_dict()})

    never, lost, won = handoff([9, 9], None, False), handoff([4, 1], None, False), handoff([4, 0.5], 0, True)
    recs = [rec("nue", "a", won), rec("nue", "b", lost), rec("nue", "c", never), rec("nue", "d", won),
            rec("fr", "a", never), rec("fr", "b", never), rec("fr", "c", never), rec("fr", "d", lost)]
    diffs = {(d.method, d.outcome): d for d in outcome_differences(recs)}
    assert diffs[("fr", "never_near")].diff == pytest.approx((1 - 3) / 4)  # NUE 1 of 4, FR 3 of 4
    assert diffs[("fr", "found_then_lost")].diff == pytest.approx(0.0) and diffs[("fr", "never_near")].n == 4
    assert diffs[("fr", "never_near")].lo <= -0.5 <= diffs[("fr", "never_near")].hi
    assert "| fr | 4 | -50.0 [" in format_outcome_differences(list(diffs.values()))
    assert outcome_differences(recs, reference="nav_a3c") == []
    # a second FR seed (fr@s1) never near on every episode: pooled, FR's seed mean is (3/4 + 4/4) / 2 never near;
    # episode d, which fr@s1 did not run, drops out of the pooled difference (a, b, c: NUE 1/3, FR (3 + 3) / 6)
    recs += [rec("fr@s1", e, never) for e in "abc"]
    pooled = {(d.method, d.outcome): d for d in outcome_differences(recs)}
    assert set(pooled) == {("fr", "never_near"), ("fr", "found_then_lost")}
    nn = pooled[("fr", "never_near")]
    assert (nn.n, nn.seeds, nn.reference_seeds) == (3, 2, 1) and nn.diff == pytest.approx(1 / 3 - 1)
    assert nn.lo <= nn.diff <= nn.hi
    assert "| fr | 3 (2 x 1 seeds) | -66.7 [" in format_outcome_differences(list(pooled.values()))
