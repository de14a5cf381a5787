"""``nue view``: a replay reproduces a record's poses and finds the record's episode file by its digest, the seen
floor is drawn on the house's floor only, the exported .rrd opens with Rerun's reader and holds every view, a taken
port is a one-line error, and headless Chromium sees the scene (trajectory colour)."""

from __future__ import annotations

import dataclasses
import json
import os
import socket
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("rerun")

from nue.errors import DataError, EpisodeError
from nue.evaluate.eval_job import RunSettings
from nue.policy.agent import ExpertAgent
from nue.rollout import run_episode
from nue.sim.env import ImageNavEnv
from nue.sim.episode_gen import EpisodeGenConfig, generate_episodes
from nue.sim.episodes import save_episodes
from nue.sim.task import get_task
from nue.viz.view import ReplaySource, ViewConfig, episode_files, find_episode, find_record, view
from nue.viz.view_scene import TRAJECTORY_COLOUR, EpisodeLogger, floor_cells
from nue.viz.view_shot import find_chromium, has_colour, png_pixels, shows_content

from .conftest import BOX_ROOM, FIXTURES, nue_here


@pytest.fixture(scope="module")
def episode_file(tmp_path_factory, box_scene, box_nav, box_renderer):
    path = tmp_path_factory.mktemp("view") / "box_room.json"
    eps = generate_episodes(box_scene, "paper", EpisodeGenConfig(per_bin=1), seed=4, navgrid=box_nav, renderer=box_renderer)
    save_episodes(path, eps[:1], "paper")
    return path, eps[0]


def _checkpoint(path):
    """An untrained NUE policy checkpoint for the paper preset (as tests/test_eval.py makes one)."""
    import torch

    from nue.nerf.config import get_memory
    from nue.policy import build_model
    from nue.policy.checkpoint import policy_meta, save_checkpoint
    from nue.policy.config import get_model_config

    task = get_task("paper")
    cfg = get_model_config("nue").for_task(task)
    torch.manual_seed(0)
    meta = policy_meta(task, get_memory("fast"), cfg, {})
    return save_checkpoint(path, {**meta, "model_state": build_model(cfg).state_dict(), "step": 0})


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("", 0))
        return s.getsockname()[1]


def _nue(*args, timeout=240):
    """``nue ARGS`` as a process of its own (a served page and its web server end with it; the runs that serve
    nothing use ``nue_here``)."""
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, "-m", "nue.cli", *map(str, args)], capture_output=True, text=True,
                          env=env, timeout=timeout)


def _column(path, entity: str, component: str):
    """(steps, values) of one component of one entity in an .rrd file, read with Rerun's own reader."""
    from rerun.chunk import RrdReader

    steps, values = [], []
    for chunk in RrdReader(path).stream():
        if chunk.entity_path != entity or chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        names = batch.schema.names
        col = next(n for n in names if n.endswith(component))
        steps += batch.column(names.index("step")).to_pylist()
        values += batch.column(names.index(col)).to_pylist()
    order = np.argsort(steps)
    return np.asarray(steps)[order], [values[i] for i in order]


