"""Diagnostics: record statistics by hand, the previous-action probe on synthetic maps, map controls, `nue diagnose`."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from nue.errors import DataError
from nue.evaluate import diagnose as D
from nue.evaluate import diagnose_maps as M
from nue.sim.record import EpisodeRecord, Trajectory

from .conftest import nue_here

F, L, R = 0, 1, 2  # the `paper` preset's action ids


def test_paper_action_ids():
    from nue.sim.task import get_task

    assert [get_task("paper").action_id(n) for n in ("MOVE_FORWARD", "TURN_LEFT", "TURN_RIGHT")] == [F, L, R]
    assert D.action_short_names("habitat") == ("stop", "forward", "left", "right")


def rec(actions, collided, method="nue", i=0, steps=None, collisions=None, trajectory=True):
    actions, collided = np.array(actions), np.array(collided, dtype=bool)
    poses = np.zeros((len(actions) + 1, 3))
    extra = {"trajectory": Trajectory(actions, collided, poses).encode()} if trajectory else {}
    return EpisodeRecord(episode_id=f"e{i}", scene="s", difficulty="easy", success=False, geodesic_start=2.0,
                         path_length=1.0, final_geodesic=1.0, final_euclidean=1.0, success_radius=0.8,
                         collisions=int(collided.sum()) if collisions is None else collisions,
                         steps=len(actions) if steps is None else steps, method=method, extra=extra)


# t:        0  1  2  3  4  5  6  7  8  9
EP1 = ([F, F, F, L, R, L, F, F, R, R],
       [0, 1, 1, 0, 0, 0, 0, 1, 0, 0])
# blocked at t = 1, 2, 7 -> steps 2, 3, 8 choose F, L, R: P(forward | blocked) = 1/3
# turns at t >= 1: 3 (after F), 4 (after L: reversal), 5 (after R: reversal), 8 (after F), 9 (after R): 2 / 5
EP2 = ([L, R, F], [0, 0, 1])  # the turn at t = 0 has no predecessor; t = 1 reverses it; the last block has no next step


def test_single_trajectory_by_hand():
    c = D.trajectory_counts(Trajectory(np.array(EP1[0]), np.array(EP1[1], bool), np.zeros((11, 3))))
    assert (c.steps, c.collisions, c.after_blocked, c.forward_after_blocked, c.turns, c.reversals) == (10, 3, 3, 1, 5, 2)
    assert (c.after_stuck, c.forward_after_stuck) == (3, 1)  # the poses never move: every blocked move is stuck
    assert c.blocked_again == 1  # step 2 after the blocked step 1
    cleared = D.trajectory_counts(Trajectory(np.array([F, F, F]), np.array([1, 0, 1], bool), np.zeros((4, 3))))
    assert (cleared.after_blocked, cleared.forward_after_blocked, cleared.blocked_again) == (1, 1, 0)  # forward, cleared
    assert c.action_counts == (5, 2, 3)


def test_stuck_is_a_blocked_move_that_barely_advanced():
    # forward step 0.25 m: step 1 slides 0.20 m (blocked, not stuck), step 2 advances 0.10 m (stuck, < 0.125),
    # step 7 does not move (stuck); the steps after them choose F, L, R
    moved = np.zeros(10)
    moved[[0, 1, 2, 5, 6]] = [0.25, 0.20, 0.10, 0.25, 0.25]
    poses = np.zeros((11, 3))
    poses[1:, 0] = np.cumsum(moved)
    c = D.trajectory_counts(Trajectory(np.array(EP1[0]), np.array(EP1[1], bool), poses))
    assert (c.after_blocked, c.forward_after_blocked) == (3, 1)
    assert (c.after_stuck, c.forward_after_stuck) == (2, 0)


def test_record_diagnostics_by_hand():
    recs = [rec(*EP1, i=0), rec(*EP2, i=1), rec([], [], i=2, steps=7, collisions=2, trajectory=False),
            rec([], [], method="fr", i=0, steps=10, collisions=1, trajectory=False)]
    d = D.record_diagnostics(recs)
    assert list(d) == ["fr", "nue"]  # table order
    nue = d["nue"]
    assert (nue.episodes, nue.steps, nue.collisions, nue.without_trajectory) == (3, 20, 6, 1)
    assert nue.collisions_per_episode == pytest.approx(2.0) and nue.collisions_per_step == pytest.approx(6 / 20)
    assert nue.p_forward_after_blocked == pytest.approx(1 / 3) and nue.p_blocked_again == pytest.approx(1 / 3)
    assert nue.turn_reversal_rate == pytest.approx(3 / 6)
    assert nue.action_fractions == pytest.approx({"forward": 6 / 13, "left": 3 / 13, "right": 4 / 13})
    fr = d["fr"]  # old records only: collisions from the record fields, the rest n/a
    assert fr.without_trajectory == 1 and fr.collisions_per_step == pytest.approx(0.1)
    assert np.isnan(fr.p_forward_after_blocked) and np.isnan(fr.turn_reversal_rate)
    md = D.format_record_diagnostics(d)
    assert "| FR | 1 | 10 | 1.00 | 0.100 | n/a | n/a | n/a | n/a | n/a | 1 |" in md
    assert "| NUE (full) | 3 | 20 | 2.00 | 0.300 | 33.3 | 33.3 (3) | 33.3 | 50.0 | 46.2 / 23.1 / 30.8 | 1 |" in md
    assert list(D.record_diagnostics(recs, methods=["NUE (full)"])) == ["nue"]
    js = D.to_jsonable(d)
    assert js["fr"]["p_forward_after_blocked"] is None and json.dumps(js, allow_nan=False)


def test_habitat_action_ids():
    shift = [[a + 1 for a in EP1[0]], EP1[1]]  # STOP = 0, forward 1, left 2, right 3
    d = D.record_diagnostics([rec(*shift)], task="habitat")["nue"]
    assert d.p_forward_after_blocked == pytest.approx(1 / 3) and d.turn_reversal_rate == pytest.approx(2 / 5)
    assert d.action_fractions["stop"] == 0.0 and d.action_fractions["forward"] == pytest.approx(0.5)


def test_report_section_shows_na_without_trajectories(tmp_path):
    from nue.evaluate.report import closed_loop_markdown
    from nue.evaluate.results_md import render_results_md

    text = render_results_md([rec([], [], trajectory=False, steps=4, collisions=1)], {"command": "x"})
    assert "## Closed-loop diagnostics" in text and "| NUE (full) | 1 | 4 | 1.00 | 0.250 | n/a | n/a | n/a | n/a | n/a | 1 |" in text
    assert "| 33.3 | 33.3 (3) | 33.3 | 40.0 |" in closed_loop_markdown([rec(*EP1)])


# --- map controls -------------------------------------------------------------------------------
def test_mirror_is_a_width_flip():
    x = np.arange(2 * 3 * 4 * 5).reshape(2, 3, 4, 5)
    assert np.array_equal(M.mirror_maps(x), np.flip(x, axis=-1))
    assert M.mirror_maps(x)[0, 0, 0, 0] == x[0, 0, 0, 4]


@pytest.mark.parametrize("n", [1, 2, 3, 5, 11, 12, 21, 100])
def test_other_step_never_the_same_step(n):
    rng = np.random.default_rng(n)
    for _ in range(20):
        idx = M.other_step_indices(n, rng)
        t = np.arange(n)
        assert idx.shape == (n,) and idx.min() >= 0 and idx.max() < n
        if n == 1:
            assert idx[0] == 0
            continue
        assert (idx != t).all()
        assert (np.abs(idx - t) >= np.minimum(10, np.maximum(t, n - 1 - t))).all()
    assert len(np.unique(M.other_step_indices(100, rng))) > 30  # drawn, not a fixed shift


def _write_demos(root, houses, eps, steps, cog, rng, encode=True, layout=None):
    from nue.train.episode_file import write_episode_file

    from nue.nerf.config import get_memory
    from nue.train.manifest import CollectionManifest, DataLayout, write_manifest

    fh, fw = 90, 120
    layout = layout or {"frame_size": [fh, fw], "map_size": [45, 60], "max_depth": 5.0, "cog_channels": cog}
    root.mkdir(parents=True)
    write_manifest(root, CollectionManifest(task="paper", memory=get_memory("fast"),
                                            model_layout=DataLayout.from_dict(layout), split="train",
                                            scenes={f"h{i}": "x" for i in range(houses)}, episodes_per_bin=eps,
                                            heldout_per_bin=eps, seed=0))
    for h in range(houses):
        for e in range(eps):
            executed = rng.choice(3, steps, p=[0.5, 0.25, 0.25]).astype(np.int8)
            i_u = rng.uniform(0, 0.3, (steps, 1, 45, 60))
            if encode:  # the edge just turned towards is newly seen: high uncertainty
                i_u[1:, 0, :, :10] += 2.0 * (executed[:-1] == L)[:, None, None]
                i_u[1:, 0, :, -10:] += 2.0 * (executed[:-1] == R)[:, None, None]
            arrays = {"rgbd": rng.uniform(0, 1, (steps, 4, fh, fw)).astype(np.float16), "i_u": i_u.astype(np.float16),
                      "i_cog": rng.normal(0, 1, (steps, cog, 45, 60)).astype(np.float16), "action": executed.copy(),
                      "executed": executed, "goal_angle": np.zeros(steps, np.float32), "pose": np.zeros((steps, 3), np.float32),
                      "goal_map": np.zeros((3, fh, fw), np.float16), "goal_frame": np.zeros((3, fh, fw), np.float16)}
            write_episode_file(root / "heldout" / f"h{h}" / f"e{e}.nue", arrays, {"scene": f"h{h}", "key": f"heldout/h{h}/e{e}"})
    return root


@pytest.fixture(scope="module")
def probe_demos(tmp_path_factory):
    return _write_demos(tmp_path_factory.mktemp("probe") / "demos", 4, 2, 60, 2, np.random.default_rng(0))


@pytest.fixture(scope="module")
def model_demos(tmp_path_factory):
    """Full-size inputs (2 houses x 1 episode x 12 steps) and a NUE and an FR checkpoint (random weights)."""
    from nue.policy import build_model, get_model_config
    from nue.policy.checkpoint import save_checkpoint

    tmp = tmp_path_factory.mktemp("model")
    root = _write_demos(tmp / "demos", 2, 1, 12, 64, np.random.default_rng(1))
    torch.manual_seed(0)
    paths = {}
    for name in ("nue", "fr"):
        cfg = get_model_config(name)
        paths[name] = save_checkpoint(tmp / f"{name}.pt", {"model_config": cfg.to_dict(),
                                                           "model_state": build_model(cfg).state_dict()})
    return root, paths


def test_probe_finds_the_previous_action_and_not_in_shuffled_maps(probe_demos):
    from nue.train.dataset import DemoSet

    p = M.previous_action_probe(DemoSet(probe_demos, "heldout"), seed=0)
    assert (p.steps, p.houses, p.classes) == (4 * 2 * 59, 4, (0, 1, 2))
    assert p.chance_balanced_accuracy == pytest.approx(1 / 3)
    assert p.maps.balanced_accuracy > 0.9 and p.maps.accuracy > 0.9
    assert abs(p.shuffled.balanced_accuracy - 1 / 3) < 0.12
    assert 0.4 < p.maps.majority_accuracy < 0.6
    small = M.previous_action_probe(DemoSet(probe_demos, "heldout"), seed=0, max_steps=100, with_cog=True)
    assert small.steps == 100 and small.features.endswith("+cog_norm")


def test_probe_on_maps_without_the_encoding_is_at_chance(tmp_path):
    from nue.train.dataset import DemoSet

    root = _write_demos(tmp_path / "d", 3, 2, 50, 2, np.random.default_rng(2), encode=False)
    assert abs(M.previous_action_probe(DemoSet(root, "heldout")).maps.balanced_accuracy - 1 / 3) < 0.12


def test_map_views_flip_and_remap_what_the_model_reads(model_demos):
    from nue.policy import get_model_config
    from nue.train.dataset import DemoSet

    data, cfg = DemoSet(model_demos[0], "heldout"), get_model_config("nue")
    ep, st = np.zeros(3, np.int64), np.array([0, 4, 11])
    orig = data.batch(ep, st, cfg).inp
    mir = M.with_maps(data, "mirrored").batch(ep, st, cfg).inp
    assert torch.equal(mir.i_u, orig.i_u.flip(-1)) and torch.equal(mir.i_cog, orig.i_cog.flip(-1))
    assert torch.equal(mir.rgbd, orig.rgbd)
    other = M.with_maps(data, "other_step", np.random.default_rng(0))
    idx = other.episodes[0]["i_u"].index
    assert (idx != np.arange(12)).all()
    assert torch.equal(other.batch(ep, st, cfg).inp.i_cog, data.batch(ep, idx[st], cfg).inp.i_cog)
    assert torch.equal(other.batch(ep, st, cfg).inp.rgbd, orig.rgbd)
    assert isinstance(data.episodes[0]["i_u"], np.ndarray)  # the original is untouched
    assert M.with_maps(data, "intact") is data


def test_map_controls(model_demos):
    from nue.train.dataset import DemoSet

    root, ckpts = model_demos
    data = DemoSet(root, "heldout")
    mc = M.map_controls(ckpts["nue"], data)
    assert mc.uses_maps and (mc.episodes, mc.steps) == (2, 24) and set(mc.accuracy) == set(M.CONDITIONS)
    assert all(0 <= v <= 1 for v in [*mc.accuracy.values(), *mc.balanced_accuracy.values()])
    fr = M.map_controls(ckpts["fr"], data)
    assert not fr.uses_maps and all(v is None for v in fr.accuracy.values())
    assert "n/a" in M.format_map_controls(fr)


def test_blocked_steps_from_poses():
    """Forward moves of 0.25 m but one of 0.1 m (slid along a wall) and one of 0 (stopped): the steps after
    those two are found; a turn that does not move is not a blocked move."""
    xy = [(0, 0), (0.25, 0), (0.35, 0), (0.35, 0), (0.35, 0), (0.60, 0), (0.85, 0)]
    executed = np.array([F, F, F, L, F, F, F], np.int8)  # step 3 turns (no move), step 6 is the last
    pose = np.array([(x, y, 0.0) for x, y in xy], np.float32)
    data = SimpleNamespace(episodes=[{"executed": executed, "pose": pose, "action": executed},
                                     {"action": np.array([F, F], np.int8), "pose": np.zeros((2, 3), np.float32)}])
    ep, st = M.blocked_steps(data, forward_step=0.25, forward=F)
    assert ep.tolist() == [0, 0, 1] and st.tolist() == [2, 3, 1]  # old collections without "executed": the labels


def test_after_blocked(model_demos):
    """The fixture's poses never move, so every step after an executed forward move is after a blocked one."""
    from nue.train.dataset import DemoSet

    root, ckpts = model_demos
    data = DemoSet(root, "heldout")
    want = [(e, t + 1) for e, a in enumerate(data.episodes) for t in range(len(a["action"]) - 1) if a["executed"][t] == F]
    labels = [data.episodes[e]["action"][t] == F for e, t in want]
    for name in ("nue", "fr"):
        ab = M.after_blocked(ckpts[name], data, forward_step=0.25)
        assert ab.steps == len(want) > 0 and ab.expert_forward == pytest.approx(np.mean(labels))
        assert 0 <= ab.policy_forward <= 1 and ab.policy_argmax_forward in {k / ab.steps for k in range(ab.steps + 1)}
    assert "| expert label forward % |" in M.format_after_blocked(ab)


