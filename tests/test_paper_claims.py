"""The paper's ablation ordering, step by step, on hand-made records whose outcomes decide each step."""

from __future__ import annotations

from nue.evaluate.paper_claims import STEPS, ablation_ordering_markdown, step_verdicts
from nue.sim.record import EpisodeRecord

N = 60


def _runs(method: str, successes: int, scene: str = "s0") -> list[EpisodeRecord]:
    """``N`` episodes of ``method``, the first ``successes`` of them successful."""
    return [EpisodeRecord(episode_id=f"e{i:03d}", scene=scene, difficulty="easy", success=i < successes,
                          geodesic_start=2.0, path_length=2.0, final_geodesic=0.5 if i < successes else 3.0,
                          final_euclidean=0.5, success_radius=0.8, method=method) for i in range(N)]


def test_the_ordering_holds_where_every_step_is_resolved_after_holm():
    # full 60/60 > each single 30/60 > all-off 0/60: every step +50 points on one set (paired on the same episodes)
    strong = _runs("nue", 60) + [r for m in ("abl_at_cbam", "abl_fu_cbam", "abl_fu_at") for r in _runs(m, 30)] \
        + _runs("abl_none", 0) + _runs("abl_fu", 60)  # f_u alone: no step
    # on the second set NUE equals the no-CBAM ablation (no step above 0) and the no-AT ablation did not run
    weak = _runs("nue", 30) + _runs("abl_at_cbam", 0) + _runs("abl_fu_at", 30) + _runs("abl_none", 0) \
        + _runs("nue_v6", 0)  # an earlier recipe's row: ignored
    sets = {"a": strong, "b": weak}
    diffs, holds = step_verdicts(sets)
    assert all(holds[(s, "a")] for s in STEPS)
    assert diffs[("nue", "abl_at_cbam")]["a"].mean == 0.5 and diffs[("abl_at_cbam", "abl_none")]["a"].mean == 0.5
    assert holds[(("nue", "abl_at_cbam"), "b")] and not holds[(("nue", "abl_fu_at"), "b")]
    assert holds[(("abl_fu_at", "abl_none"), "b")] and not holds[(("abl_at_cbam", "abl_none"), "b")]
    assert (("nue", "abl_fu_cbam"), "b") not in holds and ("abl_fu", "abl_none") not in diffs
    text = ablation_ordering_markdown(sets)
    assert "- `a`: the ordering holds; full > single ablation holds for 3 of 3 (without f_u, AT, CBAM), single " \
           "ablation > all ablated for 3 of 3 (without f_u, AT, CBAM)." in text
    assert "- `b`: the ordering is not shown; full > single ablation holds for 1 of 2 (without f_u), single " \
           "ablation > all ablated for 1 of 2 (without CBAM)." in text
    assert "| NUE (full) − f_u=off AT=on CBAM=on | +50.0 [" in text and "across the 10 cells" in text
    assert ablation_ordering_markdown({"c": _runs("nue", 10) + _runs("fr", 5)}) == ""


def test_nue_against_every_baseline_names_where_it_is_ahead_or_behind():
    from nue.evaluate.paper_claims import baselines_markdown

    a = _runs("nue", 50) + _runs("fr", 10) + _runs("nav_a3c", 48) + _runs("vgm", 60) + _runs("sling+fr", 10) \
        + _runs("sling+nue", 60)  # SLING around NUE is no baseline
    b = _runs("nue", 40) + _runs("fr", 0)
    text = baselines_markdown({"a": a, "b": b})
    assert "- `a`: NUE ahead of 2 of 4 baselines (FR, SLING + FR); behind VGM." in text
    assert "- `b`: NUE ahead of 1 of 1 baselines (FR)." in text
    assert "| NUE (full) − Nav-A3C | +3.3 [" in text and "SLING + NUE" not in text.split("\n\n", 2)[2]
    assert baselines_markdown({"c": _runs("nue", 10)}) == ""


def test_controls_say_reads_its_maps_and_uses_uncertainty_only_where_resolved():
    from nue.evaluate.paper_claims import controls_markdown

    # set a: NUE 50/60 and (seed 1) 40/60, mean 75%; swapped maps 10/60 for both seeds: +58.3 points; no f_u 45/60: 0
    a = _runs("nue", 50) + _runs("nue@s1", 40) + _runs("nue+swap", 10) + _runs("nue@s1+swap", 10) \
        + _runs("abl_at_cbam", 45) + _runs("fr", 0)  # FR is no control
    b = _runs("nue", 40) + _runs("abl_at_cbam", 0)  # set b: no swap run; f_u off 0/60
    text = controls_markdown({"a": a, "b": b})
    assert "- `a`: reads its maps: shown (NUE (full) − nue+swap +58.3 points [" in text
    assert "; uses uncertainty: not shown (NUE (full) − f_u=off AT=on CBAM=on +0.0 points [" in text
    assert "- `b`: uses uncertainty: shown (NUE (full) − f_u=off AT=on CBAM=on +66.7 points [" in text
    assert "reads its maps: shown" not in text.split("- `b`")[1] and "FR" not in text
    assert "(60, 2 x 2)" in text  # both seeds of NUE against both of the control
    assert controls_markdown({"c": _runs("nue", 10) + _runs("fr", 5)}) == ""
    # a lead whose interval excludes 0 but not after Holm across the table's cells is said so
    close = _runs("nue", 40) + _runs("nue+swap", 36)  # +6.7 [+1.7, +13.3], p 0.03 > 0.05 / 2
    assert "reads its maps: not shown after Holm (NUE (full) − nue+swap +6.7 points [+" in controls_markdown(
        {"a": a, "b": b, "c": close})
