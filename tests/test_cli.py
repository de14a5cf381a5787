"""CLI smoke runs and bad input: a one-line message naming the file, exit status 2, no traceback."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import pytest
from PIL import Image

from .conftest import BOX_ROOM


def nue(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "nue.cli", *map(str, args)], capture_output=True, text=True, cwd=cwd)


def assert_clean_error(res, *fragments):
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr and "Traceback" not in res.stdout
    line = res.stderr.strip()
    assert line.startswith("error: ") and "\n" not in line, line
    for frag in fragments:
        assert frag in line, line


def test_episodes_then_expert_end_to_end(tmp_path):
    eps = tmp_path / "eps.json"
    res = nue("episodes", "generate", "--scene", BOX_ROOM, "--out", eps, "--per-bin", 2, "--seed", 1)
    assert res.returncode == 0, res.stderr
    assert len(json.loads(eps.read_text())["episodes"]) == 6
    rec = tmp_path / "rec.jsonl"
    res = nue("expert", "--scene", BOX_ROOM, "--episodes", eps, "--records", rec)
    assert res.returncode == 0, res.stderr
    assert "| total | 6 | 100.0 |" in res.stdout
    assert len(rec.read_text().splitlines()) == 6


@pytest.fixture()
def broken(tmp_path):
    d = tmp_path / "broken"
    shutil.copytree(BOX_ROOM, d)
    return d


@pytest.mark.parametrize(
    "breakage, fragments",
    [
        (lambda d: (d / "mesh_z_up.obj").unlink(), ["mesh_z_up.obj", "mesh file not found"]),
        (lambda d: (d / "mesh_z_up.obj").write_bytes(b"\x00garbage\xff" * 20), ["mesh_z_up.obj", "mesh"]),
        (lambda d: (d / "floors.txt").unlink(), ["floors.txt", "not found"]),
        (lambda d: Image.new("RGB", (50, 50)).save(d / "floor_trav_0.png"), ["floor_trav_0.png", "mode 'L'"]),
        (lambda d: Image.new("L", (50, 40), 255).save(d / "floor_trav_0.png"), ["floor_trav_0.png", "square"]),
    ],
    ids=["missing-mesh", "corrupt-mesh", "missing-floors", "rgb-map", "non-square-map"],
)
def test_bad_scene_exits_2(broken, breakage, fragments):
    breakage(broken)
    assert_clean_error(nue("scenes", "info", broken), *fragments)


def _episode_file(tmp_path, start, goal, name="eps.json"):
    item = {"startXYZ": start, "startQuat": [0, 0, 0, 1], "endXYZ": goal, "endQuat": [0, 0, 0, 1], "dist": 2.0, "pathDist": 2.0}
    p = tmp_path / name
    p.write_text(json.dumps([item]))
    return p


@pytest.mark.parametrize(
    "start, goal, fragments",
    [
        ([-1.0, 0.0, 0.0], [2.0, 2.0, 0.0], ["eps.json", "episode 0", "inside an obstacle"]),
        ([0.0, 0.0, 0.0], [1.0, -2.0, 0.0], ["eps.json", "episode 0", "unreachable"]),
        ([0.0, float("nan"), 0.0], [2.0, 2.0, 0.0], ["eps.json", "episode 0", "startXYZ is not finite"]),
    ],
    ids=["start-in-wall", "unreachable-goal", "nan-pose"],
)
def test_bad_episode_exits_2(tmp_path, start, goal, fragments):
    eps = _episode_file(tmp_path, start, goal)
    assert_clean_error(nue("expert", "--scene", BOX_ROOM, "--episodes", eps), *fragments)