# --- CLI ----------------------------------------------------------------------------------------
def assert_clean_error(res, *fragments):
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr + res.stdout
    line = res.stderr.strip()
    assert line.startswith("error: ") and "\n" not in line, line
    for frag in fragments:
        assert frag in line, line


def test_cli_diagnose_records(tmp_path):
    path, out = tmp_path / "r.jsonl", tmp_path / "d.json"
    recs = [rec(*EP1), rec(*EP2, i=1), rec([], [], method="fr", trajectory=False)]
    path.write_text("".join(json.dumps(r.to_dict()) + "\n" for r in recs))
    res = nue_here("diagnose", "--records", path, "--method", "nue", "--out", out)
    assert res.returncode == 0, res.stderr
    assert "| NUE (full) | 2 | 13 | 2.00 | 0.308 | 33.3 | 33.3 (3) | 33.3 | 50.0 |" in res.stdout and "| FR |" not in res.stdout
    assert json.loads(out.read_text())["records"]["nue"]["turns"] == 6
    bad = tmp_path / "bad.jsonl"
    bad.write_text(path.read_text() + "{not json\n")
    assert_clean_error(nue_here("diagnose", "--records", bad), str(bad), "line 4: not JSON")
    assert_clean_error(nue_here("diagnose", "--records", tmp_path / "missing.jsonl"), "missing.jsonl")
    broken = json.loads(path.read_text().splitlines()[0])
    broken["extra"]["trajectory"]["poses"] = "AAA"
    bad.write_text(json.dumps(broken) + "\n")
    assert_clean_error(nue_here("diagnose", "--records", bad), "line 1: bad trajectory")


