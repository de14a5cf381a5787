"""Training resumes where it stopped: the shuffle-buffer sampler gives the same batches as an uninterrupted
iteration, and ``nue train`` killed with SIGKILL and rerun with ``--resume`` ends with the weights of an
uninterrupted run (checkpoints are written atomically: a temporary file, then ``os.replace``)."""

from __future__ import annotations

import dataclasses
import os
import signal
import subprocess
import sys
import time
import types

import numpy as np
import pytest
import torch

from nue.cli import main
from nue.nerf.config import get_memory
from nue.policy.checkpoint import load_checkpoint
from nue.train.collect import CollectConfig, collect
from nue.train.dataset import BufferSampler

from .conftest import BOX_ROOM


def test_buffer_sampler_state_round_trip_gives_the_same_batches():
    data = types.SimpleNamespace(n_episodes=7, lengths=np.random.default_rng(5).integers(1, 20, 7))
    full = BufferSampler(data, 4, np.random.default_rng(1), buffer_episodes=3)
    reference = [next(full) for _ in range(60)]
    cut = BufferSampler(data, 4, np.random.default_rng(1), buffer_episodes=3)
    head = [next(cut) for _ in range(13)]  # stop inside a buffer
    saved, rng_state = cut.state_dict(), cut.rng.bit_generator.state
    rng = np.random.default_rng(99)  # a fresh process: another generator, restored below
    rng.bit_generator.state = rng_state
    resumed = BufferSampler(data, 4, rng, buffer_episodes=3)
    resumed.load_state_dict(saved)
    tail = [next(resumed) for _ in range(47)]
    for (ea, sa), (eb, sb) in zip(reference, head + tail):
        assert np.array_equal(ea, eb) and np.array_equal(sa, sb)
    fresh = BufferSampler(data, 4, np.random.default_rng(1), buffer_episodes=3)
    fresh.rng.bit_generator.state = rng_state  # the generator alone is not enough
    assert any(not np.array_equal(next(fresh)[0], e) for e, _ in reference[13:20])


@pytest.fixture(scope="module")
def tiny_demos(tmp_path_factory):
    """Three expert episodes in the box room (one per difficulty), collected with a cheap memory (its maps
    are training inputs here, their quality does not matter)."""
    out = tmp_path_factory.mktemp("tiny_demos") / "demos"
    memory = dataclasses.replace(get_memory("fast"), name="tiny", train_rays=32, iters_per_update=1)
    cfg = CollectConfig(scene_dirs=(str(BOX_ROOM),), episodes_per_bin=1, heldout_per_bin=0, memory=memory)
    collect(out, cfg, out.parent / "scenes", workers=1, progress=False)
    return out


STEPS = 16
"""Optimiser steps of the runs below; the kill comes at the first checkpoint (step 2), long before the end."""


def _train_args(data, out) -> list[str]:
    return ["train", "--data", str(data), "--out", str(out), "--model", "nue", "--steps", str(STEPS),
            "--batch-size", "4", "--warmup", "2", "--eval-every", "2", "--map-dropout", "0.3"]


def _nue_in_process(args) -> int:
    try:
        main(args)
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else 1
    return 0


def _kill_at_first_checkpoint(args, out, log, deadline_s: float = 120.0) -> int:
    """Start ``nue *args`` as a process, SIGKILL it as soon as ``out/last.pt`` exists; the step of that file."""
    env = {**os.environ, "OMP_NUM_THREADS": "1"}  # as this process (conftest): the same float sums
    with open(log, "wb") as sink:
        proc = subprocess.Popen([sys.executable, "-m", "nue.cli", *args], stdout=sink, stderr=sink, env=env)
    try:
        deadline = time.monotonic() + deadline_s
        while not (out / "last.pt").exists():  # os.replace: the file appears whole
            assert proc.poll() is None, f"nue train ended (status {proc.returncode}) before a checkpoint: {log.read_text()[-2000:]}"
            assert time.monotonic() < deadline, f"no checkpoint after {deadline_s:g} s"
            time.sleep(0.005)  # polling interval
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == -signal.SIGKILL, (proc.returncode, log.read_text()[-2000:])
    return load_checkpoint(out / "last.pt")["step"]


@pytest.mark.timeout(300)
def test_kill_9_mid_training_then_resume_equals_an_uninterrupted_run(tiny_demos, tmp_path, capsys):
    full, cut = tmp_path / "full", tmp_path / "cut"
    assert _nue_in_process(_train_args(tiny_demos, full)) == 0, capsys.readouterr().err[-2000:]
    killed_at = _kill_at_first_checkpoint(_train_args(tiny_demos, cut), cut, tmp_path / "killed.log")
    assert 2 <= killed_at < STEPS  # killed mid-run, with steps left to resume
    assert _nue_in_process([*_train_args(tiny_demos, cut), "--resume"]) == 0, capsys.readouterr().err[-2000:]
    a, b = load_checkpoint(full / "last.pt"), load_checkpoint(cut / "last.pt")
    assert a["step"] == b["step"] == STEPS
    for k in a["model_state"]:
        assert torch.equal(a["model_state"][k], b["model_state"][k]), k
    for sa, sb in zip(a["optimizer"]["state"].values(), b["optimizer"]["state"].values()):
        assert all(torch.equal(sa[k], sb[k]) for k in sa)
    assert a["scheduler"] == b["scheduler"] and a["rng_states"] == b["rng_states"]
    assert a["sampler_states"] == b["sampler_states"]
    assert all(torch.equal(x, y) for x, y in zip(a["torch_rng_states"], b["torch_rng_states"]))


def test_exploit_weight_changes_training_and_is_recorded(tiny_demos, tmp_path, capsys):
    """``--exploit-weight 4`` (the in-view steps' action loss x 4): the same seed's weights come out otherwise than at
    1, the checkpoint records it (a run at 1 does not), a resume at another weight is refused, 0 is a usage error."""
    def args(out, *extra):
        return ["train", "--data", str(tiny_demos), "--out", str(out), "--model", "nue", "--steps", "4",
                "--batch-size", "4", "--warmup", "1", "--eval-every", "2", *extra]

    plain, weighted = tmp_path / "plain", tmp_path / "weighted"
    assert _nue_in_process(args(plain)) == 0, capsys.readouterr().err[-2000:]
    assert _nue_in_process(args(weighted, "--exploit-weight", "4")) == 0, capsys.readouterr().err[-2000:]
    a, b = load_checkpoint(plain / "last.pt"), load_checkpoint(weighted / "last.pt")
    assert "exploit_weight" not in a["train_config"] and b["train_config"]["exploit_weight"] == 4.0
    assert any(not torch.equal(a["model_state"][k], b["model_state"][k]) for k in a["model_state"])
    capsys.readouterr()
    assert _nue_in_process([*args(weighted, "--exploit-weight", "2"), "--resume"]) == 2
    assert "exploit_weight" in capsys.readouterr().err
    assert _nue_in_process(args(tmp_path / "zero", "--exploit-weight", "0")) == 2
    assert "--exploit-weight" in capsys.readouterr().err
