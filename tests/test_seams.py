"""Typed seams: the collection manifest, the agent spec and the job payloads are frozen dataclasses that
become dicts only in files, and files written before they were typed read back and write out unchanged."""

from __future__ import annotations

import hashlib
import json
import pickle
from pathlib import Path

import pytest

from nue.errors import DataError
from nue.evaluate.eval_job import EvalJob, RunSettings
from nue.nerf.config import get_memory
from nue.sim.episodes import Episode
from nue.train.collect_job import AgentSpec, CollectJob
from nue.train.manifest import CollectionManifest, read_manifest, write_manifest

REPO = Path(__file__).resolve().parents[1]
GOLDEN = Path(__file__).parent / "golden"
MANIFESTS = sorted(REPO.glob("results/v*/demos_manifest.json")) + sorted(GOLDEN.glob("demos_manifest_*.json"))

EPISODE = Episode("easy_000", "room", (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), (2.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0),
                  2.0, 2.1, "easy", "straight", "0123456789abcdef")


@pytest.mark.parametrize("path", MANIFESTS, ids=[p.name for p in MANIFESTS])
def test_manifests_written_before_read_back_and_write_out_unchanged(path, tmp_path):
    raw = json.loads(path.read_text())
    manifest = CollectionManifest.from_dict(raw, path)
    assert manifest.to_dict() == raw
    assert manifest.hash() == hashlib.sha256(json.dumps(raw, sort_keys=True).encode()).hexdigest()[:16]
    write_manifest(tmp_path, manifest)
    assert json.loads((tmp_path / "manifest.json").read_text()) == raw and read_manifest(tmp_path) == manifest
    write_manifest(tmp_path, manifest)  # the same collection: accepted
    with pytest.raises(DataError, match="differs in seed"):
        write_manifest(tmp_path, CollectionManifest.from_dict({**raw, "seed": raw["seed"] + 1}))


def test_a_dagger_manifest_keeps_its_agent():
    dagger = [p for p in MANIFESTS if "agent" in json.loads(p.read_text())]
    assert dagger, "no DAgger manifest among the golden files"
    manifest = read_manifest_file(dagger[0])
    assert manifest.agent.kind == "dagger" and manifest.agent.checkpoint and manifest.subsample_per_bin == 1


def read_manifest_file(path: Path) -> CollectionManifest:
    return CollectionManifest.from_dict(json.loads(path.read_text()), path)


def test_not_a_manifest_is_refused(tmp_path):
    with pytest.raises(DataError, match="no manifest"):
        read_manifest(tmp_path)
    (tmp_path / "manifest.json").write_text('{"format": "something-else"}')
    with pytest.raises(DataError, match="not a nue-demos/1 collection manifest"):
        read_manifest(tmp_path)
    (tmp_path / "manifest.json").write_text('{"format": "nue-demos/1", "task": "paper"}')
    with pytest.raises(DataError, match="malformed collection manifest"):
        read_manifest(tmp_path)


def test_agent_spec_file_forms():
    """The manifest's ``agent`` and the episode header's ``meta["agent"]`` as the untyped code wrote them."""
    assert AgentSpec().to_dict() == {"kind": "expert"} and AgentSpec.from_dict({"kind": "expert"}) == AgentSpec()
    spec = AgentSpec.dagger("run/best.pt", 0.5, "data/demos")
    legacy = {"kind": "dagger", "checkpoint": "run/best.pt", "beta": 0.5, "expert_steps_from": "data/demos",
              "max_factor": 3.0}
    assert spec.to_dict() == legacy and AgentSpec.from_dict(legacy) == spec
    job = CollectJob("scene", EPISODE, "paper", get_memory("fast"), "nue", 7, "cpu", spec, "explore", 0.3, 41)
    assert job.agent_meta() == {**legacy, "expert": "explore", "noise": 0.3, "expert_steps": 41}
    expert = CollectJob("scene", EPISODE, "paper", get_memory("fast"), "nue", 7, "cpu", AgentSpec())
    assert expert.agent_meta() == {"kind": "expert", "expert": "geodesic", "noise": 0.0}
    with pytest.raises(DataError, match="unknown agent kind"):
        AgentSpec("policy")
    with pytest.raises(DataError, match="needs a checkpoint"):
        AgentSpec("dagger")


def test_job_payloads_pickle_as_they_are():
    settings = RunSettings("expert", "paper", 0, 0, False, True, RunSettings.episode_digest(EPISODE), "abc")
    jobs = [EvalJob("expert", None, "geodesic", "scene", EPISODE, None, "paper", 1, "cpu", True, 0, settings),
            CollectJob("scene", EPISODE, "paper", get_memory("fast"), "nue", 7, "cpu", AgentSpec())]
    for job in jobs:
        assert pickle.loads(pickle.dumps(job)) == job


def test_run_settings_record_form_and_differences():
    settings = RunSettings("abc", "paper", 20, 0, False, True, RunSettings.episode_digest(EPISODE), "h")
    stored = settings.to_dict()
    assert list(stored) == ["agent", "task", "max_steps", "seed", "swap_maps", "coverage", "episode", "scene",
                            "goal_from", "explore_only"]
    assert settings.differences(stored) == []
    older = {k: v for k, v in stored.items() if k not in ("goal_from", "explore_only")}  # before those existed
    assert settings.differences(older) == []
    explore = RunSettings("abc", "paper", 20, 0, False, True, RunSettings.episode_digest(EPISODE), "h", "g/e", True)
    assert explore.differences(older) == ["explore_only", "goal_from"]
    assert settings.differences({**stored, "max_steps": 30, "agent": "x"}) == ["agent", "max_steps"]
    assert settings.differences(None) == ["settings (an older record)"]
