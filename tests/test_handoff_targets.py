"""The hand-off issue's targets on hand-made records whose counts, SRs and coverage ratios decide each verdict."""

from __future__ import annotations

from nue.evaluate.handoff import Handoff
from nue.evaluate.handoff_targets import handoff_targets_markdown
from nue.sim.record import EpisodeRecord

N = 60


def _handoff(outcome: str, closest: float) -> dict:
    return Handoff(first_seen_step=None, first_near_step=None, closest_geodesic=closest, closest_step=0, steps_near=0,
                   search_steps=10, exploit_steps=0, outcome=outcome).to_dict()


def _runs(method: str, successes: int, near: int) -> list[EpisodeRecord]:
    """``N`` episodes: the first ``successes`` succeed; of the failures after them the first ``near`` came within 1 m
    of the goal (near misses), the rest never within 5 m (*never near*)."""
    out = []
    for i in range(N):
        ok, lost = i < successes, successes <= i < successes + near
        h = _handoff("success", 0.5) if ok else _handoff("found_then_lost", 1.0) if lost else _handoff("never_near", 5.0)
        out.append(EpisodeRecord(episode_id=f"e{i:03d}", scene="s0", difficulty="easy", success=ok, geodesic_start=4.0,
                                 path_length=4.0, final_geodesic=0.5 if ok else 5.0, final_euclidean=0.5,
                                 success_radius=0.8, method=method, extra={"handoff": h}))
    return out


def _explore(method: str, area: float) -> list[EpisodeRecord]:
    """Exploration runs from 6 starts: seen area growing linearly to ``area`` x (start + 1) m² at step 500."""
    return [EpisodeRecord(episode_id=f"x{i}", scene="s0", difficulty="easy", success=False, geodesic_start=4.0,
                          path_length=1.0, final_geodesic=4.0, final_euclidean=4.0, success_radius=0.8, method=method,
                          extra={"coverage": [area * (i + 1) * (t + 1) / 500 for t in range(500)]}) for i in range(6)]


def _row(text: str, start: str) -> list[str]:
    line = next(x for x in text.splitlines() if x.startswith(f"| {start}"))
    return [c.strip() for c in line.strip("|").split("|")][1:]


def test_each_target_s_verdict_follows_its_numbers():
    val252 = (_runs("nue", 57, 2) + _runs("nue@s1", 55, 3)  # SR 95.0 / 91.7; near misses 2 / 3; never near 1 / 2
              + _runs("nue_v6", 40, 10)  # 10 near misses -> at most 5
              + _runs("abl_at_cbam", 30, 10)  # 20 never near
              + _runs("fr", 56, 0))  # fails e056-e059: NUE's seed mean per episode matches it on average
    val_plain = _runs("nue", 50, 8)  # one seed, no v6 rows, no ablation
    explore = {"val252": _explore("nue", 20.0) + _explore("abl_at_cbam", 10.0),  # 2x everywhere
               "val_pale": _explore("nue", 12.0) + _explore("abl_at_cbam", 10.0)}  # 1.2x
    text = handoff_targets_markdown({"val252": val252, "val_plain": val_plain}, explore)
    assert "| target | `val252` | `val_plain` | `val_pale` |" in text

    near, never, seen, sr, no_fu, fr = (_row(text, s) for s in ("NUE's near misses", "NUE's *never near*",
                                                                "NUE's seen area", "NUE's SR", "NUE ahead of the no-f_u",
                                                                "NUE ahead of FR"))
    assert near == ["2.5 (2, 3) of 60; v6: 10 -> at most 5: **met**", "8 of 60; no v6 rows to halve", "–"]
    # never near: NUE 1 / 2 against 20; the paired rate difference is (1.5 - 20) / 60 = -30.8 points
    assert never[0].startswith("1.5 (1, 2) vs 20 of 60 (NUE − no f_u: -30.8 points [") and never[0].endswith(": **met**")
    assert never[1:] == ["–", "–"]
    assert seen == ["2.00 [2.00, 2.00] (6 starts, 1 x 1 seeds): **met**", "–",
                    "1.20 [1.20, 1.20] (6 starts, 1 x 1 seeds): not met"]  # ratio 2 >= 1.3; 1.2 is not
    assert sr == ["93.3% (95.0, 91.7) of 60: **met**", "83.3% of 60", "–"]
    # NUE - no f_u: seed mean (57 + 55) / 2 / 60 = 93.3% against 50%: +43.3 points, resolved
    assert no_fu[0].startswith("+43.3 points [") and no_fu[0].endswith("(60 episodes, 2 x 1 seeds): **met**")
    # NUE - FR: e055 0.5 - 1 and e056 0.5 - 0 cancel: +0.0 points, not met
    assert fr[0].startswith("+0.0 points [") and fr[0].endswith(": not met") and fr[1:] == ["–", "–"]
    assert "Met: 5 of 7." in text  # val252: all but FR; val_plain: no verdict (no reference); val_pale's ratio: not


def test_nothing_to_say_without_nue():
    assert handoff_targets_markdown({"val252": _runs("fr", 30, 5)}) == ""


def test_nue_alone_compares_nothing_and_one_seed_has_no_two_level_wording():
    assert handoff_targets_markdown({"val252": _runs("nue", 55, 3)}) == ""  # its SR alone: no section
    text = handoff_targets_markdown({"val252": _runs("nue", 55, 3) + _runs("abl_at_cbam", 30, 10)})
    assert "two-level" not in text and "several training seeds" not in text and "across the 1 paired SR cells" in text
    assert "| NUE's SR at least 90% on `val252` (seed mean; each seed's) | 91.7% of 60: **met** |" in text
