"""The typed hand-offs between stages (what ``collect`` and ``run_dagger`` return, reproduce's stage markers) keep
the JSON forms that ``summary.json``, ``dagger.json`` and the stage markers held when they were plain dicts."""

import json
from dataclasses import replace
from pathlib import Path

import pytest

from nue.errors import DataError
from nue.reproduce import RunFolders, _methods, stage_done
from nue.reproduce_marker import (EvalStageSummary, HousesSummary, ReportSummary, StageMarker, TrainRunSummary,
                                  summary_type)
from nue.train.collect import CollectSummary
from nue.train.dagger import DaggerRound

REPO = Path(__file__).resolve().parents[1]

SUMMARY = {"episodes": 6, "steps": 120, "bytes": 4096, "bytes_per_step": 34.13, "expert_success_rate": 0.5,
           "manifest_hash": "abcd", "storage": {"rgbd_bits": 8, "i_cog_bits": 4, "i_u_bits": 0}}
ROUNDS = [{"round": 0, "best": "run/round_0/best.pt", "data": "demos", "seconds": 12.5},
          {"round": 1, "beta": 0.5, "best": "run/round_1/best.pt", "data": "demos,run/data_r1",
           "collected": {k: v for k, v in SUMMARY.items() if k != "storage"}, "rollout_seconds": 3.0, "train_steps": 40,
           "seconds": 9.0}]


def test_collect_summary_round_trips_its_json_form_key_for_key():
    for d in (SUMMARY, {k: v for k, v in SUMMARY.items() if k != "storage"}):
        s = CollectSummary.from_dict(d)
        assert json.dumps(s.to_dict()) == json.dumps(d)
    assert CollectSummary.from_dict(SUMMARY).steps == 120


def test_dagger_rounds_round_trip_their_json_form_key_for_key():
    given = {"round": 0, "best": "bc/best.pt", "data": "demos", "seconds": 0.0, "given": True}
    for d in (*ROUNDS, given):
        r = DaggerRound.from_dict(d)
        assert json.dumps(r.to_dict()) == json.dumps(d)
    r1 = DaggerRound.from_dict(ROUNDS[1])
    assert r1.best == Path("run/round_1/best.pt") and r1.collected.episodes == 6 and not r1.given
    assert DaggerRound.from_dict(given).given


def _marker_text(d: dict) -> str:
    return json.dumps(d, indent=1, default=str) + "\n"  # as nue.reproduce writes a marker


def test_the_committed_reproduce_markers_read_typed_and_write_back_byte_for_byte():
    files = sorted((REPO / "results" / "reproduce" / "run" / "stages").glob("*.json"))
    assert len(files) == 15
    kinds = set()
    for f in files:
        m = StageMarker.read(f)
        kinds.add(type(m.summary))
        assert _marker_text(m.to_dict()) == f.read_text(), f.name
    assert kinds == {HousesSummary, CollectSummary, TrainRunSummary, EvalStageSummary, ReportSummary}
    assert m.machine == ""  # written before markers said where they ran; a new one does, and reads back
    assert StageMarker.from_dict(replace(m, machine="AMD EPYC, 2 CPUs").to_dict()).machine == "AMD EPYC, 2 CPUs"
    nue = StageMarker.read(REPO / "results" / "reproduce" / "run" / "stages" / "train__nue.json")
    assert nue.train_run().best == "runs/reproduce/runs/nue/best.pt" and nue.train_run().steps == 4000
    assert nue.train_run().model is None and nue.train_run().rounds is None  # written before model/seed were recorded


