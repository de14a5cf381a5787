"""Demonstrations and behaviour cloning end to end on two tiny houses: collection round trip, kill and
resume, parallel / Ray equality, corrupt files, loss falling, resume = uninterrupted, DDP smoke."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from nue.errors import CheckpointError
from nue.jobs import FAIL_AFTER_ENV
from nue.nerf.config import MEMORY_PRESETS, get_memory
from nue.train.collect import CollectConfig, collect
from nue.train.dataset import DemoSet
from nue.train.compact import QuantizedArray
from nue.train.episode_file import read_episode_file, read_header

from .conftest import BOX_ROOM, nue_here

REPO = Path(__file__).resolve().parents[1]

MAP_KEYS = ("i_u", "i_cog")
TINY = get_memory("fast").replace(name="tiny", train_rays=32, iters_per_update=1)
"""The default memory with 1 iteration of 32 rays a step instead of 2 of 512 (its updates were 3/4 of a collection
step; the reference collection takes a third less time): the maps are training inputs here, their quality does
not matter, and the code path is the default's."""


@pytest.fixture(scope="module", autouse=True)
def _tiny_memory_preset():
    """``--memory tiny`` on the command line, for this module's tests (collections store the config itself,
    so workers, DAgger rounds and training read it from there)."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setitem(MEMORY_PRESETS, "tiny", TINY)
        yield


@pytest.fixture(scope="module")
def houses(tmp_path_factory):
    root = tmp_path_factory.mktemp("tiny_houses")
    dirs = []
    for name in ("room_a", "room_b"):
        shutil.copytree(BOX_ROOM, root / name)
        dirs.append(root / name)
    return dirs


def _cli(*args, fail_after: int = 0):
    """``nue ARGS`` in this process; ``fail_after``: stop after that many episode files (as if killed)."""
    return nue_here(*args, env={FAIL_AFTER_ENV: str(fail_after)} if fail_after else None)


def _files(root: Path) -> dict[str, Path]:
    return {str(p.relative_to(root)): p for p in sorted(root.glob("*/*/*.nue"))}


def _same_episode(a: Path, b: Path) -> None:
    xa, ma = read_episode_file(a, mmap=False, verify=True)
    xb, mb = read_episode_file(b, mmap=False, verify=True)
    assert ma["steps"] == mb["steps"] and set(xa) == set(xb)
    for k in xa:
        if k in MAP_KEYS:  # float noise between processes; a compact map may then round to the next code
            step = np.maximum(xa[k].scale, xb[k].scale)[..., None, None] if isinstance(xa[k], QuantizedArray) else 0
            assert (np.abs(np.asarray(xa[k], np.float32) - np.asarray(xb[k], np.float32)) <= 1e-2 + step).all(), k
        else:
            assert np.array_equal(xa[k], xb[k]), k


@pytest.fixture(scope="module")
def reference(houses, tmp_path_factory):
    """An uninterrupted single-process collection."""
    out = tmp_path_factory.mktemp("reference") / "demos"
    cfg = CollectConfig(scene_dirs=tuple(map(str, houses)), episodes_per_bin=1, heldout_per_bin=1, memory=TINY)
    collect(out, cfg, out.parent / "scenes", workers=1, progress=False)
    return out


@pytest.fixture(scope="module")
def demos(houses, tmp_path_factory):
    """The same collection through the CLI with 2 workers, killed after 3 episodes and rerun."""
    out = tmp_path_factory.mktemp("resumed") / "demos"
    args = ["collect", "--out", out, "--scenes-root", out.parent / "scenes", "--scene", houses[0], "--scene", houses[1],
            "--episodes-per-bin", 1, "--heldout-per-bin", 1, "--memory", "tiny", "--workers", 2]
    first = _cli(*args, fail_after=3)
    assert first.returncode == 3, first.stderr
    assert len(_files(out)) == 3
    second = _cli(*args)
    assert second.returncode == 0, second.stderr
    assert "12 episodes" in second.stdout
    return out


def test_collect_in_the_diverse_training_houses(tmp_path):
    """``--split train_diverse --houses 5`` generates that house and collects in it (stopped after one episode file,
    which is enough to show where it collected); the manifest names the split."""
    from nue.train.manifest import read_manifest

    out = tmp_path / "demos"
    res = _cli("collect", "--out", out, "--scenes-root", tmp_path / "scenes", "--split", "train_diverse", "--houses", 5,
               "--episodes-per-bin", 1, "--heldout-per-bin", 0, "--memory", "tiny", fail_after=1)
    assert res.returncode == 3, res.stderr
    assert [p.parent.name for p in _files(out).values()] == ["train_diverse_05"]
    manifest = read_manifest(out)
    assert manifest.split == "train_diverse" and list(manifest.scenes) == ["train_diverse_05"]
    assert (tmp_path / "scenes" / "train_diverse_05" / "house.json").exists()


def test_collection_round_trip(reference):
    files = _files(reference)
    assert len(files) == 12 and sum(k.startswith("heldout/") for k in files) == 6
    path = next(iter(files.values()))
    arrays, meta = read_episode_file(path, verify=True)
    t = meta["steps"]
    assert meta["success"] and t == len(arrays["action"]) > 0
    assert read_header(path)[0]["version"] == 2  # the compact format: 8-bit RGB-D, 4-bit I_cog, float16 I_u
    assert isinstance(arrays["rgbd"], QuantizedArray) and arrays["rgbd"].bits == 8
    assert isinstance(arrays["i_cog"], QuantizedArray) and arrays["i_cog"].bits == 4
    assert arrays["rgbd"].shape == (t, 4, 90, 120) and arrays["i_u"].dtype == np.float16
    assert arrays["i_u"].shape == (t, 1, 45, 60) and arrays["i_cog"].shape == (t, 64, 45, 60)
    assert float(arrays["i_cog"].lo.min()) >= 0 and arrays["goal_map"].shape == (3, 45, 60)
    assert arrays["goal_frame"].shape == (3, 90, 120) and arrays["pose"].shape == (t, 3)
    assert arrays["action"].dtype == np.int8 and set(np.unique(arrays["action"])) <= {0, 1, 2}
    assert np.array_equal(arrays["action"], arrays["executed"])  # expert collection: label = executed
    assert np.all(np.abs(arrays["goal_angle"]) <= np.pi)
    # the exploitation head's labels: in view only within the expert's 3 m view range; the distance is the pose's
    assert arrays["goal_in_view"].dtype == np.int8 and arrays["goal_in_view"].shape == (t,)
    assert np.all(arrays["goal_distance"][arrays["goal_in_view"] == 1] <= 3.0)
    assert arrays["goal_distance"][-1] < arrays["goal_distance"][0] and arrays["goal_distance"][-1] <= 0.8 + 0.25
    assert arrays["goal_in_view"][-1] == 1  # a successful expert ends looking at the goal's floor
    rgbd = np.asarray(arrays["rgbd"])
    assert rgbd.dtype == np.float32 and 0.0 <= float(rgbd[:, :3].min()) and float(rgbd.max()) <= 1.0
    summary = json.loads((reference / "summary.json").read_text())
    assert summary["bytes_per_step"] <= 150 * 1024, summary  # 428 KiB in float16


def test_killed_and_resumed_collection_equals_uninterrupted(demos, reference):
    a, b = _files(demos), _files(reference)
    assert sorted(a) == sorted(b)
    for key in a:
        _same_episode(a[key], b[key])


def test_ray_collection_equals_single_process(houses, reference, tmp_path, local_ray):
    out = tmp_path / "demos"
    cfg = CollectConfig(scene_dirs=(str(houses[0]),), episodes_per_bin=1, heldout_per_bin=0, memory=TINY)
    collect(out, cfg, tmp_path / "scenes", ray_address="auto", progress=False)
    got, ref = _files(out), _files(reference)
    assert sorted(got) == [k for k in sorted(ref) if k.startswith("train/room_a/")]
    for key, path in got.items():
        _same_episode(path, ref[key])


def test_float16_storage_collects_the_same_episodes_and_refuses_a_mixed_resume(houses, reference, tmp_path):
    out = tmp_path / "demos16"
    args = ["collect", "--out", out, "--scenes-root", tmp_path / "scenes", "--scene", houses[0],
            "--episodes-per-bin", 1, "--heldout-per-bin", 0, "--memory", "tiny", "--rgbd-bits", 0, "--i-cog-bits", 0]
    first = _cli(*args)
    assert first.returncode == 0, first.stderr
    assert json.loads((out / "storage.json").read_text()) == {"rgbd_bits": 0, "i_cog_bits": 0, "i_u_bits": 0}
    got, ref = _files(out), _files(reference)
    assert sorted(got) == [k for k in sorted(ref) if k.startswith("train/room_a/")]
    for key, path in got.items():
        x, _ = read_episode_file(path, mmap=False, verify=True)
        r, _ = read_episode_file(ref[key], mmap=False, verify=True)
        assert x["rgbd"].dtype == np.float16 and x["i_cog"].dtype == np.float16  # no QuantizedArray
        assert np.array_equal(x["action"], r["action"]) and np.array_equal(x["pose"], r["pose"])
        # the compact reference is within one 8-bit code of the float16 frame (its codes span [lo, lo + 255 scale])
        step = np.asarray(r["rgbd"].scale)[..., None, None]
        assert (np.abs(np.asarray(r["rgbd"], np.float32) - x["rgbd"].astype(np.float32)) <= step + 1e-3).all()
    second = _cli(*args[:-4])  # resumed with the default (compact) storage
    assert second.returncode == 2 and "storage.json" in second.stderr and "i_cog_bits" in second.stderr
    assert "Traceback" not in second.stderr


def test_corrupt_and_truncated_files_are_reported_and_skipped(reference, tmp_path):
    copy = tmp_path / "demos"
    shutil.copytree(reference, copy)
    files = list(_files(copy).values())
    train_files = [p for p in files if "/train/" in str(p)]
    data = bytearray(train_files[0].read_bytes())
    data[-100] ^= 0xFF
    train_files[0].write_bytes(bytes(data))
    train_files[1].write_bytes(train_files[1].read_bytes()[:5000])
    with pytest.warns(UserWarning) as caught:
        ds = DemoSet(copy, "train")
    messages = " ".join(str(w.message) for w in caught)
    assert train_files[0].name in messages and "checksum" in messages
    assert train_files[1].name in messages and "truncated" in messages
    assert ds.n_episodes == len(train_files) - 2
    assert {p for p, _ in ds.skipped} == {train_files[0], train_files[1]}


def _fixed_batch_loss(model_cfg_name, state_dict, data_dir):
    from nue.policy import build_model
    from nue.policy.config import get_model_config
    from nue.sim.task import get_task
    from nue.train.bc import bc_loss, class_weights

    ds = DemoSet(data_dir, "train")
    cfg = get_model_config(model_cfg_name).for_task(get_task("paper"))
    model = build_model(cfg)
    model.load_state_dict(state_dict)
    model.eval()
    eps = np.concatenate([np.full(n, e) for e, n in enumerate(ds.lengths)])
    steps = np.concatenate([np.arange(n) for n in ds.lengths])
    batch = ds.batch(eps[None], steps[None], cfg)
    with torch.no_grad():
        out = model.forward_sequence(batch.inp, None, torch.ones(batch.action.shape, dtype=torch.bool))
        return float(bc_loss(out, batch, class_weights(ds.action_counts(3), 0.5), 0.5)[0])


@pytest.mark.parametrize("precision", ["fp32", "bf16"])
def test_training_loss_falls(demos, tmp_path, precision):
    from nue.policy import build_model
    from nue.policy.checkpoint import load_checkpoint
    from nue.policy.config import get_model_config
    from nue.train.bc import TrainConfig, train

    torch.manual_seed(0)
    init = build_model(get_model_config("nue")).state_dict()
    res = train(TrainConfig(data=str(demos), out=str(tmp_path / "run"), steps=60, batch_size=16, warmup=5,
                            eval_every=30, lr=2e-3, precision=precision), progress=False)
    last = load_checkpoint(res.last)
    assert last["step"] == 60 and res.steps_this_call == 60
    before = _fixed_batch_loss("nue", init, demos)
    after = _fixed_batch_loss("nue", last["model_state"], demos)
    assert after < 0.7 * before, (before, after)
    assert "action_accuracy" in last["metrics"] and "angle_error_deg" in last["metrics"]
    assert list((tmp_path / "run" / "tb").glob("events.out.tfevents.*"))


def test_precision_defaults_to_auto_and_resolves_by_hardware(monkeypatch):
    """The default is ``auto``: bf16 autocast exactly where the CPU runs bfloat16 natively (oneDNN supports it and
    the CPU has the instructions), else fp32."""
    from nue.train import bc, hardware

    assert bc.TrainConfig().precision == "auto"
    cpu = torch.device("cpu")
    for onednn, native, want in ((True, True, "bf16"), (True, False, "fp32"), (False, True, "fp32")):
        monkeypatch.setattr(torch.ops.mkldnn, "_is_mkldnn_bf16_supported", lambda onednn=onednn: onednn)
        monkeypatch.setattr(hardware, "cpu_has_native_bf16", lambda native=native: native)
        assert bc.resolve_precision("auto", cpu) == want
        assert bc.resolve_precision("fp32", cpu) == "fp32" and bc.resolve_precision("bf16", cpu) == "bf16"


def test_native_bf16_is_read_from_the_cpu_flags_not_from_onednn():
    """oneDNN reports bf16 on any AVX512 CPU (emulated there, several times slower than fp32); only AVX512-BF16 or
    AMX-BF16 count."""
    from nue.train.hardware import cpu_has_native_bf16

    avx512 = "flags\t\t: fpu sse2 avx2 avx512f avx512bw avx512vl avx512_vnni\n"
    assert not cpu_has_native_bf16(avx512)
    assert cpu_has_native_bf16(avx512.replace("avx512_vnni", "avx512_vnni avx512_bf16"))
    assert cpu_has_native_bf16("flags : avx512f amx_tile amx_bf16 amx_int8")
    assert not cpu_has_native_bf16("flags : avx512f avx512bf16x")  # a whole flag, not a substring


def test_the_cpu_model_is_read_from_cpuinfo():
    from nue.train.hardware import cpu_model

    text = "processor\t: 0\nvendor_id\t: AuthenticAMD\nmodel name\t: AMD EPYC 7B13\nflags\t\t: fpu\n"
    assert cpu_model(text) == "AMD EPYC 7B13" and cpu_model("processor : 0\n") == ""


def test_a_non_finite_loss_stops_training_with_one_line(demos, tmp_path):
    from nue.errors import DataError
    from nue.train.bc import TrainConfig, train

    with pytest.raises(DataError, match=r"the training loss is (nan|inf) at step \d+ \(precision fp32, compile False\)"):
        train(TrainConfig(data=str(demos), out=str(tmp_path / "run"), model="fr", steps=20, batch_size=4, warmup=1,
                          eval_every=10, lr=1e30, precision="fp32"), progress=False)


def test_auto_precision_is_recorded_resolved_in_the_checkpoint(demos, tmp_path):
    from nue.policy.checkpoint import load_checkpoint
    from nue.train.bc import TrainConfig, resolve_precision, train

    res = train(TrainConfig(data=str(demos), out=str(tmp_path / "run"), steps=2, batch_size=4, warmup=1,
                            eval_every=2), progress=False)
    stored = load_checkpoint(res.last)["train_config"]
    assert stored["precision"] == "auto"
    assert stored["precision_resolved"] == resolve_precision("auto", torch.device("cpu")) in ("bf16", "fp32")


def test_resume_mismatches_names_changed_settings_and_data():
    from nue.policy.checkpoint import resume_mismatches

    stored = {"train_config": {"lr": 1e-3, "steps": 100, "out": "a", "precision": "fp32", "precision_resolved": "fp32",
                               "eval_houses": (0, 1), "old_field": 1}, "manifest_hash": "aaaa"}
    same = {"train_config": {"lr": 1e-3, "steps": 100, "out": "b", "precision": "auto", "precision_resolved": "fp32",
                             "eval_houses": [0, 1]}, "manifest_hash": "aaaa"}
    assert resume_mismatches(stored, same) == []  # another --out, auto resolving to the same, list vs tuple
    changed = {"train_config": {**same["train_config"], "lr": 2e-3, "precision_resolved": "bf16"}, "manifest_hash": "bbbb"}
    assert resume_mismatches(stored, changed) == ["lr 0.001 -> 0.002", "precision_resolved 'fp32' -> 'bf16'",
                                                  "training data (manifest aaaa -> bbbb)"]
    assert resume_mismatches({}, changed) == []  # a checkpoint that recorded nothing
    # every data folder's manifest, when the stored checkpoint recorded them (older ones: the first folder's only)
    two = {**same, "data": {"manifests": ["aaaa", "cccc"]}}
    assert resume_mismatches({**stored, "data": {"manifests": ["aaaa"]}}, two) == [
        "training data folders (manifests aaaa -> aaaa+cccc)"]
    assert resume_mismatches({**stored, "data": {"episodes": 3}}, two) == []
    assert resume_mismatches({**stored, "data": {"manifests": ["aaaa", "cccc"]}}, two) == []
    # the budget's clock matters only with a time budget
    clocked = {"train_config": {"time_budget_s": 0.0, "budget_clock": "wall"}}
    assert resume_mismatches(clocked, {"train_config": {"time_budget_s": 0.0, "budget_clock": "cpu"}}) == []
    assert resume_mismatches({"train_config": {"time_budget_s": 60.0, "budget_clock": "wall"}},
                             {"train_config": {"time_budget_s": 60.0, "budget_clock": "cpu"}}) == [
        "budget_clock 'wall' -> 'cpu'"]


@pytest.mark.slow
@pytest.mark.timeout(900)  # a cold inductor compile: ~30 s on 2 idle cores, over 300 s beside two busy evaluation workers
def test_compiled_training_computes_what_eager_training_computes(demos, tmp_path):
    """``compile=True`` (torch.compile, inductor) trains the same function: same batches, weights within float
    rounding of eager after 4 steps; and a run may switch it on resume (how, not what, is trained)."""
    from nue.policy import build_model
    from nue.policy.checkpoint import load_checkpoint
    from nue.policy.config import get_model_config
    from nue.train.bc import TrainConfig, train

    cfg = TrainConfig(data=str(demos), out=str(tmp_path / "eager"), model="fr", steps=4, batch_size=8, warmup=1,
                      eval_every=2, precision="fp32")
    eager = load_checkpoint(train(cfg, progress=False).last)
    res = train(cfg.replace(out=str(tmp_path / "compiled"), compile=True), progress=False)
    compiled = load_checkpoint(res.last)
    assert compiled["train_config"]["compile"] is True and res.step == 4
    for k, v in eager["model_state"].items():
        torch.testing.assert_close(compiled["model_state"][k], v, rtol=1e-3, atol=1e-4, msg=k)
    torch.manual_seed(cfg.seed)
    init = build_model(get_model_config("fr")).state_dict()
    assert max((eager["model_state"][k].float() - init[k].float()).abs().max() for k in init) > 1e-3  # it trained
    assert eager["rng_states"] == compiled["rng_states"] and eager["sampler_states"] == compiled["sampler_states"]
    assert train(cfg.replace(out=str(tmp_path / "compiled")), resume=True, progress=False).steps_this_call == 0


def test_compile_needs_a_cxx_compiler_on_cpu(monkeypatch):
    from nue.errors import ConfigError
    from nue.train import hardware

    monkeypatch.setattr(hardware.shutil, "which", lambda name: None)
    with pytest.raises(ConfigError, match="needs a C\\+\\+ compiler"):
        hardware.check_compile(torch.device("cpu"))
    monkeypatch.setattr(hardware.shutil, "which", lambda name: f"/usr/bin/{name}")
    hardware.check_compile(torch.device("cpu"))


def test_resumed_training_refuses_other_settings(demos, tmp_path):
    from nue.errors import CheckpointError
    from nue.train.bc import TrainConfig, train

    cfg = TrainConfig(data=str(demos), out=str(tmp_path / "run"), steps=2, batch_size=4, warmup=1, eval_every=2)
    train(cfg, progress=False)
    with pytest.raises(CheckpointError, match=r"other settings \(lr 0.001 -> 0.002\)"):
        train(cfg.replace(lr=2e-3), resume=True, progress=False)
    assert train(cfg.replace(select_workers=2), resume=True, progress=False).steps_this_call == 0
    second = tmp_path / "second"  # a second data folder (here a copy: same manifest) is other training data
    shutil.copytree(demos, second)
    with pytest.raises(CheckpointError, match=r"training data folders \(manifests (\w+) -> \1\+\1\)"):
        train(cfg.replace(data=f"{demos},{second}"), resume=True, progress=False)


def test_a_resume_point_of_another_model_is_refused():
    from nue.errors import CheckpointError
    from nue.policy.checkpoint import PolicyHeader, load_checkpoint, load_resumable
    from nue.policy.config import get_model_config

    path = REPO / "checkpoints" / "fr.pt"
    stored = load_checkpoint(path)
    model = PolicyHeader.from_dict(stored, path).model
    assert load_resumable(path, model, stored)["step"] == stored["step"]  # its own settings: resumable
    with pytest.raises(CheckpointError, match="fr.pt: was trained with another model config"):
        load_resumable(path, get_model_config("nav_a3c"), stored)
    lr = {**stored, "train_config": {**stored["train_config"], "lr": 0.5}}
    with pytest.raises(CheckpointError, match=rf"other settings \(lr {stored['train_config']['lr']} -> 0.5\)"):
        load_resumable(path, model, lr)


@pytest.mark.parametrize("model, extra", [("nav_a3c", {}), ("nue", {"map_dropout": 0.5, "buffer_episodes": 3}),
                                          ("nue_gru", {"map_dropout": 0.5})],
                         ids=["sequences", "buffers+map-dropout", "gru-sequences+map-dropout"])
def test_resume_continues_from_the_saved_step_and_matches(demos, tmp_path, model, extra):
    """Killed after the checkpoint at step 6 and resumed: bit-identical weights and optimiser state (for the
    reactive model the kill falls inside a shuffle buffer, so the sampler's position must be restored)."""
    from nue.jobs import InjectedFailure
    from nue.policy.checkpoint import load_checkpoint
    from nue.train.bc import TrainConfig, train

    cfg = TrainConfig(data=str(demos), out=str(tmp_path / "a"), model=model, steps=12, batch_size=4, seq_len=4,
                      warmup=2, eval_every=6, **extra)
    full = train(cfg, progress=False)
    os.environ["NUE_FAIL_AT_STEP"] = "6"
    try:
        with pytest.raises(InjectedFailure):
            train(cfg.replace(out=str(tmp_path / "b")), progress=False)
    finally:
        del os.environ["NUE_FAIL_AT_STEP"]
    assert load_checkpoint(tmp_path / "b" / "last.pt")["step"] == 6
    resumed = train(cfg.replace(out=str(tmp_path / "b")), resume=True, progress=False)
    assert resumed.step == 12 and resumed.steps_this_call == 6
    ca, cb = load_checkpoint(full.last), load_checkpoint(resumed.last)
    for k in ca["model_state"]:
        assert torch.equal(ca["model_state"][k], cb["model_state"][k]), k
    for sa, sb in zip(ca["optimizer"]["state"].values(), cb["optimizer"]["state"].values()):
        assert all(torch.equal(sa[k], sb[k]) for k in sa)
    assert ca["rng_states"] == cb["rng_states"] and ca["sampler_states"] == cb["sampler_states"]


def test_a_spent_time_budget_stays_spent_on_resume(demos, tmp_path):
    from nue.policy.checkpoint import load_checkpoint
    from nue.train.bc import TrainConfig, train

    cfg = TrainConfig(data=str(demos), out=str(tmp_path / "run"), model="fr", steps=50, batch_size=4, warmup=2,
                      eval_every=25, time_budget_s=1e-6)
    first = train(cfg, progress=False)
    assert first.steps_this_call == 1  # the budget ran out during the first step
    before = load_checkpoint(first.last)
    again = train(cfg, resume=True, progress=False)
    assert again.steps_this_call == 0 and again.step == 1
    after = load_checkpoint(again.last)
    assert all(torch.equal(before["model_state"][k], after["model_state"][k]) for k in before["model_state"])


def test_a_cpu_time_budget_counts_the_process_cpu_clock_not_the_wall_clock(demos, tmp_path, monkeypatch):
    """A fake CPU clock that advances 100 s per reading: the ``cpu`` budget of 450 s runs out at the third step
    (readings: start 0, then two per step, 100/200, 300/400, 500/600 >= 450), the ``wall`` one never."""
    import itertools

    from nue.train import bc

    readings = itertools.count(0.0, 100.0)
    monkeypatch.setattr(bc.time, "process_time", lambda: next(readings))
    cfg = bc.TrainConfig(data=str(demos), out="", model="fr", steps=6, batch_size=4, warmup=2, eval_every=25,
                         time_budget_s=450.0)
    wall = bc.train(cfg.replace(out=str(tmp_path / "wall")), progress=False)
    assert wall.step == 6 and wall.elapsed_s < 450.0
    cpu = bc.train(cfg.replace(out=str(tmp_path / "cpu"), budget_clock="cpu"), progress=False)
    assert (cpu.step, cpu.elapsed_s) == (3, 600.0)
    with pytest.raises(Exception, match="budget_clock"):
        cfg.replace(budget_clock="gpu")


def test_ddp_two_processes_gloo(demos, tmp_path):
    env = {**os.environ, "NUE_DDP_BACKEND": "gloo", "OMP_NUM_THREADS": "1"}
    res = subprocess.run([sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
                          "-m", "nue.cli", "train", "--data", str(demos), "--out", str(tmp_path / "ddp"), "--steps", "4",
                          "--batch-size", "8", "--eval-every", "2"], capture_output=True, text=True, env=env, timeout=240)
    assert res.returncode == 0, res.stderr[-3000:]
    from nue.policy.checkpoint import load_checkpoint

    assert load_checkpoint(tmp_path / "ddp" / "last.pt")["step"] == 4


def test_checkpoint_embeds_presets_and_refuses_mismatches(demos, tmp_path):
    from nue.policy.checkpoint import PolicyHeader, check_compatible, load_checkpoint, load_policy
    from nue.sim.task import get_task
    from nue.train.bc import TrainConfig, train
    from nue.train.manifest import read_manifest

    res = train(TrainConfig(data=str(demos), out=str(tmp_path / "run"), steps=2, batch_size=4, eval_every=2), progress=False)
    model, header = load_policy(res.best)
    assert header.task == "paper" and header.memory == TINY and header.model == model.config
    assert header.manifest_hash == read_manifest(demos).hash() and set(header.scenes) == {"room_a", "room_b"}
    ckpt = load_checkpoint(res.best)
    assert ckpt["memory_init"] and PolicyHeader.from_dict(header.to_dict()) == header
    assert {k: ckpt[k] for k in header.to_dict()} == header.to_dict()  # the file holds exactly the header's entries
    check_compatible(header, res.best, get_task("paper"), TINY, {"room_a": header.scenes["room_a"]})
    with pytest.raises(CheckpointError, match="trained for task preset 'paper'"):
        check_compatible(header, res.best, task=get_task("habitat"))
    with pytest.raises(CheckpointError, match="memory preset differs"):
        check_compatible(header, res.best, memory=get_memory("authors"))
    with pytest.raises(CheckpointError, match="scene room_a has content 0000"):
        check_compatible(header, res.best, scenes={"room_a": "0000000000000000"})


MAX_FACTOR = 1
"""Policy control of the DAgger rollouts below: at most 1 x the expert's steps (default 3 x), then the expert."""


def test_dagger_round_collects_policy_rollouts_labelled_by_the_expert(demos, houses, tmp_path):
    res = _cli("dagger", "--data", demos, "--out", tmp_path / "run", "--steps", 4, "--batch-size", 8, "--eval-every", 4,
               "--rounds", 1, "--round-steps", 2, "--max-factor", MAX_FACTOR, "--scene", houses[0], "--scene", houses[1],
               "--scenes-root", tmp_path / "scenes")
    assert res.returncode == 0, res.stderr[-2000:]
    rounds = json.loads((tmp_path / "run" / "dagger.json").read_text())
    assert [r["round"] for r in rounds] == [0, 1] and rounds[1]["beta"] == 0.5
    dagger_dir = tmp_path / "run" / "data_r1"
    manifest = json.loads((dagger_dir / "manifest.json").read_text())
    assert manifest["agent"]["kind"] == "dagger"
    files = _files(dagger_dir)
    assert len(files) == 6 and all(k.startswith("train/") for k in files)
    mixed = 0
    for path in files.values():
        arrays, meta = read_episode_file(path)
        mixed += int((arrays["action"] != arrays["executed"]).sum())
        expert_steps = read_episode_file(demos / path.relative_to(dagger_dir))[1]["steps"]
        assert meta["steps"] <= MAX_FACTOR * expert_steps + 200  # policy capped at 1x, then the expert finishes
    assert mixed > 0  # some executed actions were the policy's, labelled with the expert's
    from nue.policy.checkpoint import load_checkpoint

    assert load_checkpoint(tmp_path / "run" / "round_1" / "last.pt")["step"] == 2


def test_dagger_from_a_given_checkpoint_counts_rollouts_against_the_round_budget(demos, houses, tmp_path):
    from nue.policy.checkpoint import load_checkpoint
    from nue.train.bc import TrainConfig, train

    start = train(TrainConfig(data=str(demos), out=str(tmp_path / "bc"), steps=2, batch_size=4, eval_every=2),
                  progress=False).best
    res = _cli("dagger", "--data", demos, "--out", tmp_path / "run", "--batch-size", 8, "--eval-every", 1000,
               "--rounds", 1, "--round-steps", 1000, "--start", start, "--episodes-per-bin", 1, "--max-factor", MAX_FACTOR,
               "--time-budget", 0.01, "--scene", houses[0], "--scenes-root", tmp_path / "scenes")  # one house: 3 rollouts
    assert res.returncode == 0, res.stderr[-2000:]
    rounds = json.loads((tmp_path / "run" / "dagger.json").read_text())
    assert rounds[0]["given"] and rounds[0]["best"] == str(start) and not (tmp_path / "run" / "round_0").exists()
    # the rollouts used up the 0.6 s budget: retraining got its 1 s floor, far fewer than 1000 steps
    assert rounds[1]["rollout_seconds"] > 0.6 and 1 <= rounds[1]["train_steps"] < 1000
    manifest = json.loads((tmp_path / "run" / "data_r1" / "manifest.json").read_text())
    expert = json.loads((demos / "manifest.json").read_text())
    assert manifest["memory"] == expert["memory"] and manifest["subsample_per_bin"] == 1
    assert manifest["agent"]["checkpoint"] == str(start)
    assert load_checkpoint(tmp_path / "run" / "round_1" / "best.pt")["model_config"]["name"] == "nue"


def test_dagger_rolls_out_in_the_collections_layout(demos, houses):
    """DAgger's rollouts store what the expert collection stores: the trained model's layout when it reads it, else
    the first preset reading the collection's maps (a ``lean`` collection: ``nue_lean``; FR reads no maps); a layout
    no preset reads is a DataError naming the manifest."""
    import dataclasses

    from nue.errors import DataError
    from nue.policy.config import get_model_config
    from nue.sim.task import get_task
    from nue.train.dagger import collect_config_from_manifest, layout_model
    from nue.train.manifest import DataLayout, read_manifest

    manifest = read_manifest(demos)
    assert collect_config_from_manifest(manifest, houses).model == "nue"
    task = get_task(manifest.task)
    lean = dataclasses.replace(manifest, model_layout=DataLayout.of(get_model_config("nue_lean").for_task(task)))
    assert layout_model(lean, "nue_gru_lean") == "nue_gru_lean" and layout_model(lean, "abl_none_lean") == "abl_none_lean"
    assert layout_model(lean, "fr") == layout_model(lean, "nue") == "nue_lean"
    assert collect_config_from_manifest(lean, houses, model="fr").model == "nue_lean"
    odd = dataclasses.replace(manifest, model_layout=dataclasses.replace(manifest.model_layout, map_size=(7, 9)))
    with pytest.raises(DataError, match="m.json"):
        layout_model(odd, "nue", where="m.json")


def test_dagger_options_are_nue_daggers_and_nue_train_refuses_the_removed_spellings(monkeypatch, capsys, tmp_path):
    """``nue dagger`` builds the DAgger run from its options; ``nue train --dagger-*`` (deprecated, now removed; see
    docs/cli.md's changelog) stops with the one-line error of an unknown option, exit 2, before anything runs."""
    import nue.cli_learn
    from nue.cli import main

    runs = []
    monkeypatch.setattr(nue.cli_learn, "_run_dagger", lambda *args: runs.append(args))
    common = ["--data", str(tmp_path / "d"), "--out", str(tmp_path / "run"), "--steps", "7", "--time-budget", "2",
              "--scene", "a", "--scenes-root", str(tmp_path / "s"), "--workers", "2"]
    with pytest.raises(SystemExit) as stop:
        main(["dagger", *common, "--rounds", "3", "--round-steps", "5", "--beta", "0.3", "--episodes-per-bin", "1",
              "--start", "x.pt"])
    assert stop.value.code == 0
    (cfg, dagger, scene, scenes_root, workers, _), = runs
    assert (dagger.rounds, dagger.steps_per_round, dagger.beta0, dagger.episodes_per_bin, dagger.start_from) == (
        3, 5, 0.3, 1, "x.pt")
    assert dagger.round_budget_s == 120 and cfg.time_budget_s == 120 and cfg.steps == 7
    assert scene == [Path("a")] and scenes_root == tmp_path / "s" and workers == 2
    capsys.readouterr()
    for old in (["--dagger-rounds", "3"], ["--dagger-steps", "5"], ["--dagger-beta", "0.3"],
                ["--dagger-episodes-per-bin", "1"], ["--dagger-start", "x.pt"], ["--scene", "a"], ["--workers", "2"]):
        with pytest.raises(SystemExit) as stop:
            main(["train", "--data", str(tmp_path / "d"), "--out", str(tmp_path / "run2"), *old])
        err = capsys.readouterr().err.strip()
        assert stop.value.code == 2 and old[0] in err and "\n" not in err, err
    assert len(runs) == 1 and not (tmp_path / "run2").exists()


def test_subsample_keeps_the_first_episodes_of_each_bin():
    from types import SimpleNamespace

    from nue.train.collect import _first_per_bin

    eps = [SimpleNamespace(difficulty=d, episode_id=f"{d}_{i}") for d in ("easy", "medium") for i in range(3)]
    assert [e.episode_id for e in _first_per_bin(eps, 2)] == ["easy_0", "easy_1", "medium_0", "medium_1"]


@pytest.mark.parametrize("name", ["nue", "fr", "nav_a3c"])
def test_bf16_training_step_is_unchanged_by_casting_the_images_first(name, monkeypatch):
    """Under bf16, ``forward_loss`` hands the models rgbd and I_cog already in bfloat16 (half the bytes through
    the concatenations in front of the first convolutions; ~10% more NUE samples/s): the loss and every
    gradient must be bit for bit those of autocast casting them itself."""
    from nue.policy import PolicyInput, build_model
    from nue.policy.config import get_model_config
    from nue.sim.task import get_task
    from nue.train.bc import TrainConfig, class_weights
    from nue.train.step import forward_loss
    from nue.train.dataset import Batch

    cfg = get_model_config(name).for_task(get_task("paper"))
    g = torch.Generator().manual_seed(0)
    t, b = 2, 3
    inp = PolicyInput(rgbd=torch.rand(t, b, 4, *cfg.frame_size, generator=g),
                      goal=torch.rand(t, b, 3, *cfg.goal_size, generator=g),
                      i_u=torch.rand(t, b, 1, *cfg.map_size, generator=g) if cfg.uses_i_u else None,
                      i_cog=torch.randn(t, b, 64, *cfg.map_size, generator=g) if cfg.uses_i_cog else None)
    batch = Batch(inp, torch.randint(0, 3, (t, b), generator=g), torch.rand(t, b, generator=g) * 6 - 3)
    reset = torch.zeros(t, b, dtype=torch.bool)
    reset[0] = True
    torch.manual_seed(0)
    model = build_model(cfg)
    cpu = torch.device("cpu")
    cast_inp = inp.with_image_dtype(torch.bfloat16)  # what the bf16 path hands the model
    assert cast_inp.rgbd.dtype == torch.bfloat16 and cast_inp.goal.dtype == torch.float32
    results = []
    for cast in (True, False):
        if not cast:
            monkeypatch.setattr(PolicyInput, "with_image_dtype", lambda self, dtype: self)
        model.zero_grad()
        loss = forward_loss(model.forward_sequence, model, batch, reset, class_weights(np.ones(3), 0.5),
                            TrainConfig(precision="bf16"), cpu)[0]
        loss.backward()
        results.append((loss.detach(), {n: p.grad.clone() for n, p in model.named_parameters() if p.grad is not None}))
    (l1, g1), (l2, g2) = results
    assert torch.equal(l1, l2) and g1.keys() == g2.keys() and len(g1) > 10
    assert [n for n in g1 if not torch.equal(g1[n], g2[n])] == []


def test_panorama_model_collects_trains_and_acts(houses, tmp_path):
    """A memory preset with a panorama stores it per step; ``nue_pano`` trains on it and its agent acts in the loop
    with the checkpoint's memory; a model that reads a panorama refuses a collection without one."""
    from nue.errors import DataError
    from nue.policy.config import get_model_config
    from nue.rollout import run_episode
    from nue.sim.env import make_env
    from nue.train.bc import TrainConfig, train
    from nue.policy.checkpoint import load_agent

    pano_mem = TINY.replace(name="tiny_pano", panorama_headings=8)
    out = tmp_path / "demos"
    collect(out, CollectConfig(scene_dirs=(str(houses[0]),), episodes_per_bin=1, heldout_per_bin=0, memory=pano_mem,
                               model="nue_pano"), tmp_path / "scenes", workers=1, progress=False)  # in its own layout
    ep = DemoSet(out, "train").episodes[0]
    assert ep["panorama"].shape == (len(ep["action"]), 8, 6, 8) and float(np.asarray(ep["panorama"]).max()) > 0
    res = train(TrainConfig(data=str(out), out=str(tmp_path / "run"), model="nue_pano", steps=3, batch_size=4,
                            warmup=1, eval_every=3), progress=False)
    env = make_env(houses[0], "paper", max_steps=6)
    agent, memory = load_agent(res.last, env.task)
    rec = run_episode(env, agent, memory=memory, seed=0)
    assert rec.steps == 6 and agent.last_input.panorama.shape == (1, 8, 6, 8)
    plain = tmp_path / "plain"
    collect(plain, CollectConfig(scene_dirs=(str(houses[0]),), episodes_per_bin=1, heldout_per_bin=0, memory=TINY),
            tmp_path / "scenes", workers=1, progress=False)
    with pytest.raises(DataError, match="panorama"):
        DemoSet(plain, "train").check_layout(get_model_config("nue_pano"))


def test_goal_head_model_learns_its_labels_and_reports_them_at_decision_time(reference, houses, tmp_path):
    """``nue_goal`` trains its exploitation head on the collection's labels (its loss on the training steps falls)
    and the agent exposes the head's probability and distance after each act."""
    from nue.policy import build_model
    from nue.policy.checkpoint import load_agent, load_checkpoint
    from nue.policy.config import get_model_config
    from nue.rollout import run_episode
    from nue.sim.env import make_env
    from nue.sim.task import get_task
    from nue.train.bc import TrainConfig, goal_head_loss, train

    cfg = get_model_config("nue_goal").for_task(get_task("paper"))
    torch.manual_seed(0)
    init = build_model(cfg).state_dict()
    res = train(TrainConfig(data=str(reference), out=str(tmp_path / "run"), model="nue_goal", steps=40, batch_size=16,
                            warmup=5, eval_every=40, lr=2e-3), progress=False)

    def head_loss(state):
        ds = DemoSet(reference, "train")
        model = build_model(cfg)
        model.load_state_dict(state)
        model.eval()
        eps = np.concatenate([np.full(n, e) for e, n in enumerate(ds.lengths)])
        steps = np.concatenate([np.arange(n) for n in ds.lengths])
        batch = ds.batch(eps, steps, cfg)
        assert batch.goal_in_view is not None and 0 < float(batch.goal_in_view.mean()) < 1
        with torch.no_grad():
            return float(goal_head_loss(model(batch.inp), batch))

    last = load_checkpoint(res.last)
    before, after = head_loss(init), head_loss(last["model_state"])
    assert after < 0.7 * before, (before, after)
    assert {"goal_view_auroc", "goal_view_recall", "goal_log_distance_error"} <= set(last["metrics"])
    env = make_env(houses[0], "paper", max_steps=3)
    agent, memory = load_agent(res.last, env.task)
    run_episode(env, agent, memory=memory, seed=0)
    assert 0.0 <= agent.last_goal_view <= 1.0 and agent.last_goal_distance > 0.0


def test_flat_step_indices_locate_their_episode_and_a_fixed_sample_is_reproducible(demos):
    ds = DemoSet(demos, "train")
    first, second = int(ds.lengths[0]), int(ds.lengths[1])
    ep, st = ds.locate(np.array([0, first - 1, first, first + second - 1]))
    assert ep.tolist() == [0, 0, 1, 1] and st.tolist() == [0, first - 1, 0, second - 1]
    a, b = ds.sample_steps(5, seed=3), ds.sample_steps(5, seed=3)
    assert (a[0] == b[0]).all() and (a[1] == b[1]).all() and len(a[0]) == 5
    flat = ds.offsets[a[0]] + a[1]
    assert len(set(flat.tolist())) == 5 and (np.diff(flat) > 0).all()  # distinct, in order
    every = ds.sample_steps(len(ds) + 10, seed=0)  # asking for more than there are: every step once
    assert (ds.offsets[every[0]] + every[1]).tolist() == list(range(len(ds)))
