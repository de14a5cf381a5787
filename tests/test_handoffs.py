"""The typed hand-offs between stages (what ``collect`` and ``run_dagger`` return) keep the JSON forms that
``summary.json``, ``dagger.json`` and reproduce's stage markers held when they were plain dicts."""

import json
from pathlib import Path

from nue.train.collect import CollectSummary
from nue.train.dagger import DaggerRound

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