def test_cli_diagnose_data_and_checkpoint(model_demos, tmp_path):
    from typer.testing import CliRunner

    from nue.cli import app
    from nue.errors import DataError

    root, ckpts = model_demos  # in-process: torch and scikit-learn are loaded already
    res = CliRunner().invoke(app, ["diagnose", "--data", str(root), "--checkpoint", str(ckpts["nue"]),
                                   "--out", str(tmp_path / "d.json")])
    assert res.exit_code == 0, res.output
    assert "## Map controls" in res.output and "| mirrored left-right |" in res.output
    assert "## Previous-action probe" in res.output
    js = json.loads((tmp_path / "d.json").read_text())
    assert set(js) == {"map_controls", "after_blocked", "probe"} and js["probe"]["houses"] == 2
    assert "## After a blocked move" in res.output and js["after_blocked"]["steps"] > 0
    one = _write_demos(tmp_path / "one", 1, 1, 5, 2, np.random.default_rng(3))
    res = CliRunner().invoke(app, ["diagnose", "--data", str(one)])
    assert res.exit_code == 0 and "n/a: the probe needs episodes from at least 2 houses" in res.output
    res = CliRunner().invoke(app, ["diagnose", "--data", str(tmp_path / "nowhere")])
    assert isinstance(res.exception, DataError) and "manifest" in str(res.exception)  # main() prints it, exit 2


