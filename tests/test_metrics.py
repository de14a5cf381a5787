"""Metrics on hand-built records: success, SPL, DTS, pooled totals."""

from __future__ import annotations

import math

import pytest

from nue.evaluate.metrics import EpisodeRecord, aggregate, dts, format_table, spl, success


def rec(i, difficulty, ok, geo, p, final_geo, r=0.8, collisions=0):
    return EpisodeRecord(
        episode_id=str(i),
        scene="s",
        difficulty=difficulty,
        success=ok,
        geodesic_start=geo,
        path_length=p,
        final_geodesic=final_geo,
        final_euclidean=final_geo,
        success_radius=r,
        collisions=collisions,
    )


def test_single_record_metrics():
    a = rec(0, "easy", True, 2.0, 4.0, 0.5)
    assert success(a) == 1.0 and spl(a) == 0.5 and dts(a) == 0.0
    b = rec(1, "easy", True, 3.0, 2.5, 0.7)  # path shorter than l (success radius): SPL capped at 1
    assert spl(b) == 1.0
    c = rec(2, "hard", False, 6.0, 9.0, 3.3)
    assert success(c) == 0.0 and spl(c) == 0.0 and dts(c) == pytest.approx(2.5)
    d = rec(3, "hard", False, 6.0, 9.0, 0.5)  # failed, but already inside the radius
    assert dts(d) == 0.0


def test_totals_are_pooled_over_episodes():
    recs = [rec(0, "easy", True, 2.0, 4.0, 0.5), rec(1, "hard", False, 6.0, 9.0, 3.3), rec(2, "hard", False, 6.0, 9.0, 2.8)]
    s = aggregate(recs)
    assert s["easy"].n == 1 and s["easy"].sr == 1.0 and s["easy"].spl == 0.5
    assert s["hard"].sr == 0.0 and s["hard"].dts == pytest.approx((2.5 + 2.0) / 2)
    assert math.isnan(s["medium"].sr) and s["medium"].n == 0
    # pooled: 1 success of 3 episodes = 1/3 (the mean of bin means would be (1 + 0) / 2 = 0.5)
    assert s["total"].sr == pytest.approx(1 / 3)
    assert s["total"].spl == pytest.approx(0.5 / 3)
    assert s["total"].dts == pytest.approx(4.5 / 3)
    table = format_table(s)
    assert "| total | 3 | 33.3 | 0.167 | 1.500 |" in table and "medium" not in table


def test_record_round_trip():
    r = rec(0, "easy", True, 2.0, 4.0, 0.5)
    d = r.to_dict()
    assert d["format"] == "nue-record/1" and EpisodeRecord.from_dict(d) == r
    legacy = {k: v for k, v in d.items() if k != "format"}  # written before records carried a format
    assert EpisodeRecord.from_dict(legacy) == r
    with pytest.raises(ValueError, match="nue-record/2"):
        EpisodeRecord.from_dict({**d, "format": "nue-record/2"})
