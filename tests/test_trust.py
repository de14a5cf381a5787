"""Trust boundaries: one writer per output (a second ``nue eval`` into the same file stops at once, a killed
writer's lock is taken over), readers refuse a records file holding a key twice, checkpoints are read as data
only (a crafted one is refused without running it; every shipped one loads so), and ``nue view`` listens on the
loopback unless told otherwise."""

from __future__ import annotations

import ipaddress
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from nue.errors import CheckpointError, OutputInUseError
from nue.output_lock import hold_output, lock_file
from nue.policy.checkpoint import FORMAT, load_checkpoint, plain_data_problem, save_checkpoint
from nue.sim.episode_gen import EpisodeGenConfig, generate_episodes
from nue.sim.episodes import save_episodes

from .conftest import BOX_ROOM, FIXTURES, nue_here

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def episodes_dir(tmp_path_factory, box_scene, box_nav, box_renderer):
    d = tmp_path_factory.mktemp("episodes")
    eps = generate_episodes(box_scene, "paper", EpisodeGenConfig(per_bin=1), seed=4, navgrid=box_nav, renderer=box_renderer)
    save_episodes(d / "box_room.json", eps[:2], "paper")
    return d


def _eval_args(out, episodes_dir) -> list:
    return ["eval", "-c", "expert", "--out", out, "--episodes-dir", episodes_dir, "--scenes-root", FIXTURES,
            "--max-steps", 12]


def _nue_process(*args) -> subprocess.CompletedProcess:
    """``nue ARGS`` as a process of its own (another writer than the test process)."""
    return subprocess.run([sys.executable, "-m", "nue.cli", *map(str, args)], capture_output=True, text=True,
                          env={**os.environ, "OMP_NUM_THREADS": "1"}, timeout=240)


# --- one writer per output ------------------------------------------------------------------------------
def test_a_second_eval_into_the_same_file_stops_at_once_and_each_episode_is_recorded_once(
        tmp_path, episodes_dir, monkeypatch):
    """The first evaluation runs in this process; right after its first record, a second ``nue eval`` into the
    same file is started as another process and must stop at once; the first then finishes."""
    from nue.evaluate import runner

    out = tmp_path / "same.jsonl"
    second = []
    append = runner.append_record

    def append_then_start_another(path, record):
        append(path, record)
        if not second:
            second.append((_nue_process(*_eval_args(out, episodes_dir)), out.read_text()))

    monkeypatch.setattr(runner, "append_record", append_then_start_another)
    first = nue_here(*_eval_args(out, episodes_dir))
    assert first.returncode == 0, first.stderr
    other, seen_by_other = second[0]
    assert other.returncode == 2, other.stderr
    assert other.stderr == f"error: {out}: in use by another nue process (pid {os.getpid()})\n"
    assert other.stdout == "" and len(seen_by_other.splitlines()) == 1  # it wrote nothing
    keys = [json.loads(line)["extra"]["key"] for line in out.read_text().splitlines()]
    assert len(keys) == 2 and len(set(keys)) == 2  # both episodes, each once
    assert not lock_file(out).exists()  # released


