"""``scripts/reproduce_sync.sh`` on a hand-made run folder: ``save`` keeps the recipe, the stage markers, each trained
run's ``best.pt`` (or, with ``CHECKPOINTS=0``, its sha256) and selection, and every records file (the exploration
benchmark's sub-folder too) in ``STORE``; ``restore`` puts them into a fresh run folder and drops the markers of what
must be made again there: a training run whose ``best.pt`` was not kept, and, while any training run of the recipe
(every seed) is left, a collection whose demonstrations are missing."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "reproduce_sync.sh"
pytestmark = pytest.mark.timeout(120)


def _sync(command: str, run: Path, store: Path, checkpoints: int) -> subprocess.CompletedProcess:
    env = {**os.environ, "RUN": str(run), "STORE": str(store), "CHECKPOINTS": str(checkpoints),
           "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    return subprocess.run(["bash", str(SCRIPT), command], env=env, capture_output=True, text=True)


@pytest.fixture
def run(tmp_path) -> Path:
    """A quick-recipe run with both collections made, NUE's two seeds trained and some records."""
    out = tmp_path / "run"
    (out / "stages").mkdir(parents=True)
    (out / "recipe.json").write_text(json.dumps({"recipe": {"name": "quick"}}))
    for stage in ("collect", "collect__train_diverse", "train__nue", "train__nue@s1"):
        (out / "stages" / f"{stage}.json").write_text("{}")
    for name in ("nue", "nue@s1"):
        (out / "runs" / name).mkdir(parents=True)
        (out / "runs" / name / "best.pt").write_bytes(name.encode() * 100)
        (out / "runs" / name / "selection.json").write_text("{}")
    (out / "records" / "explore").mkdir(parents=True)
    (out / "records" / "val252.jsonl").write_text('{"a": 1}\n')
    (out / "records" / "explore" / "val252.jsonl").write_text('{"b": 2}\n')
    return out


def test_save_without_checkpoints_keeps_hashes_and_restore_retrains_and_recollects(run, tmp_path):
    store = tmp_path / "store"
    res = _sync("save", run, store, checkpoints=0)
    assert res.returncode == 0, res.stderr
    assert not (store / "runs" / "nue" / "best.pt").exists()
    digest = hashlib.sha256((run / "runs" / "nue" / "best.pt").read_bytes()).hexdigest()
    assert (store / "runs" / "nue" / "best.sha256").read_text().split() == [digest, "best.pt"]
    assert (store / "runs" / "nue@s1" / "selection.json").is_file()
    assert (store / "records" / "explore" / "val252.jsonl").read_text() == '{"b": 2}\n'
    # the store mirrors the run: a run restored elsewhere that trains again is no longer finished in the store
    (run / "stages" / "train__nue@s1.json").unlink()
    assert _sync("save", run, store, checkpoints=0).returncode == 0
    assert not (store / "stages" / "train__nue@s1.json").exists() and not (store / "runs" / "nue@s1").exists()
    assert (store / "stages" / "train__nue.json").is_file() and (store / "runs" / "nue" / "best.sha256").is_file()
    (run / "stages" / "train__nue@s1.json").write_text("{}")
    assert _sync("save", run, store, checkpoints=0).returncode == 0

    fresh = tmp_path / "fresh"
    res = _sync("restore", fresh, store, checkpoints=0)
    assert res.returncode == 0, res.stderr
    assert sorted(p.name for p in (fresh / "stages").iterdir()) == []  # both runs retrain, so both collections again
    assert "train/nue@s1: no best.pt kept, trains again" in res.stdout
    assert not list((fresh / "runs" / "nue").iterdir())  # no selection records of the old snapshots to resume from
    assert "collect/train_diverse: " in res.stdout and (fresh / "records" / "val252.jsonl").is_file()


def test_save_with_checkpoints_and_restore_keeps_trained_runs_and_present_demonstrations(run, tmp_path):
    store = tmp_path / "store"
    assert _sync("save", run, store, checkpoints=1).returncode == 0
    assert (store / "runs" / "nue" / "best.pt").read_bytes() == (run / "runs" / "nue" / "best.pt").read_bytes()
    fresh = tmp_path / "fresh"
    (fresh / "demos").mkdir(parents=True)  # the first collection is there, the second is not
    res = _sync("restore", fresh, store, checkpoints=1)
    assert res.returncode == 0, res.stderr
    # quick trains 9 runs (8 models, NUE twice): 7 are left, so the missing collection is made again
    assert sorted(p.stem for p in (fresh / "stages").iterdir()) == ["collect", "train__nue", "train__nue@s1"]