def test_a_training_marker_round_trips_with_model_seed_and_dagger_rounds(tmp_path):
    plain = {"stage": "train/nue@s1", "seconds": 10.5, "finished": "2026-12-05 18:00 UTC",
             "summary": {"best": "runs/nue@s1/best.pt", "steps": 40, "train_seconds": 8.25, "model": "nue", "seed": 7,
                         "seconds": 10.5}}
    dagger = {"stage": "train/fr", "seconds": 30.0, "finished": "2026-12-05 18:01 UTC",
              "summary": {"best": "run/round_1/best.pt", "rounds": ROUNDS, "model": "fr", "seed": 0, "seconds": 30.0}}
    for d in (plain, dagger):
        m = StageMarker.from_dict(d)
        assert json.dumps(m.to_dict()) == json.dumps(d)
    m = StageMarker.from_dict(dagger).train_run()
    assert m.steps is None and [r.round for r in m.rounds] == [0, 1] and m.rounds[1].collected.episodes == 6
    assert (StageMarker.from_dict(plain).train_run().model, StageMarker.from_dict(plain).train_run().seed) == ("nue", 7)
    # reproduce reads the best checkpoint of each run from its marker
    folders = RunFolders(tmp_path, tmp_path / "scenes", tmp_path / "episodes")
    path = folders.marker("train/nue@s1")
    path.parent.mkdir(parents=True)
    path.write_text(_marker_text(plain))
    assert stage_done(folders, "train/nue@s1") == StageMarker.from_dict(plain)
    assert stage_done(folders, "train/nue") is None

    class OneRun:
        def training_runs(self, models):
            return [type("Run", (), {"name": "nue@s1"})()]

    assert _methods(OneRun(), folders, ("nue",)) == ["nue@s1=runs/nue@s1/best.pt"]  # type: ignore[arg-type]


def test_a_broken_marker_stops_naming_its_file_and_kinds_follow_the_stage_name(tmp_path):
    path = tmp_path / "train__nue.json"
    path.write_text('{"stage": "train/nue", "seconds": 1.0, "finished": "x", "summary": {"steps": 4}}')
    with pytest.raises(DataError, match="train__nue.json"):
        StageMarker.read(path)
    assert [summary_type(s) for s in ("scenes", "collect", "train/a@s1", "eval/val252+swap", "report")] == [
        HousesSummary, CollectSummary, TrainRunSummary, EvalStageSummary, ReportSummary]
    with pytest.raises(ValueError, match="not a training run"):
        StageMarker("report", 1.0, "x", ReportSummary("RESULTS.md")).train_run()


class _Walker:
    """An agent that always walks forward and keeps no label (no ``executed``, no ``last_expert_action``)."""

    def reset(self, env, obs, seed: int = 0) -> None:
        pass

    def act(self, obs, maps) -> int:
        return 1


class _Listener(_Walker):
    """... and one that wants to hear the executed action."""

    def __init__(self):
        self.heard: list[int] = []

    def executed(self, action: int) -> None:
        self.heard.append(action)


def test_wrappers_ask_agents_by_protocol_what_they_offer():
    from nue.policy.agent import ExpertAgent, MixedAgent, NoisyAgent, PolicyAgent, RandomAgent
    from nue.policy.last_mile import LastMileAgent
    from nue.policy.protocols import BatchedAgent, Labelling, ToldExecuted, Twinnable

    assert issubclass(PolicyAgent, BatchedAgent) and issubclass(PolicyAgent, Twinnable)
    assert not issubclass(ExpertAgent, BatchedAgent) and not issubclass(LastMileAgent, Twinnable)
    assert issubclass(ExpertAgent, ToldExecuted) and not issubclass(RandomAgent, ToldExecuted)
    actions = ("STOP", "MOVE_FORWARD", "TURN_LEFT", "TURN_RIGHT")
    for inner in (_Walker(), _Listener()):
        noisy = NoisyAgent(inner, epsilon=1.0, actions=actions)  # every step replaced by a random move
        noisy.reset(None, None, seed=3)
        executed = [noisy.act({}, None) for _ in range(20)]
        assert isinstance(noisy, Labelling) and noisy.last_expert_action == 1  # the inner agent's action as label
        assert set(executed) <= {1, 2, 3} and len(set(executed)) > 1
        if isinstance(inner, _Listener):
            assert inner.heard == executed  # told each replaced action
    mixed = MixedAgent(_Walker(), _Listener(), beta=1.0)  # type: ignore[arg-type]
    mixed.reset(None, None, seed=0)
    assert mixed.act({}, None) == 1 and mixed.expert.heard == [1] and mixed.last_expert_action == 1
    noisy = NoisyAgent(mixed, epsilon=0.0, actions=actions)
    noisy.reset(None, None, seed=0)
    assert noisy.act({}, None) == 1 and noisy.last_expert_action == 1  # the mix's expert label passes through