def _holder(output) -> subprocess.Popen:
    """Another process holding ``output``'s lock (until its stdin closes or it is killed); returns once it holds it."""
    proc = subprocess.Popen(
        [sys.executable, "-c", "import sys\nfrom nue.output_lock import hold_output\n"
         "with hold_output(sys.argv[1]):\n    print('held', flush=True)\n    sys.stdin.read()\n", str(output)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


def _kill(proc: subprocess.Popen) -> None:
    proc.kill()  # SIGKILL: no clean-up runs in it
    proc.wait()
    proc.stdout.close()
    proc.stdin.close()


def test_a_killed_writers_lock_is_taken_over(tmp_path):
    out = tmp_path / "run"
    holder = _holder(out)
    try:
        with pytest.raises(OutputInUseError) as err:
            with hold_output(out):
                pass
        assert str(err.value) == f"{out}: in use by another nue process (pid {holder.pid})"
    finally:
        _kill(holder)
    assert lock_file(out).read_text().strip() == str(holder.pid)  # left behind
    with hold_output(out) as lock:
        assert lock.took_over_from == holder.pid
        assert lock_file(out).read_text().strip() == str(os.getpid())
    assert not lock_file(out).exists()


def test_a_lock_file_naming_a_gone_process_is_taken_over_and_the_lock_is_reentrant(tmp_path):
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    pid = int(gone.stdout)
    out = tmp_path / "records.jsonl"
    lock_file(out).write_text(f"{pid}\n")
    with hold_output(out) as lock:
        assert lock.took_over_from == pid
        with hold_output(tmp_path / "." / "records.jsonl") as inner:  # the same output again, in this process
            assert inner is lock
        assert lock_file(out).exists()
    assert not lock_file(out).exists()


def test_every_resumable_writer_refuses_an_output_in_use(tmp_path, episodes_dir):
    """collect, train, dagger, select, reproduce, convert and explore stop with the one-line error before touching
    their output."""

    out = tmp_path / "busy"
    commands = {
        "collect": ["collect", "--out", out, "--scene", BOX_ROOM, "--episodes-per-bin", 1],
        "train": ["train", "--data", tmp_path / "no_data", "--out", out],
        "dagger": ["dagger", "--data", tmp_path / "no_data", "--out", out],
        "select": ["select", out],
        "reproduce": ["reproduce", "--quick", "--out", out],
        "convert": ["convert", tmp_path / "no_data", "--out", out],
        "explore": ["explore", "-c", "random", "--out", out, "--episodes-dir", episodes_dir, "--scenes-root", FIXTURES],
    }
    holder = _holder(out)
    try:
        for name, args in commands.items():
            res = nue_here(*args)
            assert res.returncode == 2, (name, res.stdout, res.stderr)
            assert res.stderr == f"error: {out}: in use by another nue process (pid {holder.pid})\n", name
    finally:
        _kill(holder)
    assert not out.exists()


# --- readers refuse a key recorded twice ----------------------------------------------------------------
@pytest.fixture(scope="module")
def duplicated_records(tmp_path_factory, episodes_dir):
    """A records file of two episodes whose first record appears twice (as two writers would leave it)."""
    d = tmp_path_factory.mktemp("dups")
    res = nue_here(*_eval_args(d / "once.jsonl", episodes_dir))
    assert res.returncode == 0, res.stderr
    lines = (d / "once.jsonl").read_text().splitlines()
    path = d / "twice.jsonl"
    path.write_text("\n".join([lines[0], lines[1], lines[0]]) + "\n")
    return path, json.loads(lines[0])["extra"]["key"]


def test_report_and_diagnose_refuse_duplicate_keys_or_drop_them_when_asked(tmp_path, duplicated_records):
    path, key = duplicated_records
    refusal = (f"error: {path}: record key {key!r} appears twice (lines 1 and 3); --drop-duplicates keeps the first "
               "record of each key\n")
    for args in (["report", path, "--out", tmp_path / "report"], ["diagnose", "--records", path]):
        res = nue_here(*args)
        assert (res.returncode, res.stderr) == (2, refusal), args
        kept = nue_here(*args, "--drop-duplicates")
        assert kept.returncode == 0, kept.stderr
        assert kept.stderr == f"{path}: dropped 1 duplicate record (kept the first of each key)\n"
    assert "| 2 |" in nue_here("diagnose", "--records", path, "--drop-duplicates").stdout  # 2 episodes, not 3


def test_view_refuses_duplicate_keys_or_replays_the_first(tmp_path, duplicated_records, episodes_dir):
    pytest.importorskip("rerun")
    path, key = duplicated_records
    args = ["view", "--records", path, "--key", key, "--scenes-root", FIXTURES, "--episodes", episodes_dir / "box_room.json",
            "--no-serve", "--save", tmp_path / "r.rrd"]
    res = nue_here(*args)
    assert res.returncode == 2 and res.stderr.startswith(f"error: {path}: record key {key!r} appears twice")
    assert res.stderr.count("\n") == 1
    kept = nue_here(*args, "--drop-duplicates")
    assert kept.returncode == 0, kept.stderr
    assert f"{path}: dropped 1 duplicate record" in kept.stdout and "replayed" in kept.stdout


# --- checkpoints are data -------------------------------------------------------------------------------
class _Marker:
    """Unpickling this object would create the file ``path`` (as a checkpoint carrying code could do anything)."""

    def __init__(self, path):
        self.path = str(path)

    def __reduce__(self):
        return open, (self.path, "w")


def test_a_checkpoint_that_would_run_code_is_refused_without_running_it(tmp_path, episodes_dir):
    marker = tmp_path / "marker"
    evil = tmp_path / "shared.pt"
    torch.save({"format": FORMAT, "model_config": {}, "payload": _Marker(marker)}, evil)
    with pytest.raises(CheckpointError) as err:
        load_checkpoint(evil)
    assert str(err.value).startswith(f"{evil}: refused: holds objects other than tensors and plain data")
    res = nue_here("eval", "-c", f"nue={evil}", "--out", tmp_path / "r.jsonl", "--episodes-dir", episodes_dir,
                   "--scenes-root", FIXTURES)
    assert res.returncode == 2 and res.stderr.startswith(f"error: {evil}: refused") and res.stderr.count("\n") == 1
    assert not marker.exists()
    torch.load(evil, weights_only=False)  # what nue must never do: the file does run code
    assert marker.exists()


def test_a_checkpoint_is_saved_as_plain_data_only(tmp_path):
    with pytest.raises(TypeError, match=r"train_config.out is a PosixPath"):
        save_checkpoint(tmp_path / "c.pt", {"train_config": {"out": tmp_path}})
    assert not (tmp_path / "c.pt").exists()
    import numpy as np

    assert plain_data_problem({"metrics": {"sr": np.float64(0.5)}}) == "metrics.sr is a float64, not plain data"
    assert plain_data_problem({"w": torch.zeros(2), "steps": [1, 2.0, "a", None, True], "t": (1,)}) == ""


SHIPPED = sorted(REPO.glob("checkpoints/*.pt")) + sorted(REPO.glob("results/**/*.pt"))


@pytest.mark.parametrize("path", SHIPPED, ids=[str(p.relative_to(REPO)) for p in SHIPPED])
def test_every_shipped_checkpoint_loads_as_data(path):
    ckpt = torch.load(path, map_location="cpu", weights_only=True)
    assert ckpt["format"] == FORMAT and plain_data_problem(ckpt) == ""
    assert load_checkpoint(path).keys() == ckpt.keys()


# --- the viewer listens on the loopback -----------------------------------------------------------------
def _free_port(host="127.0.0.1") -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def _other_address() -> str | None:
    """An IPv4 address of this machine on an interface other than the loopback (None if it has none)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(("192.0.2.1", 9))  # picks the interface of the default route; sends nothing
            address = s.getsockname()[0]
        except OSError:
            return None
    return None if ipaddress.ip_address(address).is_loopback or address == "0.0.0.0" else address


def _reachable(host: str, port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(5)
        return s.connect_ex((host, port)) == 0


def test_the_viewer_listens_on_the_loopback_only_by_default():
    pytest.importorskip("rerun")
    from nue.viz.view import Viewer, ViewConfig

    other = _other_address()
    if other is None:
        pytest.skip("this machine has no interface besides the loopback")
    cfg = ViewConfig(port=_free_port(), grpc_port=_free_port())
    viewer = Viewer(cfg, "loopback")
    try:
        assert not viewer.public and viewer.url.startswith(f"http://127.0.0.1:{cfg.port}/")
        assert _reachable("127.0.0.1", cfg.port) and _reachable("127.0.0.1", cfg.grpc_port)
        assert not _reachable(other, cfg.port) and not _reachable(other, cfg.grpc_port)
    finally:
        viewer.close()
    assert not _reachable("127.0.0.1", cfg.port) and not _reachable("127.0.0.1", cfg.grpc_port)

    opened = Viewer(ViewConfig(host=other, port=cfg.port, grpc_port=cfg.grpc_port), "network")
    try:
        assert opened.public and _reachable(other, cfg.port) and _reachable(other, cfg.grpc_port)
    finally:
        opened.close()


def test_ports_are_checked_on_the_chosen_interface_and_an_open_viewer_says_so(tmp_path, episodes_dir):
    pytest.importorskip("rerun")
    from nue.errors import ConfigError
    from nue.viz.view_server import check_port

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(ConfigError, match=f"port {port} is taken"):
            check_port(port, "--port")
        other = _other_address()
        if other is not None:
            check_port(port, "--port", other)  # free on that interface
    with pytest.raises(ConfigError, match="--host: 203.0.113.7 is not an address of this machine"):
        check_port(_free_port(), "--port", "203.0.113.7")
    res = nue_here("view", "--scene", BOX_ROOM, "--episodes", episodes_dir / "box_room.json", "--max-steps", 2,
                   "--host", "0.0.0.0", "--port", _free_port(), "--grpc-port", _free_port(), "--serve-seconds", 0.01)
    assert res.returncode == 0, res.stderr
    assert "are reachable from the network by anyone who can reach this machine" in res.stdout


def test_waiting_for_a_port_to_close_sees_a_listener_and_its_end():
    """What the viewer's close() waits on: a port still accepting connections is not closed (bounded wait gives
    up), a port whose listener has closed is."""
    from nue.viz.view_server import wait_port_closed

    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen()
    port = listener.getsockname()[1]
    try:
        assert wait_port_closed("127.0.0.1", port, timeout=0.0) is False
        assert wait_port_closed("0.0.0.0", port, timeout=0.0) is False  # every interface: probed on the loopback
    finally:
        listener.close()
    assert wait_port_closed("127.0.0.1", port, timeout=0.0) is True