def test_replay_reproduces_recorded_poses(tmp_path, box_scene, box_nav, box_renderer, episode_file):
    eps_path, ep = episode_file
    task = dataclasses.replace(get_task("paper"), max_steps=12)
    env = ImageNavEnv(box_scene, task, [ep], navgrid=box_nav, renderer=box_renderer)
    record = run_episode(env, ExpertAgent(), episode=ep, method="expert")
    live_poses = env.trajectory_so_far().poses
    records = tmp_path / "records.jsonl"
    records.write_text(json.dumps(record.to_dict()) + "\n")
    key = f"expert/box_room/{ep.episode_id}"
    assert find_record([records], f"box_room/{ep.episode_id}").episode_id == ep.episode_id
    # the same run renamed as an earlier recipe's row (its key stays expert/...): the method picks one of the two
    renamed = tmp_path / "renamed.jsonl"
    keyed = {**record.to_dict(), "extra": {**record.to_dict()["extra"], "key": key}}  # as nue eval writes it
    renamed.write_text(json.dumps(keyed) + "\n" + json.dumps({**keyed, "method": "expert_v1"}) + "\n")
    assert find_record([renamed], f"expert_v1/box_room/{ep.episode_id}").method == "expert_v1"
    assert find_record([renamed], key).method == "expert"
    with pytest.raises(DataError, match="2 records"):
        find_record([renamed], f"box_room/{ep.episode_id}")

    rrd = tmp_path / "replay.rrd"
    view(ViewConfig(serve=False, save=str(rrd)),
         ReplaySource(records=(str(records),), key=key, scenes_root=str(FIXTURES), episodes=str(eps_path)), echo=lambda s: None)
    steps, translations = _column(rrd, "/world/robot", "translation")
    assert list(steps) == list(range(record.steps + 1))
    xy = np.array([t[0][:2] for t in translations])
    np.testing.assert_allclose(xy, record.trajectory().poses[:, :2], atol=1e-5)  # the record's poses, as logged
    np.testing.assert_allclose(xy, live_poses[:, :2], atol=0.006)  # = the run's poses to the record's 5 mm


def test_a_replay_finds_its_episode_file_by_digest(tmp_path, box_scene, box_nav, box_renderer, episode_file):
    """Two sets hold an episode ``easy_000`` of the house: the record's digest picks the one it was made on, whatever
    the order the sets are tried in; without a digest the first set holding the id is taken."""
    _, theirs = episode_file
    other = generate_episodes(box_scene, "paper", EpisodeGenConfig(per_bin=1), seed=5, navgrid=box_nav,
                              renderer=box_renderer)[0]
    digest = RunSettings.episode_digest
    assert other.episode_id == theirs.episode_id and digest(other) != digest(theirs)
    root = tmp_path / "episodes"
    save_episodes(root / "val" / "box_room.json", [other], "paper")
    save_episodes(root / "set2" / "box_room.json", [theirs], "paper")
    task = dataclasses.replace(get_task("paper"), max_steps=2)
    env = ImageNavEnv(box_scene, task, [theirs], navgrid=box_nav, renderer=box_renderer)
    plain = run_episode(env, ExpertAgent(), episode=theirs, method="expert")
    settings = {"episode": digest(theirs)}
    record = dataclasses.replace(plain, extra={**plain.extra, "settings": settings})
    for name, first in (("records.jsonl", "val"), ("records_set2.jsonl", "set2"), ("set2+swap.jsonl", "set2")):
        files = episode_files([tmp_path / name], "box_room", roots=(root,))
        assert files[0] == root / first / "box_room.json" and len(files) == 2
        found = find_episode(record, [tmp_path / name], box_scene, "paper", box_nav, roots=(root,))
        assert found == theirs
    assert find_episode(plain, [tmp_path / "records.jsonl"], box_scene, "paper", box_nav, roots=(root,)) == other
    (root / "set2" / "box_room.json").unlink()
    with pytest.raises(EpisodeError, match="digest .*tried .*val/box_room.json"):
        find_episode(record, [tmp_path / "records.jsonl"], box_scene, "paper", box_nav, roots=(root,))


