"""Bad input of every kind ends in one line ``error: <file or option>: <problem>``, exit status 2, no
traceback, and nothing written: CLI arguments, output paths, checkpoints, record files, episode files.

The CLI runs in this process (``nue.cli.main(argv)``, the console entry point), so each case costs no
new interpreter; an unexpected exception fails the test just as a traceback would. A few cases also
run as real ``nue`` processes (the end of this file), to show the installed command behaves the same.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from nue.cli import main

from .conftest import BOX_ROOM, FIXTURES


def run_cli(capsys, *args) -> tuple[int, str, str]:
    """(exit status, stdout, stderr) of ``nue *args`` run in this process."""
    try:
        main([str(a) for a in args])
        code = 0
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    out = capsys.readouterr()
    return code, out.out, out.err


def assert_refused(capsys, args, *fragments, untouched=()):
    """``nue *args`` exits 2 with one line naming every fragment; the paths in ``untouched`` do not exist."""
    code, out, err = run_cli(capsys, *args)
    line = err.strip()
    assert code == 2, (code, out, err)
    assert "Traceback" not in err + out
    assert line.startswith("error: ") and "\n" not in line, err
    for frag in fragments:
        assert str(frag) in line, (frag, line)
    for p in untouched:
        assert not os.path.lexists(p), f"{p} was written"
    return line


# --- arguments ---------------------------------------------------------------------------------
@pytest.mark.parametrize("option, value", [("--workers", 0), ("--workers", -2), ("--max-episodes", -1), ("--max-steps", -5)])
def test_eval_counts_are_refused(capsys, tmp_path, option, value):
    out = tmp_path / "r.jsonl"
    assert_refused(capsys, ["eval", "-c", "expert", "--out", out, option, value], option, str(value), untouched=[out])


@pytest.mark.parametrize("value", [0, -3])
def test_per_bin_is_refused(capsys, tmp_path, value):
    out = tmp_path / "eps.json"
    assert_refused(capsys, ["episodes", "generate", "--scene", BOX_ROOM, "--out", out, "--per-bin", value],
                   "--per-bin", untouched=[out])


@pytest.mark.parametrize("args, option", [
    (["--workers", 0], "--workers"), (["--episodes-per-bin", 0], "--episodes-per-bin"),
    (["--heldout-per-bin", -1], "--heldout-per-bin"), (["--noise", 1.5], "--noise"),
])
def test_collect_counts_are_refused(capsys, tmp_path, args, option):
    out = tmp_path / "demos"
    assert_refused(capsys, ["collect", "--out", out, "--scenes-root", tmp_path / "scenes", *args], option,
                   untouched=[out, tmp_path / "scenes"])


@pytest.mark.skipif(torch.cuda.is_available(), reason="needs a machine without CUDA")
@pytest.mark.parametrize("command", [["eval", "-c", "expert"], ["train"], ["collect"]])
def test_cuda_without_cuda_is_one_line(capsys, tmp_path, command):
    out = tmp_path / "out"
    line = assert_refused(capsys, [*command, "--out", out, "--device", "cuda"], "--device", "CUDA", untouched=[out])
    assert "AssertionError" not in line


@pytest.mark.parametrize("spec", ["=model.pt", "nue=", " =x.pt"])
def test_empty_method_name_or_path_is_refused(capsys, tmp_path, spec):
    out = tmp_path / "r.jsonl"
    assert_refused(capsys, ["eval", "-c", spec, "--out", out, "--episodes-dir", tmp_path], "--checkpoint",
                   untouched=[out])


def test_a_method_name_given_twice_is_refused(capsys, tmp_path):
    eps = tmp_path / "eps"
    eps.mkdir()
    (eps / "box_room.json").write_text("[]")
    out = tmp_path / "r.jsonl"
    assert_refused(capsys, ["eval", "-c", "expert", "-c", "expert", "--out", out, "--episodes-dir", eps,
                            "--scenes-root", FIXTURES], "--checkpoint", "twice", untouched=[out])


USAGE_CASES = {  # click's own usage errors: one line naming the command, no boxed usage text
    "unknown-option": (["train", "--bogus"], "nue train", "No such option: --bogus"),
    "misspelt-option": (["eval", "--worker", 2], "nue eval", "No such option: --worker (Possible options: --workers)"),
    "not-an-int": (["eval", "--workers", "abc"], "nue eval", "Invalid value for '--workers'"),
    "not-a-number": (["collect", "--noise", "often"], "nue collect", "Invalid value for '--noise'"),
    "option-without-value": (["eval", "--workers"], "nue eval", "Option '--workers' requires an argument"),
    "missing-option": (["scenes", "generate"], "nue scenes generate", "Missing option '--split'"),
    "missing-argument": (["scenes", "info"], "nue scenes info", "Missing argument 'folders'"),
    "unknown-command": (["evaluate"], "nue", "No such command 'evaluate'"),
    "misspelt-subcommand": (["scenes", "generat"], "nue scenes", "Did you mean 'generate'?"),
    "extra-argument": (["demo", "surplus"], "nue demo", "Got unexpected extra argument(s) (surplus)"),
}


@pytest.mark.parametrize("case", sorted(USAGE_CASES))
def test_usage_errors_are_one_line(capsys, tmp_path, monkeypatch, case):
    args, command, problem = USAGE_CASES[case]
    monkeypatch.chdir(tmp_path)  # default outputs are relative paths: nothing may appear here
    line = assert_refused(capsys, args, f"error: {command}: ", problem, f"(see '{command} --help')")
    assert "Usage:" not in line and "╭" not in line
    assert list(tmp_path.iterdir()) == []


def test_houses_that_are_not_integers_are_refused(capsys, tmp_path):
    out = tmp_path / "demos"
    assert_refused(capsys, ["collect", "--out", out, "--houses", "1,x"], "--houses", "'1,x'", untouched=[out])


def test_help_is_still_clicks(capsys):
    code, out, err = run_cli(capsys, "eval", "--help")
    assert code == 0 and err == "" and "Usage: nue eval" in out and "--workers" in out
    code, out, err = run_cli(capsys, "scenes")  # a group alone prints its help, as click does
    assert code == 2 and "Usage: nue scenes" in out and "generate" in out and "error" not in err


# --- output paths ------------------------------------------------------------------------------
@pytest.fixture()
def a_file(tmp_path):
    p = tmp_path / "a_file"
    p.write_text("keep me\n")
    return p


def _output_cases(tmp_path, a_file):
    folder = tmp_path / "folder"
    folder.mkdir()
    return {
        "expert-records-is-dir": (["expert", "--scene", BOX_ROOM, "--episodes", tmp_path / "none.json", "--records", folder],
                                  folder, "is a directory"),
        "expert-records-under-file": (["expert", "--scene", BOX_ROOM, "--episodes", tmp_path / "none.json",
                                       "--records", a_file / "r.jsonl"], a_file, "is a file, not a folder"),
        "eval-out-is-dir": (["eval", "-c", "expert", "--out", folder], folder, "is a directory"),
        "eval-out-under-file": (["eval", "-c", "expert", "--out", a_file / "x" / "r.jsonl"], a_file, "is a file"),
        "collect-out-is-file": (["collect", "--out", a_file], a_file, "must be a folder"),
        "train-out-is-file": (["train", "--out", a_file], a_file, "must be a folder"),
        "report-out-is-file": (["report", tmp_path / "none.jsonl", "--out", a_file], a_file, "must be a folder"),
        "report-md-is-dir": (["report", tmp_path / "none.jsonl", "--out", tmp_path / "rep", "--results-md", folder],
                             folder, "is a directory"),
        "diagnose-out-is-dir": (["diagnose", "--records", tmp_path / "none.jsonl", "--out", folder], folder, "is a directory"),
        "episodes-out-is-dir": (["episodes", "generate", "--scene", BOX_ROOM, "--out", folder], folder, "is a directory"),
        "scenes-out-is-file": (["scenes", "generate", "--split", "val", "--out", a_file], a_file, "must be a folder"),
        "demo-out-is-file": (["demo", "--out", a_file], a_file, "must be a folder"),
    }


@pytest.mark.parametrize("case", ["expert-records-is-dir", "expert-records-under-file", "eval-out-is-dir",
                                  "eval-out-under-file", "collect-out-is-file", "train-out-is-file",
                                  "report-out-is-file", "report-md-is-dir", "diagnose-out-is-dir",
                                  "episodes-out-is-dir", "scenes-out-is-file", "demo-out-is-file"])
def test_unusable_output_paths_are_refused_before_any_work(capsys, tmp_path, a_file, case):
    args, named, problem = _output_cases(tmp_path, a_file)[case]
    before = sorted(p.name for p in tmp_path.rglob("*"))
    assert_refused(capsys, args, named, problem)
    assert sorted(p.name for p in tmp_path.rglob("*")) == before  # nothing created
    assert a_file.read_text() == "keep me\n"


def test_read_only_output_folder_is_refused(capsys, tmp_path, monkeypatch):
    """A folder the user cannot write (``os.access``; root bypasses permission bits, so the check is
    exercised by denying write access to this one folder)."""
    import nue.outputs

    ro = tmp_path / "ro"
    ro.mkdir()
    real = nue.outputs._writable
    monkeypatch.setattr(nue.outputs, "_writable", lambda p: False if os.fspath(p) == os.fspath(ro) else real(p))
    out = ro / "sub" / "r.jsonl"
    assert_refused(capsys, ["eval", "-c", "expert", "--out", out], out, "not writable", untouched=[ro / "sub"])
    assert_refused(capsys, ["train", "--out", ro], ro, "not writable")


# --- checkpoints -------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    """A tiny valid FR checkpoint for the paper task (untrained weights)."""
    from nue.nerf.config import get_memory
    from nue.policy import build_model
    from nue.policy.checkpoint import policy_meta, save_checkpoint
    from nue.policy.config import get_model_config
    from nue.sim.task import get_task

    task = get_task("paper")
    cfg = get_model_config("fr").for_task(task)
    torch.manual_seed(0)
    meta = policy_meta(task, get_memory("fast"), cfg, {})
    return save_checkpoint(tmp_path_factory.mktemp("ckpt") / "fr.pt", {**meta, "model_state": build_model(cfg).state_dict(), "step": 0})


@pytest.fixture()
def one_episode_dir(tmp_path):
    d = tmp_path / "eps"
    d.mkdir()
    item = {"startXYZ": [0.0, 0.0, 0.0], "startQuat": [0, 0, 0, 1], "endXYZ": [2.0, 2.0, 0.0], "endQuat": [0, 0, 0, 1]}
    (d / "box_room.json").write_text(json.dumps([item]))
    return d


@pytest.mark.parametrize("value", [float("nan"), float("inf")])
def test_non_finite_weights_are_refused_at_load(capsys, tmp_path, checkpoint, one_episode_dir, value):
    ckpt = torch.load(checkpoint, weights_only=True)
    name = next(k for k, v in ckpt["model_state"].items() if v.is_floating_point())
    ckpt["model_state"][name].view(-1)[0] = value
    bad = tmp_path / "bad.pt"
    torch.save(ckpt, bad)
    out = tmp_path / "r.jsonl"
    for spec in (bad, f"fr={bad}"):
        assert_refused(capsys, ["eval", "-c", spec, "--out", out, "--episodes-dir", one_episode_dir,
                                "--scenes-root", FIXTURES], bad, "not finite", name, untouched=[out])


def test_a_directory_as_checkpoint_is_named_as_such(capsys, tmp_path, one_episode_dir):
    folder = tmp_path / "runs"
    folder.mkdir()
    out = tmp_path / "r.jsonl"
    for spec in (folder, f"nue={folder}"):
        line = assert_refused(capsys, ["eval", "-c", spec, "--out", out, "--episodes-dir", one_episode_dir,
                                       "--scenes-root", FIXTURES], folder, "is a directory", untouched=[out])
        assert "not found" not in line


# --- record files ------------------------------------------------------------------------------
@pytest.mark.parametrize("content, problem", [
    ("{not json\n", "line 1: not JSON"),
    ('[1, 2]\n', "line 1: not an episode record"),
    ('{"method": "nue"}\n', "missing"),
    ('{"format": "nue-record/9", "episode_id": "0", "scene": "s", "difficulty": "easy", "success": true, '
     '"geodesic_start": 2.0, "path_length": 2.0, "final_geodesic": 0.5, "final_euclidean": 0.5, "success_radius": 0.8}\n',
     "line 1: record format 'nue-record/9' is not 'nue-record/1'"),
])
def test_corrupt_record_files_are_one_line(capsys, tmp_path, content, problem):
    rec = tmp_path / "records.jsonl"
    rec.write_text(content)
    rep = tmp_path / "report"
    assert_refused(capsys, ["report", rec, "--out", rep], rec, problem, untouched=[rep])
    assert_refused(capsys, ["diagnose", "--records", rec], rec, problem)


def test_a_record_file_that_is_not_utf8_is_one_line(capsys, tmp_path):
    rec = tmp_path / "records.jsonl"
    rec.write_bytes(b"\xff\xfe\x00garbage\n")
    assert_refused(capsys, ["diagnose", "--records", rec], rec, "cannot read records (UnicodeDecodeError)")


def test_missing_record_file_is_one_line(capsys, tmp_path):
    assert_refused(capsys, ["report", tmp_path / "nope.jsonl", "--out", tmp_path / "rep"], "nope.jsonl",
                   untouched=[tmp_path / "rep"])


# --- episode files -----------------------------------------------------------------------------
GOOD = {"startXYZ": [0.0, 0.0, 0.0], "startQuat": [0, 0, 0, 1], "endXYZ": [2.0, 2.0, 0.0], "endQuat": [0, 0, 0, 1]}


def _ours(**changes) -> dict:
    ep = {"episode_id": "e0", "scene": "box_room", "start_position": [0.0, 0.0, 0.0], "start_rotation": [0, 0, 0, 1],
          "goal_position": [2.0, 2.0, 0.0], "goal_rotation": [0, 0, 0, 1], "euclidean_distance": 2.83,
          "geodesic_distance": 2.9}
    for k, v in changes.items():
        if v is None and k.startswith("drop_"):
            del ep[k[5:]]
        else:
            ep[k] = v
    return ep


EPISODE_CASES = {
    # the authors' format (a bare list)
    "entry-is-list": ([[0, 0, 0]], "episode 0", "expected an object"),
    "position-null": ([{**GOOD, "startXYZ": None}], "episode 0", "startXYZ: expected 3 numbers, got null"),
    "position-string": ([{**GOOD, "endXYZ": "2,2,0"}], "episode 0", "endXYZ: expected 3 numbers"),
    "position-2-values": ([{**GOOD, "startXYZ": [0.0, 0.0]}], "episode 0", "startXYZ: expected 3 numbers"),
    "quaternion-3-values": ([{**GOOD, "startQuat": [0, 0, 1]}], "episode 0", "startQuat: expected 4 numbers"),
    "missing-key": ([{k: v for k, v in GOOD.items() if k != "endQuat"}], "episode 0", "missing field(s): endQuat"),
    "boolean-coordinate": ([{**GOOD, "startXYZ": [True, 0.0, 0.0]}], "episode 0", "startXYZ: expected 3 numbers"),
    "boolean-distance": ([{**GOOD, "dist": True}], "episode 0", "dist: expected a number"),
    "non-unit-quaternion": ([{**GOOD, "startQuat": [0, 0, 0, 2]}], "episode 0", "not a unit quaternion"),
    "zero-quaternion": ([{**GOOD, "endQuat": [0, 0, 0, 0]}], "episode 0", "not a unit quaternion"),
    "non-yaw-quaternion": ([{**GOOD, "startQuat": [0.7071068, 0, 0, 0.7071068]}], "episode 0", "not a rotation about z"),
    "start-equals-goal": ([{**GOOD, "endXYZ": [0.0, 0.0, 0.0]}], "episode 0", "start and goal are the same point"),
    "z-off-every-floor": ([{**GOOD, "startXYZ": [0.0, 0.0, 3.0]}], "episode 0", "from every floor"),
    "empty-list": ([], None, "holds no episodes"),
    # our format
    "ours-missing-key": ({"format": "nue-episodes/1", "task": "paper", "episodes": [_ours(drop_goal_position=None)]},
                         "episode e0", "missing field(s): goal_position"),
    "ours-unknown-key": ({"format": "nue-episodes/1", "task": "paper", "episodes": [_ours(colour="red")]},
                         "episode e0", "unknown field(s): colour"),
    "ours-entry-is-list": ({"format": "nue-episodes/1", "task": "paper", "episodes": [[1, 2]]}, "episode #0",
                           "expected an object"),
    "ours-boolean-coordinate": ({"format": "nue-episodes/1", "task": "paper",
                                 "episodes": [_ours(goal_position=[2.0, False, 0.0])]}, "episode e0", "goal_position"),
    "ours-duplicate-id": ({"format": "nue-episodes/1", "task": "paper", "episodes": [_ours(), _ours()]},
                          "episode e0", "duplicate episode id"),
    "ours-empty": ({"format": "nue-episodes/1", "task": "paper", "episodes": []}, None, "holds no episodes"),
    "ours-other-task": ({"format": "nue-episodes/1", "task": "habitat", "episodes": [_ours()]}, None,
                        "made for task preset 'habitat'"),
}


@pytest.mark.parametrize("case", sorted(EPISODE_CASES))
def test_bad_episode_files_name_file_and_entry(capsys, tmp_path, case):
    doc, entry, problem = EPISODE_CASES[case]
    eps = tmp_path / "eps.json"
    eps.write_text(json.dumps(doc))
    records = tmp_path / "rec.jsonl"
    fragments = [eps, problem] + ([f"{entry}:"] if entry else [])
    line = assert_refused(capsys, ["expert", "--scene", BOX_ROOM, "--episodes", eps, "--records", records], *fragments,
                          untouched=[records])
    assert "__init__" not in line and line.count(f"{entry}:") <= 1


def test_all_bad_entries_are_named_together(capsys, tmp_path):
    eps = tmp_path / "eps.json"
    eps.write_text(json.dumps([GOOD, {**GOOD, "startXYZ": None}, {**GOOD, "endQuat": [0, 0, 0, 3]}]))
    assert_refused(capsys, ["expert", "--scene", BOX_ROOM, "--episodes", eps], eps, "2 invalid episodes",
                   "episode 1: startXYZ", "episode 2: endQuat")


HABITAT = {"episode_id": "7", "scene_id": "data/scene_datasets/gibson/box_room.glb", "start_position": [0.0, 0.0, 0.5],
           "start_rotation": [0, 0, 0, 1], "goals": [{"position": [2.0, 0.0, -1.0], "radius": 0.2}],
           "info": {"geodesic_distance": 2.55}}


DROP = object()
"""A field value in :func:`_habitat` that leaves the field out."""


def _habitat(**changes) -> dict:
    """:data:`HABITAT` with some fields changed (``None`` is JSON null) or left out (:data:`DROP`)."""
    return {k: v for k, v in {**HABITAT, **changes}.items() if v is not DROP}


HABITAT_CASES = {  # habitat-lab's format (y up), read by `nue episodes convert`, `nue expert` and `nue eval`
    "start-2-values": (_habitat(start_position=[0.0, 0.5]), "episode 7", "start_position: expected 3 numbers, got [0.0, 0.5]"),
    "start-null": (_habitat(start_position=None), "episode 7", "start_position: expected 3 numbers, got null"),
    "start-boolean": (_habitat(start_position=[0.0, True, 0.0]), "episode 7", "start_position: expected 3 numbers"),
    "rotation-3-values": (_habitat(start_rotation=[0, 0, 1]), "episode 7", "start_rotation: expected 4 numbers"),
    "rotation-not-unit": (_habitat(start_rotation=[0, 0, 0, 0]), "episode 7", "start_rotation is not a unit quaternion"),
    "rotation-tilted": (_habitat(start_rotation=[0.7071068, 0, 0, 0.7071068]), "episode 7",
                        "start_rotation is not a rotation about y (x, z must be 0)"),
    "goals-missing": (_habitat(goals=DROP), "episode 7", "missing field(s): goals"),
    "goals-empty": (_habitat(goals=[]), "episode 7", "goals: expected a non-empty list of goals, got []"),
    "goal-without-position": (_habitat(goals=[{"radius": 0.2}]), "episode 7", "goals[0]: expected an object with a position"),
    "goal-nan": (_habitat(goals=[{"position": [float("nan"), 0.0, -1.0]}]), "episode 7", "goals[0].position is not finite"),
    "episode-id-missing": (_habitat(episode_id=DROP), "episode #0", "missing field(s): episode_id"),
    "scene-id-missing": (_habitat(scene_id=DROP), "episode 7", "missing field(s): scene_id"),
    "scene-id-number": (_habitat(scene_id=3), "episode 7", "scene_id: expected the path of the scene's mesh, got 3"),
    "entry-is-list": ([1, 2], "episode #0", "expected an object with the episode's fields, got a list"),
    "distance-string": (_habitat(info={"geodesic_distance": "2.55"}), "episode 7", "info.geodesic_distance: expected a number"),
}


@pytest.mark.parametrize("case", sorted(HABITAT_CASES))
def test_bad_habitat_episodes_name_file_and_entry(capsys, tmp_path, case):
    import gzip

    item, entry, problem = HABITAT_CASES[case]
    src = tmp_path / "box_room.json.gz"
    src.write_bytes(gzip.compress(json.dumps({"episodes": [item]}).encode()))
    out = tmp_path / "ours.json"
    line = assert_refused(capsys, ["episodes", "convert", src, "--out", out, "--scene", BOX_ROOM], src, f"{entry}: ",
                          problem, untouched=[out])
    assert "malformed" not in line and "Error" not in line and line.count(f"{entry}:") == 1


def test_bad_habitat_episodes_are_refused_by_expert_too(capsys, tmp_path):
    src = tmp_path / "eps.json"
    src.write_text(json.dumps({"episodes": [HABITAT, _habitat(episode_id="8", goals=[])]}))
    records = tmp_path / "rec.jsonl"
    assert_refused(capsys, ["expert", "--scene", BOX_ROOM, "--episodes", src, "--records", records], src,
                   "episode 8: goals: expected a non-empty list", untouched=[records])


# --- scenes ------------------------------------------------------------------------------------
def _break_obj(folder, line):
    obj = folder / "mesh_z_up.obj"
    lines = obj.read_text().splitlines()
    i = next(k for k, ln in enumerate(lines) if ln.startswith("v "))
    lines[i] = line
    obj.write_text("\n".join(lines) + "\n")
    return i + 1


def _with_texture(folder, data: bytes | None):
    mtl = folder / "mesh_z_up.mtl"
    mtl.write_text(mtl.read_text().replace("newmtl floor\n", "newmtl floor\nmap_Kd textures/floor.png\n", 1))
    if data is not None:
        (folder / "textures").mkdir()
        (folder / "textures" / "floor.png").write_bytes(data)


SCENE_CASES = {
    "nan-vertex": (lambda d: _break_obj(d, "v nan 0.0 0.0"), "mesh_z_up.obj", "has a NaN or inf value"),
    "inf-vertex": (lambda d: _break_obj(d, "v 0.0 inf 0.0"), "mesh_z_up.obj", "has a NaN or inf value"),
    "too-few-values": (lambda d: _break_obj(d, "v 1.0 2.0"), "mesh_z_up.obj", "'v' needs at least 3 values, got 2"),
    "missing-mtl": (lambda d: (d / "mesh_z_up.mtl").unlink(), "mesh_z_up.mtl", "material library referenced by mesh_z_up.obj not found"),
    "missing-texture": (lambda d: _with_texture(d, None), "floor.png", "texture referenced by mesh_z_up.mtl not found"),
    "corrupt-texture": (lambda d: _with_texture(d, b"\x89PNG\r\n\x1a\n garbage"), "floor.png", "not a readable image"),
}


@pytest.mark.parametrize("case", sorted(SCENE_CASES))
def test_bad_scene_files_are_one_line(capsys, tmp_path, case):
    import shutil

    breakage, named, problem = SCENE_CASES[case]
    folder = tmp_path / "scene"
    shutil.copytree(BOX_ROOM, folder)
    breakage(folder)
    line = assert_refused(capsys, ["scenes", "info", folder], named, problem)
    assert "IndexError" not in line


@pytest.mark.parametrize("value", [float("nan"), float("inf")], ids=["nan", "inf"])
@pytest.mark.parametrize("fmt", ["glb", "ply"])
def test_non_finite_vertices_of_glb_and_ply_meshes_are_refused(tmp_path, fmt, value):
    """Checked as read: trimesh's clean-up would drop a PLY's NaN vertex and its faces without a word.
    The mesh is read when the scene is rendered (``Scene.load`` with ``mesh=``, or a mesh path)."""
    import shutil

    import trimesh

    from nue.errors import NueError, SceneError
    from nue.scene.scene import Scene
    from nue.sim.renderer import Renderer

    folder = tmp_path / "scene"
    shutil.copytree(BOX_ROOM, folder)
    box = trimesh.creation.box((1.0, 1.0, 1.0))
    vertices = box.vertices.copy()
    vertices[3, 2] = value
    mesh = folder / f"mesh.{fmt}"
    trimesh.Trimesh(vertices, box.faces, process=False).export(mesh)
    for load in (Scene.load(folder, mesh=mesh.name).load_mesh, lambda: Renderer(mesh)):
        with pytest.raises(SceneError) as err:
            load()
        line = str(err.value)
        assert isinstance(err.value, NueError) and "\n" not in line  # the CLI prints it as one line, exit 2
        assert line.startswith(f"{mesh}: ") and "1 of 8 vertices" in line and "NaN or inf" in line and "vertex 3" in line


def test_eval_refuses_an_incomplete_house_folder_and_keeps_its_files(capsys, tmp_path):
    root = tmp_path / "scenes"
    (root / "val_00").mkdir(parents=True)
    (root / "val_00" / "notes.txt").write_text("mine\n")
    eps = tmp_path / "eps"
    eps.mkdir()
    (eps / "val_00.json").write_text(json.dumps([GOOD]))
    out = tmp_path / "r.jsonl"
    assert_refused(capsys, ["eval", "-c", "expert", "--out", out, "--episodes-dir", eps, "--scenes-root", root],
                   root / "val_00", "not a complete generated house", "mesh_z_up.obj", untouched=[out])
    assert sorted(p.name for p in (root / "val_00").iterdir()) == ["notes.txt"]
    assert (root / "val_00" / "notes.txt").read_text() == "mine\n"


def test_scenes_generate_regenerates_a_corrupt_house_only_with_force(capsys, tmp_path, monkeypatch):
    from nue.scene import generator

    monkeypatch.setitem(generator.SPLITS, "tiny", (generator.SPLITS["val"][0],))
    root = tmp_path / "scenes"
    code, _, err = run_cli(capsys, "scenes", "generate", "--split", "tiny", "--out", root)
    assert code == 0, err
    texture = sorted((root / "tiny_00" / "textures").glob("*.png"))[0]
    good = texture.read_bytes()
    texture.write_bytes(good[: len(good) // 2])  # a truncated copy
    assert_refused(capsys, ["scenes", "generate", "--split", "tiny", "--out", root], root / "tiny_00", "--force")
    assert texture.read_bytes() == good[: len(good) // 2]  # kept as it was
    code, _, err = run_cli(capsys, "scenes", "generate", "--split", "tiny", "--out", root, "--force")
    assert code == 0 and "regenerated" in err, err
    assert texture.read_bytes() == good


def test_typed_errors_survive_a_worker_process_boundary():
    """Errors raised in a worker are pickled to the driver; they must arrive with the same one line."""
    import pickle

    from nue.errors import CheckpointError, InvalidEpisodesError, SceneError

    for exc in (SceneError("a/mesh_z_up.obj", "line 3: 'v' needs at least 3 values, got 2"),
                CheckpointError(None, "no file"), InvalidEpisodesError("eps.json", [("e1", "bad"), ("e2", "worse")])):
        back = pickle.loads(pickle.dumps(exc))
        assert type(back) is type(exc) and str(back) == str(exc) and back.where == exc.where


# --- the installed command ---------------------------------------------------------------------
def _console_script() -> list[str]:
    """The ``nue`` console script of this environment (``python -m nue.cli`` where it is not installed)."""
    script = Path(sys.executable).with_name("nue")
    return [str(script)] if script.is_file() else [sys.executable, "-m", "nue.cli"]


def _process_cases(tmp_path) -> dict:
    import gzip

    habitat = tmp_path / "box_room.json.gz"
    habitat.write_bytes(gzip.compress(json.dumps({"episodes": [_habitat(goals=[])]}).encode()))
    a_file = tmp_path / "a_file"
    a_file.write_text("keep me\n")
    return {  # args and what the line names (commands that import little: a process costs ~1 s each)
        "usage-not-an-int": (["eval", "--workers", "abc", "--out", "r.jsonl"], "nue eval: Invalid value for '--workers'"),
        "usage-unknown-command": (["evaluate", "--out", "r.jsonl"], "nue: No such command 'evaluate'"),
        "habitat-entry": (["episodes", "convert", habitat, "--out", "o.json", "--scene", BOX_ROOM],
                          f"{habitat}: episode 7: goals"),
        "output-is-a-file": (["scenes", "generate", "--split", "val", "--out", a_file], f"{a_file}: is a file"),
    }


@pytest.mark.parametrize("case", ["usage-not-an-int", "usage-unknown-command", "habitat-entry", "output-is-a-file"])
def test_the_console_script_prints_the_same_line(capsys, tmp_path, monkeypatch, case):
    """A real ``nue`` process gives the exit status and the one line of the in-process run, and neither
    writes anything (relative outputs would land in the working folder, ``tmp_path`` for both)."""
    args, named = _process_cases(tmp_path)[case]
    before = {p: p.read_bytes() for p in tmp_path.rglob("*")}
    monkeypatch.chdir(tmp_path)
    line = assert_refused(capsys, args, named)
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    res = subprocess.run([*_console_script(), *map(str, args)], capture_output=True, text=True, env=env,
                         cwd=tmp_path, timeout=120)
    assert (res.returncode, res.stderr.strip(), res.stdout) == (2, line, ""), res.stderr
    assert {p: p.read_bytes() for p in tmp_path.rglob("*")} == before