def _scratch_repo(tmp_path: Path, run: Path, **env_extra: str):
    """A git repository holding a copy of the script, RUN = ``run``, STORE=results/run, CHECKPOINTS=1: (repo folder,
    ``commit()`` running the script's ``commit`` there, ``git(*args)``)."""
    repo = tmp_path / "repo"
    (repo / "scripts").mkdir(parents=True)
    script = repo / "scripts" / "reproduce_sync.sh"
    script.write_bytes(SCRIPT.read_bytes())
    env = {**os.environ, "GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@t", "GIT_COMMITTER_NAME": "t",
           "GIT_COMMITTER_EMAIL": "t@t", "RUN": str(run), "STORE": "results/run", "CHECKPOINTS": "1", **env_extra,
           "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}

    def git(*args):
        return subprocess.run(["git", *args], cwd=repo, env=env, capture_output=True, text=True)

    def commit():
        return subprocess.run(["bash", str(script), "commit"], env=env, capture_output=True, text=True)

    git("init", "-q")
    (repo / ".gitignore").write_bytes((SCRIPT.parents[1] / ".gitignore").read_bytes())  # the repository's patterns
    return repo, commit, git


def test_commit_keeps_everything_but_the_checkpoints_in_git_and_nothing_else_staged(run, tmp_path):
    repo, commit, git = _scratch_repo(tmp_path, run)
    records = run / "records"
    records.rename(tmp_path / "later")  # before the first evaluation: no records yet
    res = commit()
    assert res.returncode == 0, res.stderr
    assert "4 stages done, 0 episodes recorded" in git("log", "-1", "--format=%s").stdout
    (tmp_path / "later").rename(records)
    (repo / "other.txt").write_text("staged by someone else\n")
    git("add", "other.txt")

    res = commit()
    assert res.returncode == 0, res.stderr
    committed = set(git("ls-tree", "-r", "--name-only", "HEAD").stdout.split())
    assert committed == {"results/run/recipe.json", "results/run/records/val252.jsonl",
                         "results/run/records/explore/val252.jsonl", "results/run/runs/nue/selection.json",
                         "results/run/runs/nue@s1/selection.json", "results/run/runs/nue/best.sha256",
                         "results/run/runs/nue@s1/best.sha256",
                         *(f"results/run/stages/{s}.json" for s in ("collect", "collect__train_diverse", "train__nue",
                                                                    "train__nue@s1"))}
    assert set(git("show", "--name-only", "--format=", "HEAD").stdout.split()) == {
        "results/run/records/val252.jsonl", "results/run/records/explore/val252.jsonl"}  # what the second one added
    assert "4 stages done, 2 episodes recorded" in git("log", "-1", "--format=%s").stdout
    assert (repo / "results" / "run" / "runs" / "nue" / "best.pt").is_file()  # saved, not committed
    assert git("diff", "--cached", "--name-only").stdout.split() == ["other.txt"]  # still staged, not committed
    res = commit()
    assert res.returncode == 0 and res.stdout.strip() == "nothing new"


def test_commit_checkpoints_commits_each_finished_runs_best_pt_once(run, tmp_path):
    """``COMMIT_CHECKPOINTS=1``: a multi-session run keeps its trained models in git (each file once: a later commit
    with the same checkpoints adds nothing); the sha256 is kept beside each file."""
    repo, commit, git = _scratch_repo(tmp_path, run, COMMIT_CHECKPOINTS="1")
    res = commit()
    assert res.returncode == 0, res.stderr
    committed = set(git("ls-tree", "-r", "--name-only", "HEAD").stdout.split())
    assert {"results/run/runs/nue/best.pt", "results/run/runs/nue@s1/best.pt",
            "results/run/runs/nue/best.sha256"} <= committed
    digest = hashlib.sha256((run / "runs" / "nue@s1" / "best.pt").read_bytes()).hexdigest()
    assert git("show", "HEAD:results/run/runs/nue@s1/best.sha256").stdout.split() == [digest, "best.pt"]
    res = commit()
    assert res.returncode == 0 and res.stdout.strip() == "nothing new"


def test_commit_during_an_evaluation_leaves_the_writers_lock_behind(run, tmp_path):
    """A running ``nue eval`` holds ``.val252.jsonl.lock`` beside its records (``nue.output_lock``); git ignores it,
    so a store holding a copy made every ``commit`` fail (autosave hid it: nothing of the evaluation was saved)."""
    repo, commit, git = _scratch_repo(tmp_path, run)
    (run / "records" / ".val252.jsonl.lock").write_text("12345")
    (run / "records" / "explore" / ".val252.jsonl.lock").write_text("12345")
    res = commit()
    assert res.returncode == 0, res.stderr
    assert "results/run/records/val252.jsonl" in git("ls-tree", "-r", "--name-only", "HEAD").stdout.split()
    assert not list((repo / "results" / "run" / "records").rglob("*.lock"))
