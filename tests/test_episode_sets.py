"""The fixed evaluation episode sets under ``episodes/``: their sizes, the 252-episode set opening with the
84-episode one, a committed file rebuilt from its spec, extending a set, and ``nue eval`` on the held-out style."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from nue.evaluate.runner import EvalConfig, plan_eval
from nue.scene.generator import SPLITS
from nue.sim.episode_gen import EpisodeGenConfig, extend_episodes, generate_episodes
from nue.sim.episode_sets import EPISODE_SETS, build_episode_set, set_size

EPISODES = Path(__file__).resolve().parents[1] / "episodes"


def _entries(path: Path) -> list[dict]:
    return json.loads(path.read_text())["episodes"]


def test_committed_sets_have_their_sizes_and_the_large_one_opens_with_the_quick_one():
    assert (set_size("val"), set_size("val252"), set_size("val_plain")) == (84, 252, 252)
    assert (set_size("select"), set_size("select_diverse")) == (21, 21)
    for name, spec in EPISODE_SETS.items():
        files = sorted((EPISODES / name).glob("*.json"))
        houses = spec.houses or range(len(SPLITS[spec.split]))
        assert [f.stem for f in files] == [f"{spec.split}_{i:02d}" for i in houses]
        per_house = set_size(name) // len(files)
        for i, f in zip(houses, files):
            eps = _entries(f)
            assert len(eps) == per_house and len({e["episode_id"] for e in eps}) == per_house
            assert all(e["scene"] == f.stem for e in eps)
            if spec.bin_per_house:  # the bins in turn by house index
                assert {e["difficulty"] for e in eps} == {("easy", "medium", "hard")[i % 3]}
            else:
                assert all(sum(e["difficulty"] == d for e in eps) == per_house // 3 for d in ("easy", "medium", "hard"))
    for f in sorted((EPISODES / "val").glob("*.json")):
        small = _entries(f)
        assert _entries(EPISODES / "val252" / f.name)[: len(small)] == small


def _same_episodes(a: list[dict], b: list[dict]) -> None:
    assert [e["episode_id"] for e in a] == [e["episode_id"] for e in b]
    for x, y in zip(a, b):
        for key in x:
            if isinstance(x[key], str):
                assert x[key] == y[key], key
            else:
                np.testing.assert_allclose(x[key], y[key], rtol=1e-12, atol=1e-12, err_msg=key)


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    return tmp_path_factory.mktemp("scenes")


def test_committed_files_are_rebuilt_from_their_specs(scenes, tmp_path):
    shutil.copytree(EPISODES / "val", tmp_path / "val")  # the set val252 extends
    for name, i, house in (("val252", 0, "val_00"), ("val_plain", 0, "val_plain_00"), ("val_pale", 0, "val_pale_00"),
                           ("select", 5, "train_05"), ("select_diverse", 4, "train_diverse_04")):
        (path,) = build_episode_set(name, scenes, tmp_path, houses=(i,), progress=False)
        assert path == tmp_path / name / f"{house}.json"
        _same_episodes(_entries(path), _entries(EPISODES / name / f"{house}.json"))


def test_a_house_outside_a_selection_set_is_refused(scenes, tmp_path):
    from nue.errors import ConfigError

    with pytest.raises(ConfigError, match=r"house indices \[3\] are not in the set"):
        build_episode_set("select_diverse", scenes, tmp_path, houses=(2, 3), progress=False)
    assert not (tmp_path / "select_diverse").exists()


def test_extending_keeps_the_episodes_and_continues_their_ids(box_scene, box_nav, box_renderer):
    kw = dict(navgrid=box_nav, renderer=box_renderer, bins=("easy", "medium"))
    base = generate_episodes(box_scene, "paper", EpisodeGenConfig(per_bin=1), seed=4, **kw)
    more = extend_episodes(base, box_scene, "paper", EpisodeGenConfig(per_bin=1), seed=5, **kw)
    assert more[:2] == base
    assert [e.episode_id for e in more] == ["easy_000", "medium_000", "easy_001", "medium_001"]
    assert [e.difficulty for e in more[2:]] == ["easy", "medium"]
    assert all(e.start_position != b.start_position for e in more[2:] for b in base)


def test_make_set_refuses_an_unknown_set(tmp_path, capsys):
    from nue.cli import main

    with pytest.raises(SystemExit) as stop:
        main(["episodes", "make-set", "val999", "--root", str(tmp_path), "--scenes-root", str(tmp_path / "scenes")])
    assert stop.value.code == 2 and "unknown episode set" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_eval_finds_the_held_out_houses_by_their_file_names(scenes, tmp_path):
    """``nue eval --episodes-dir episodes/val_plain`` runs the val_plain houses, not the val houses of the same index."""
    shutil.copy(EPISODES / "val_plain" / "val_plain_00.json", tmp_path)
    jobs = plan_eval(["expert"], EvalConfig(episodes_dir=str(tmp_path), scenes_root=str(scenes), max_episodes=2))
    assert [j.key for j in jobs] == ["expert/val_plain_00/easy_000", "expert/val_plain_00/easy_001"]