def test_action_agreement_by_hand_and_on_the_command_line(tmp_path):
    # episode 0: the same 4 actions; episode 1: differs at step 2 (of 4); episode 2: b stops one step early;
    # episode 3: only a ran it
    a = [rec([F, F, L, R], [0] * 4, "m", 0), rec([F, L, L, F], [0] * 4, "m", 1), rec([F, F, F], [0] * 3, "m", 2),
         rec([F], [0], "m", 3)]
    b = [rec([F, F, L, R], [0] * 4, "m_b8", 0), rec([F, L, R, F], [0] * 4, "m_b8", 1), rec([F, F], [0] * 2, "m_b8", 2)]
    ag = D.action_agreement(a + b, "m", "m_b8", limit=3)
    # compared: 3 + 3 + 2 steps; differing: episode 1's step 2
    assert (ag.episodes, ag.steps, ag.identical) == (3, 8, 1) and ag.agreement == pytest.approx(7 / 8)
    assert ag.median_first_difference == 2.0  # episode 1 at step 2, episode 2 at its end (step 2)
    path = tmp_path / "r.jsonl"
    path.write_text("".join(json.dumps(r.to_dict()) + "\n" for r in a + b))
    res = nue_here("diagnose", "--records", path, "--agree", "m,m_b8", "--agree-steps", 3)
    assert res.returncode == 0, res.stderr
    assert "m vs m_b8: 87.5% of 8 steps (the first 3 of 3 episodes both ran)" in res.stdout
    assert_clean_error(nue_here("diagnose", "--records", path, "--agree", "m,nope"), "--agree", "'m,nope'")