def test_seen_floor_dots_stay_on_the_floor_map(tmp_path, box_scene, box_nav, box_renderer, episode_file):
    """The coverage measure counts cells at and just behind the foot of walls (a wall's bottom 5 cm pass as floor);
    the viewer draws only the seen cells on the floor map."""
    _, ep = episode_file
    task = dataclasses.replace(get_task("paper"), max_steps=12)
    env = ImageNavEnv(box_scene, task, [ep], navgrid=box_nav, renderer=box_renderer)
    rec = rerun_recording(tmp_path / "seen.rrd")
    log: list[EpisodeLogger] = []

    def on_step(s) -> None:
        if s.t == 0:
            log.append(EpisodeLogger(rec, task.camera, box_nav, env.floor_z))
        log[0].step(s.t, s.obs["pose"], s.obs["rgb"], s.obs["depth"])

    run_episode(env, ExpertAgent(), episode=ep, on_step=on_step)
    rec.flush()
    rec.disconnect()
    floor = floor_cells(box_nav)
    assert (log[0].seen & ~floor).any()  # what the measure counts off the floor map (the box room has some)
    _, dots = _column(tmp_path / "seen.rrd", "/world/seen", "positions")
    for points in dots:
        rc = box_nav.cell_of(np.asarray(points)[:, :2])
        assert floor[rc[:, 0], rc[:, 1]].all()


def rerun_recording(path):
    import rerun as rr

    rec = rr.RecordingStream("nue-test")
    rec.set_sinks(rr.FileSink(str(path)))
    return rec


def test_export_of_a_policy_run_opens_with_reader_and_holds_every_view(tmp_path, episode_file):
    from rerun.chunk import RrdReader

    eps_path, _ = episode_file
    rrd = tmp_path / "live.rrd"
    ckpt = _checkpoint(tmp_path / "nue.pt")
    run = nue_here("view", "--scene", BOX_ROOM, "--episodes", eps_path, "--max-steps", 6, "--checkpoint", ckpt,
                    "--no-serve", "--save", rrd)
    assert run.returncode == 0, run.stderr
    assert "nue: " in run.stdout and f"recording: {rrd}" in run.stdout
    entities = {c.entity_path for c in RrdReader(rrd).stream()}
    for e in ("world/house", "world/goal/position", "world/robot", "world/camera/rgb", "world/trajectory", "world/seen",
              "world/uncertainty", "frames/depth", "goal/photo", "memory/i_u", "memory/i_cog", "memory/rgb",
              "metrics/seen_m2"):
        assert "/" + e in entities, e
    steps, _ = _column(rrd, "/world/robot", "translation")
    assert steps[0] == 0 and len(steps) >= 2
    steps_u, _ = _column(rrd, "/world/uncertainty", "positions")
    assert len(steps_u) == len(steps) - 1  # maps at every step the policy acted, none after the last


def test_a_record_of_another_format_is_refused_naming_the_file(tmp_path):
    records = tmp_path / "rec.jsonl"
    records.write_text(json.dumps({"format": "nue-record/9", "method": "nue", "scene": "box_room", "episode_id": "3"}) + "\n")
    with pytest.raises(DataError, match="record format 'nue-record/9'") as err:
        find_record([records], "box_room/3")
    assert str(records) in str(err.value)


def test_taken_port_is_a_one_line_error(episode_file):
    eps_path, _ = episode_file
    with socket.socket() as s:
        s.bind(("0.0.0.0", 0))
        s.listen()
        port = s.getsockname()[1]
        run = nue_here("view", "--scene", BOX_ROOM, "--episodes", eps_path, "--port", port, "--grpc-port", _free_port())
    assert run.returncode == 2
    assert run.stderr.strip() == f"error: --port: port {port} is taken (another program listens there); choose another"


@pytest.mark.skipif(find_chromium() is None, reason="needs chromium (apt-get install chromium)")
@pytest.mark.timeout(600)
def test_headless_browser_sees_the_scene(tmp_path, episode_file):
    eps_path, _ = episode_file
    shot = tmp_path / "view.png"
    run = _nue("view", "--scene", BOX_ROOM, "--episodes", eps_path, "--max-steps", 15, "--port", _free_port(),
               "--grpc-port", _free_port(), "--screenshot", shot, "--screenshot-timeout", 400, timeout=580)
    assert run.returncode == 0, run.stderr
    assert "page ready after" in run.stdout
    pixels = png_pixels(shot.read_bytes())
    assert shows_content(pixels)
    assert has_colour(pixels, TRAJECTORY_COLOUR), "trajectory colour not on the page"
