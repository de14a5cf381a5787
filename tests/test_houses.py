"""Generated houses end to end: reproducible content hashes, the expert on a CI episode set, the
``nue scenes generate`` command and the demo on a reduced setting."""

from __future__ import annotations

import subprocess
import sys

import pytest

from nue.evaluate.metrics import aggregate
from nue.policy.agent import ExpertAgent
from nue.rollout import run_episode
from nue.scene.generator import SPLITS, generate_house
from nue.scene.navgrid import NavGrid
from nue.scene.scene import Scene
from nue.sim.env import ImageNavEnv
from nue.sim.episode_gen import EpisodeGenConfig, generate_episodes
from nue.sim.renderer import Renderer

from .conftest import nue_here


HOUSES = (("val", 3), ("train", 5))


@pytest.fixture(scope="module")
def houses(tmp_path_factory):
    root = tmp_path_factory.mktemp("houses")
    return [generate_house(SPLITS[split][i], root / f"{split}_{i:02d}") for split, i in HOUSES]


def test_regenerating_two_houses_reproduces_their_content_hashes(houses, tmp_path):
    """Both houses again in one other process (another hash seed, a fresh interpreter)."""
    code = ("import sys; from nue.scene.generator import generate_house\n"
            "for seed, out in zip(sys.argv[1::2], sys.argv[2::2]): generate_house(int(seed), out)")
    args = [str(a) for (split, i), folder in zip(HOUSES, houses) for a in (SPLITS[split][i], tmp_path / folder.name)]
    subprocess.run([sys.executable, "-c", code, *args], check=True)
    for folder in houses:
        assert Scene.load(tmp_path / folder.name).content_hash == Scene.load(folder).content_hash


def test_expert_succeeds_on_a_ci_episode_set(houses):
    records = []
    for folder in houses:
        scene = Scene.load(folder)
        nav, renderer = NavGrid.from_scene(scene), Renderer(scene)
        for task in ("paper", "habitat"):
            eps = generate_episodes(scene, task, EpisodeGenConfig(per_bin=3), seed=2, navgrid=nav, renderer=renderer)
            env = ImageNavEnv(scene, task, eps, navgrid=nav, renderer=renderer)
            records += [run_episode(env, ExpertAgent(), episode_index=i) for i in range(len(eps))]
    total = aggregate(records)["total"]
    assert total.n == 36
    assert total.sr >= 0.99, [r for r in records if not r.success]
    assert total.collisions < 0.5


def test_scenes_generate_cli_makes_14_loadable_val_scenes(tmp_path):
    res = nue_here("scenes", "generate", "--split", "val", "--out", tmp_path)
    assert res.returncode == 0 and "14 scenes in" in res.stdout, res.stderr
    folders = sorted(p for p in tmp_path.iterdir() if p.is_dir())
    assert [p.name for p in folders] == [f"val_{i:02d}" for i in range(14)]
    hashes = {Scene.load(p).content_hash for p in folders}
    assert len(hashes) == 14


def test_demo_writes_figures_and_table(tmp_path):
    res = nue_here("demo", "--out", tmp_path / "demo", "--max-steps", 20)
    assert res.returncode == 0, res.stderr
    names = ["topdown.png", "metrics.md", "records.jsonl"]
    names += [f"{kind}_{d}.{ext}" for d in ("easy", "medium", "hard")
              for kind, ext in (("frames", "png"), ("fig6", "png"), ("episode", "gif"))]
    for name in names:
        assert (tmp_path / "demo" / name).stat().st_size > 0, name
    assert "| total | 3 |" in res.stdout
    assert (tmp_path / "scenes" / "val_00" / "mesh_z_up.obj").is_file()