def test_trajectory_decode_round_trips_and_refuses_actions_that_are_not_digits():
    t = Trajectory(np.array([0, 1, 2, 9]), np.array([0, 1, 0, 0], bool), np.zeros((5, 3)))
    d = t.encode()
    assert d["actions"] == "0129"
    back = Trajectory.decode(d)
    assert back.actions.tolist() == [0, 1, 2, 9] and back.collided.tolist() == [False, True, False, False]
    for actions in ("01x9", "01/9", "01\u06639"):  # a letter, the character before '0', an Arabic-Indic three
        with pytest.raises(ValueError):
            Trajectory.decode({**d, "actions": actions})


def test_read_records_reads_a_file_again_once_it_changed(tmp_path):
    """Parsed files are kept while unchanged; an appended record or a rewrite is read."""
    path = tmp_path / "r.jsonl"
    path.write_text(json.dumps(rec(*EP1).to_dict()) + "\n")
    assert len(D.read_records(path)) == 1
    with path.open("a") as f:
        f.write(json.dumps(rec(*EP2, i=1).to_dict()) + "\n")
    assert [r.episode_id for r in D.read_records(path)] == [rec(*EP1).episode_id, rec(*EP2, i=1).episode_id]
    path.write_text("{not json\n")
    with pytest.raises(DataError, match="line 1: not JSON"):
        D.read_records(path)
