"""Report: Table I cells by hand, Wilson intervals, paired bootstrap, paper numbers, coverage (curves; the figure
from nue.viz.coverage), RESULTS.md regeneration."""

from __future__ import annotations

import csv
import io
import dataclasses
import json
import math

import numpy as np
import pytest

from nue.evaluate import coverage as cov
from nue.evaluate import report as R
from nue.evaluate import results_md as RM
from nue.evaluate.metrics import EpisodeRecord
from nue.sim.task import CameraConfig
from nue.viz.coverage import write_coverage_figure

Z = 1.959963984540054


def rec(i, difficulty, ok, geo=2.0, p=2.0, final_geo=0.5, method="nue", scene="s0", **extra):
    return EpisodeRecord(episode_id=str(i), scene=scene, difficulty=difficulty, success=ok, geodesic_start=geo,
                         path_length=p, final_geodesic=final_geo, final_euclidean=final_geo, success_radius=0.8,
                         method=method, extra=dict(extra))


def hand_records():
    """NUE: easy 1/2 (SPL .5, DTS 2.5 on the failure), medium 1/1 (SPL 1), hard 0/1 (DTS .2)."""
    return [rec(0, "easy", True, 2.0, 4.0, 0.5), rec(1, "easy", False, 2.0, 6.0, 3.3),
            rec(2, "medium", True, 3.0, 3.0, 0.6), rec(3, "hard", False, 6.0, 9.0, 1.0)]


def wilson_by_roots(k, n):
    """Wilson's interval = the p solving (k/n - p)^2 = z^2 p (1 - p) / n (a quadratic in p)."""
    ph = k / n
    a, b, c = 1 + Z * Z / n, -(2 * ph + Z * Z / n), ph * ph
    disc = math.sqrt(b * b - 4 * a * c)
    return (-b - disc) / (2 * a), (-b + disc) / (2 * a)


def test_cells_by_hand():
    (row,) = R.build_table(hand_records())
    assert row.method == "nue" and row.label == "NUE (full)"
    assert list(row.cells) == ["easy", "medium", "hard", "total"]
    e, m, h, t = (row.cells[g] for g in ("easy", "medium", "hard", "total"))
    assert (e.n, e.successes, e.sr, e.spl, e.dts) == (2, 1, 0.5, pytest.approx(0.25), pytest.approx(1.25))
    assert (m.n, m.sr, m.spl, m.dts) == (1, 1.0, 1.0, 0.0)
    assert (h.n, h.sr, h.spl, h.dts) == (1, 0.0, 0.0, pytest.approx(0.2))
    # totals pool the 4 episodes (not the mean of the three bins)
    assert (t.n, t.successes, t.sr) == (4, 2, 0.5)
    assert t.spl == pytest.approx((0.5 + 0 + 1 + 0) / 4) and t.dts == pytest.approx((0 + 2.5 + 0 + 0.2) / 4)
    for c, k in ((e, 1), (m, 1), (h, 0), (t, 2)):
        assert (c.sr_lo, c.sr_hi) == pytest.approx(wilson_by_roots(k, c.n), abs=1e-12)


def test_wilson_interval_known_values():
    assert R.wilson_interval(8, 10) == pytest.approx((0.4902, 0.9433), abs=1e-4)  # textbook 8 / 10
    assert R.wilson_interval(1, 2) == pytest.approx((0.0945, 0.9055), abs=1e-4)
    lo, hi = R.wilson_interval(0, 20)
    assert lo == 0.0 and hi == pytest.approx(wilson_by_roots(0, 20)[1]) and hi > 0
    assert R.wilson_interval(20, 20)[1] == 1.0
    assert all(math.isnan(v) for v in R.wilson_interval(0, 0))


def test_method_names_and_order():
    recs = [rec(0, "easy", True, method=m) for m in ("custom", "NUE (full)", "fr", "abl_fu_at", "Nav-A3C", "abl_none")]
    recs.append(rec(1, "easy", False, method="nue"))  # same method as "NUE (full)"
    rows = R.build_table(recs)
    assert [r.method for r in rows] == ["fr", "nav_a3c", "abl_none", "abl_fu_at", "nue", "custom"]
    assert rows[4].cells["total"].n == 2
    assert R.canonical_method("ablation f_u=on AT=off CBAM=on") == "abl_fu_cbam"
    assert R.method_label("abl_at_cbam") == "f_u=off AT=on CBAM=on"


def test_formats_markdown_csv_latex():
    rows = R.build_table(hand_records() + [rec(9, "easy", False, method="fr")])
    md = R.format_markdown(rows, R.paper_table())
    lines = md.splitlines()
    assert lines[0].startswith("| method | n | Easy SR % | Easy SPL | Easy DTS | Medium SR %")
    fr, fr_paper, nue, nue_paper = lines[2:6]
    assert fr.startswith("| FR | 1 | 0.0 [0.0, 79.3] |") and "*22.37*" in fr_paper and "*0.012*" in fr_paper
    assert nue.startswith("| NUE (full) | 4 | 50.0 [9.5, 90.5] | 0.250 | 1.250 | 100.0 [20.7, 100.0] | 1.000 | 0.000 |")
    assert nue.endswith("| 50.0 [15.0, 85.0] | 0.375 | 0.675 |") and "*59.65*" in nue_paper
    table = list(csv.DictReader(io.StringIO(R.format_csv(rows, R.paper_table()))))
    assert [(r["method"], r["source"]) for r in table] == [("fr", "ours"), ("fr", "paper"), ("nue", "ours"), ("nue", "paper")]
    assert table[2]["total_n"] == "4" and table[2]["total_sr"] == "50.00" and table[2]["total_dts"] == "0.6750"
    assert table[2]["hard_sr_hi"] == f"{100 * wilson_by_roots(0, 1)[1]:.2f}" and table[3]["total_sr"] == "59.65"
    tex = R.format_latex(rows, R.paper_table())
    assert tex.startswith(r"\begin{tabular}{l ccc ccc ccc ccc}") and r"\toprule" in tex and r"\bottomrule" in tex
    assert r"NUE (full) & 50.0\,{\scriptsize[9.5, 90.5]} & 0.250 & 1.250" in tex
    assert tex.count(r"\\") == 2 + 4  # 2 header rows + 4 table rows


def test_paper_table_data():
    p = R.paper_table()
    assert len(p) == 13 and {m.key for m in R.METHODS if m.paper_row} <= set(p)
    assert {m.key for m in R.METHODS if not m.paper_row} == {"sling+fr", "sling+nav_a3c", "sling+nue"}
    assert p["nue"]["total"] == (59.65, 0.385, 2.053)
    assert p["fr"]["total"][1] == 0.012  # the paper's typo, kept as printed
    assert p["abl_fu_at"]["easy"] == (62.23, 0.422, 1.406) and "SLING+OVRL" in p


def test_paired_difference_identical_methods_is_zero():
    recs = [rec(i, "easy", i % 3 == 0, 2.0, 2.0 + i / 10, method=m) for m in ("nue", "abl_fu") for i in range(30)]
    (sr, sp) = R.paired_differences(recs)
    for d in (sr, sp):
        assert d.method == "abl_fu" and d.n_pairs == 30
        assert (d.mean, d.lo, d.hi) == (0.0, 0.0, 0.0) and not d.resolved
    assert sr.verdict() == "not resolved (CI contains 0)"


def test_paired_difference_better_everywhere_is_resolved():
    recs = [rec(i, "hard", False, 6.0, 9.0, 3.0, scene=f"s{i % 2}") for i in range(20)]  # NUE fails everywhere
    recs += [rec(i, "hard", True, 6.0, 6.0 + 0.1 * i, 0.5, method="abl_none", scene=f"s{i % 2}") for i in range(20)]
    recs += [rec(99, "hard", True, method="abl_none")]  # NUE never ran it: ignored
    sr, sp = R.paired_differences(recs)
    assert sr.n_pairs == 20 and (sr.mean, sr.lo, sr.hi) == (1.0, 1.0, 1.0)
    assert sp.mean == pytest.approx(np.mean([6.0 / (6.0 + 0.1 * i) for i in range(20)]))
    assert 0 < sp.lo < sp.mean < sp.hi <= 1.0 and sp.resolved
    assert sp.verdict() == "resolved: f_u=off AT=off CBAM=off ahead"
    nue_better = R.paired_differences([rec(i, "easy", True) for i in range(5)] +
                                      [rec(i, "easy", False, method="fr") for i in range(5)])[0]
    assert nue_better.hi < 0 and nue_better.verdict() == "resolved: NUE (full) ahead"
    assert R.paired_differences([rec(0, "easy", True, method="fr")]) == []  # no NUE records
    md = R.format_paired_markdown([sr, sp])
    assert "| f_u=off AT=off CBAM=off | 20 | +100.0 [+100.0, +100.0] | resolved" in md


def test_paired_bootstrap_matches_normal_approximation():
    d = np.tile([0.0, 1.0], 250)  # 500 pairs, mean .5, sd .5
    mean, lo, hi = R.paired_bootstrap(d, n_boot=10_000, seed=0)
    half = Z * 0.5 / math.sqrt(500)
    assert mean[0] == 0.5 and lo[0] == pytest.approx(0.5 - half, abs=0.01) and hi[0] == pytest.approx(0.5 + half, abs=0.01)
    again = R.paired_bootstrap(d, n_boot=10_000, seed=0)
    assert (again[1][0], again[2][0]) == (lo[0], hi[0])


def test_coverage_curves_and_pure_functions(box_nav):
    a = np.zeros(box_nav.free.shape, bool)
    a[0, :2] = True
    b = a.copy()
    b[5, 5] = True
    np.testing.assert_allclose(cov.coverage_curve([a, b, a], 0.0025), [0.005, 0.0075, 0.0075])
    recs = [rec(0, "easy", True, coverage=[1.0, 2.0, 3.0]), rec(1, "easy", True, coverage=[2.0]),
            rec(2, "easy", True, method="fr", coverage=[4.0, 4.0]), rec(3, "easy", True, method="fr")]
    curves = cov.mean_coverage_curves(recs, ["fr", "nue"])
    assert list(curves) == ["fr", "nue"]
    np.testing.assert_allclose(curves["nue"], [1.5, 2.0, 2.5])  # the ended episode holds its final area
    np.testing.assert_allclose(curves["fr"], [4.0, 4.0, 4.0])


def test_seen_floor_cells_flat_floor(box_nav):
    """Analytic z-depth of an infinite floor 0.6 m below the camera; the robot at (0, 0) looks along +x."""
    cam = CameraConfig()
    v = (np.arange(cam.height) + 0.5 - cam.cy) / cam.fy
    depth = np.where(v > 0, 0.6 / np.maximum(v, 1e-9), 0.0)[:, None].repeat(cam.width, axis=1)
    seen = cov.seen_floor_cells(depth, (0.0, 0.0, 0.0), cam, box_nav, floor_z=0.0)
    xy = box_nav.cell_centre(np.argwhere(seen))
    assert seen.sum() > 100
    assert xy[:, 0].min() > 0.8 - 0.05  # the lowest image row sees the floor 0.6 * 120 / 90 = 0.8 m ahead
    assert np.hypot(xy[:, 0], xy[:, 1]).max() <= 5.0 + 0.05  # range limit
    assert np.all(np.abs(xy[:, 1]) <= xy[:, 0] + 0.05)  # 90 deg field of view
    for ahead in ((1.0, 0.0), (2.0, 0.5), (3.0, -1.0)):
        assert seen[tuple(box_nav.cell_of(ahead))]
    for unseen in ((-1.0, 0.0), (0.5, 0.0), (1.0, 1.5)):
        assert not seen[tuple(box_nav.cell_of(unseen))]
    # area of {x >= 0.8, |y| <= x, x^2 + y^2 <= 25}, the floor inside the view and the range
    g = np.mgrid[0:5:0.005, -5:5:0.005].reshape(2, -1)
    wedge = ((g[0] >= 0.8) & (np.abs(g[1]) <= g[0]) & (np.hypot(g[0], g[1]) <= 5.0)).sum() * 0.005 ** 2
    assert seen.sum() * 0.05 ** 2 == pytest.approx(wedge, rel=0.03)
    # turned by 90 degrees: the same set rotated
    seen_left = cov.seen_floor_cells(depth, (0.0, 0.0, math.pi / 2), cam, box_nav, floor_z=0.0)
    assert seen_left[tuple(box_nav.cell_of((0.0, 2.0)))] and not seen_left[tuple(box_nav.cell_of((2.0, 0.0)))]


def test_coverage_figure_lines_pool_seeds_and_leave_out_earlier_recipes(tmp_path):
    """One line per current row in Table I order, seeds pooled with their min-max band (hand-computed), an ended
    episode holding its last area, earlier recipes' rows left out, a style per kind of row."""
    from nue.viz.coverage import coverage_lines, plot_coverage

    recs = [rec(0, "easy", True, method="nue", coverage=[1.0, 2.0, 3.0]),
            rec(1, "easy", True, method="nue", coverage=[3.0, 4.0]),  # ended at step 2: holds 4.0
            rec(0, "easy", True, method="nue@s1", coverage=[5.0, 6.0, 7.0]),
            rec(1, "easy", True, method="nue@s1", coverage=[5.0, 6.0, 7.0]),
            rec(0, "easy", True, method="nue_v6", coverage=[9.0, 9.0, 9.0]),
            rec(0, "easy", True, method="expert", coverage=[1.0, 1.0, 1.0]),
            rec(0, "easy", True, method="nue+swap", coverage=[2.0, 2.0, 2.0]),
            rec(0, "easy", True, method="fr", coverage=[0.5, 1.5, 2.5]),
            rec(1, "easy", True, method="fr")]  # no coverage: not in the mean
    lines = coverage_lines(recs)
    assert [(ln.key, ln.kind, ln.seeds) for ln in lines] == [
        ("fr", "baseline", 1), ("nue", "nue", 2), ("expert", "reference", 1), ("nue+swap", "control", 1)]
    nue = lines[1]
    assert nue.label == "NUE (full) (2 seeds)"
    # seed 0: mean of [1, 2, 3] and [3, 4, 4] = [2, 3, 3.5]; seed 1: [5, 6, 7]; pooled over the 4 episodes
    assert nue.mean.tolist() == [3.5, 4.5, 5.25]
    assert nue.band[0].tolist() == [2.0, 3.0, 3.5] and nue.band[1].tolist() == [5.0, 6.0, 7.0]
    assert lines[0].band is None and lines[0].mean.tolist() == [0.5, 1.5, 2.5]
    path = plot_coverage(lines, tmp_path / "c.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert coverage_lines([r for r in recs if r.method == "nue_v6"]) == []
    assert plot_coverage([], tmp_path / "empty.png").is_file()


def test_write_report_and_results_md_regenerate(tmp_path):
    recs = hand_records() + [rec(i, d, i % 2 == 0, method=m, coverage=[0.5 * (k + 1) for k in range(10 + i)])
                             for m in ("fr", "abl_fu") for i, d in enumerate(("easy", "easy", "medium", "hard"))]
    paths = {**R.write_report(recs, tmp_path / "rep"), **write_coverage_figure(recs, tmp_path / "rep")}
    assert sorted(paths) == ["coverage.png", "table.csv", "table.md", "table.tex"]
    assert all(p.is_file() and p.stat().st_size > 0 for p in paths.values())
    assert paths["coverage.png"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "## Paired differences to NUE" in paths["table.md"].read_text()
    meta = {"command": "nue eval --split val", "date": "2025-01-02", "commit": "abc1234", "machine": "2 vCPU",
            "task": "paper"}
    text = RM.render_results_md(recs, meta)
    (tmp_path / "RESULTS.md").write_text(text)
    jsonl = tmp_path / "records.jsonl"
    jsonl.write_text("".join(json.dumps(r.to_dict()) + "\n" for r in recs) + "\n")
    again = RM.render_results_md(R.load_records(jsonl), dict(reversed(list(meta.items()))))
    assert again.encode() == (tmp_path / "RESULTS.md").read_bytes()
    for s in ("| command | `nue eval --split val` |", "| commit | abc1234 |", "*59.65*", "Wilson",
              "| NUE (full) | 1 / 2 | 1 / 1 | 0 / 1 | 2 / 4 |", "## Exploration coverage", "## Ordering by total SR"):
        assert s in text


def test_results_md_puts_earlier_recipes_in_their_own_table():
    """``nue_v2`` (all four episodes failed) is not a Table I row and not in the ordering, but has its own table and
    its paired difference to NUE: -0.5 SR (NUE won 2 of the 4 episodes)."""
    recs = hand_records() + [rec(i, d, False, method="nue_v2") for i, d in enumerate(("easy", "easy", "medium", "hard"))]
    text = RM.render_results_md(recs, {"command": "x"})
    table1 = text.split("## Table I")[1].split("## Earlier recipes")[0]
    earlier = text.split("## Earlier recipes")[1].split("## ")[0]
    assert "| NUE (full) | 4 |" in table1 and "nue_v2" not in table1
    assert "| nue_v2 | 4 | 0.0 [0.0, 65.8] |" in earlier and "NUE (full)" not in earlier
    assert "| nue_v2 | 4 | -50.0 [" in text.split("## Paired differences to NUE")[1]
    assert RM.is_earlier_recipe("fr_v12") and not RM.is_earlier_recipe("fr") and not RM.is_earlier_recipe("v2_nue")
    assert RM.is_earlier_recipe("nue_v5a") and RM.is_earlier_recipe("nue_v5a+swap") and not RM.is_earlier_recipe("nue+swap")
    assert "## Earlier recipes" not in RM.render_results_md(hand_records(), {"command": "x"})
    # in a further set's section (the 84-episode set beside the 252-episode one): its own earlier-recipes table
    section = RM.render_results_md(hand_records(), {"command": "x"}, sets={"val": recs}).split("## Table I on `val`")[1]
    table1, rest = section.split("Earlier recipes on `val`")
    assert "| NUE (full) | 4 |" in table1 and "nue_v2" not in table1
    assert "| nue_v2 | 4 | 0.0 [0.0, 65.8] |" in rest.split("\n\n")[1] and "| nue_v2 | 4 | -50.0 [" in rest
    assert "Earlier recipes on" not in RM.render_results_md(hand_records(), {"command": "x"}, sets={"val": hand_records()})


def test_seen_floor_cells_rendered_occlusion(box_nav, box_renderer):
    """Looking south at the 1 m high box at (1.0, -2.0): the floor behind it and behind the walls is not seen."""
    cam = CameraConfig()
    pose = (1.0, 0.5, -math.pi / 2)
    _, depth = box_renderer.render(pose, 0.0)
    seen = cov.seen_floor_cells(depth, pose, cam, box_nav, floor_z=0.0)
    for xy in ((1.0, -1.0), (1.0, -1.6), (2.0, -2.5), (0.0, -2.5)):
        assert seen[tuple(box_nav.cell_of(xy))], xy
    for xy in ((1.0, -2.0), (1.0, -2.6), (1.0, -3.3), (1.0, 1.0), (1.0, 0.0)):
        assert not seen[tuple(box_nav.cell_of(xy))], xy
    tracker = cov.CoverageTracker(cam, box_nav, 0.0)
    step = type("Step", (), {"obs": {"depth": depth[..., None], "pose": np.array(pose)}})
    tracker(step)
    tracker(step)
    assert tracker.areas[0] == tracker.areas[1] == pytest.approx(seen.sum() * 0.0025)


def test_results_md_gives_each_further_episode_set_its_own_section(tmp_path, capsys):
    """``sets``: a section per further set, after the main tables and before the discussion, with that set's own
    counts and paired differences (FR lost all 4 there: -50 points against NUE's 2 / 4); ``nue report --set`` writes
    the same text and a report folder per set."""
    main = hand_records() + [rec(i, d, True, method="fr") for i, d in enumerate(("easy", "easy", "medium", "hard"))]
    plain = hand_records() + [rec(i, d, False, method="fr") for i, d in enumerate(("easy", "easy", "medium", "hard"))]
    meta = {"command": "x", "discussion": "the end"}
    text = RM.render_results_md(main, meta, sets={"val_plain": plain})
    assert text.index("## Table I on `val_plain`: 14 houses of the held-out plain") < text.index("## Discussion")
    section = text.split("## Table I on `val_plain`")[1].split("## Discussion")[0]
    assert "| FR | 0 / 2 | 0 / 1 | 0 / 1 | 0 / 4 |" in section and "| FR | 2 / 2 |" not in section
    assert "| FR | 4 | -50.0 [" in section and "| FR | 4 | +50.0 [" in text.split("## Table I on")[0]
    # the main tables do not depend on the further sets; the claims across sets come after their sections
    alone = RM.render_results_md(main, meta)
    assert alone.split("## NUE against every baseline")[0] == text.split("## Table I on `val_plain`")[0]
    assert alone.endswith("## Discussion\n\nthe end\n") and "`val_plain`: ΔSR" in text.split("## NUE against")[1]
    # the same through the CLI, with the meta beside RESULTS.md
    from tests.test_bad_input import run_cli

    files = {}
    for name, recs in (("main", main), ("plain", plain)):
        files[name] = tmp_path / f"{name}.jsonl"
        files[name].write_text("".join(json.dumps(r.to_dict()) + "\n" for r in recs))
    (tmp_path / "RESULTS.meta.json").write_text(json.dumps(meta))
    code, out, err = run_cli(capsys, "report", files["main"], "--set", f"val_plain={files['plain']}",
                             "--out", tmp_path / "rep", "--results-md", tmp_path / "RESULTS.md")
    assert code == 0, err
    assert (tmp_path / "RESULTS.md").read_text() == text
    assert (tmp_path / "rep" / "val_plain" / "table.md").is_file()
    # --name names the main records (the pooled section would say "`val252` + `val_plain`"); the --set names stay
    other = [rec(i, d, i < 2, method=m, scene="s1") for m in ("nue", "fr") for i, d in enumerate(("easy", "easy", "medium", "hard"))]
    files["other"] = tmp_path / "other.jsonl"
    files["other"].write_text("".join(json.dumps(r.to_dict()) + "\n" for r in other))
    code, out, err = run_cli(capsys, "report", files["main"], "--name", "val252", "--set", f"val_plain={files['other']}",
                             "--out", tmp_path / "rep3", "--results-md", tmp_path / "RESULTS.md")
    assert code == 0, err
    named = (tmp_path / "RESULTS.md").read_text()
    assert "## Pooled: `val252` + `val_plain`\n" in named  # other houses (s1): both sets pooled
    assert named == RM.render_results_md(main, meta, sets={"val_plain": other}, main_name="val252")
    code, out, err = run_cli(capsys, "report", files["main"], "--set", "val_plain", "--out", tmp_path / "rep2")
    assert code == 2 and "NAME=FILE" in err and not (tmp_path / "rep2").exists()


def test_two_further_sets_are_also_pooled_over_the_methods_that_ran_both():
    """Set a: NUE 2 / 4, FR 4 / 4, Nav-A3C only here; set b (other houses): NUE 2 / 4, FR 0 / 4. Pooled: 8 pairs,
    FR - NUE = (2 + -2) / 8 = 0 points, NUE 4 / 8 and FR 4 / 8; Nav-A3C is left out (it did not run set b), as is an
    earlier recipe's row. One set alone gets no pooled section."""
    a = hand_records() + [rec(i, d, True, method="fr") for i, d in enumerate(("easy", "easy", "medium", "hard"))]
    a += [rec(i, d, True, method="nav_a3c") for i, d in enumerate(("easy", "easy", "medium", "hard"))]
    b = [rec(i, d, ok, method="nue", scene="s1") for i, d, ok in ((0, "easy", True), (1, "easy", True),
                                                                     (2, "medium", False), (3, "hard", False))]
    b += [rec(i, d, False, method="fr", scene="s1") for i, d in enumerate(("easy", "easy", "medium", "hard"))]
    b += [rec(i, d, True, method="fr_v1", scene="s1") for i, d in enumerate(("easy", "easy", "medium", "hard"))]
    text = RM.render_results_md(hand_records(), {"command": "x"}, sets={"val252": a, "val_plain": b})
    pooled = text.split("## Pooled: `val252` + `val_plain`")[1].split("\n## ")[0]  # up to the next section
    assert "| FR | 8 | +0.0 [" in pooled and "Nav-A3C" not in pooled and "fr_v1" not in pooled
    assert "| NUE (full) | 8 | " in pooled and "| FR | 8 | " in pooled
    table = pooled.split("Ordering by total SR, pooled")[0]
    assert "| 50.0 [" in table.split("| NUE (full) | 8 |")[1].split("\n")[0]
    assert "## Pooled" not in RM.render_results_md(hand_records(), {"command": "x"}, sets={"val252": a})
    # as nue reproduce calls it: the main records are the larger set, a further set is inside them and is left out
    val = [r for r in a if r.episode_id in ("0", "1")]  # the first episodes of a, as episodes/val of val252
    again = RM.render_results_md(a, {"command": "x"}, sets={"val": val, "val_plain": b})
    assert "## Pooled: Table I's episodes + `val_plain`\n" in again and "| FR | 8 | +0.0 [" in again.split("## Pooled")[1]
    named = RM.render_results_md(a, {"command": "x"}, sets={"val": val, "val_plain": b}, main_name="val252")
    claims = "\n## NUE against every baseline"
    assert named.split(claims)[0] == again.split(claims)[0].replace("## Pooled: Table I's episodes + `val_plain`\n",
                                                                    "## Pooled: `val252` + `val_plain`\n")
    # the claims across sets: named, the main set is val252, which holds val's episodes, so val is no column of its own
    assert "`val`: ΔSR" in again.split(claims)[1] and "`val`: ΔSR" not in named.split(claims)[1]
    assert "`val252`: ΔSR" in named.split(claims)[1]


def test_an_episode_ending_off_the_planning_grid_is_left_out_of_dts_only():
    """A failure whose final geodesic is inf (a pocket the planning grid does not connect to the goal) has no DTS:
    the DTS mean is over the other episodes (easy: 2.5 from the hand records' failure, not inf), SR and SPL
    still count it as a failure, and the report names it."""
    pocket = rec(9, "easy", False, final_geo=math.inf)
    recs = hand_records() + [pocket]
    rows = {r.method: r for r in R.build_table(recs)}
    easy = rows["nue"].cells["easy"]
    assert easy.n == 3 and easy.successes == 1 and easy.dts == pytest.approx((0.0 + 2.5) / 2)
    assert easy.spl == pytest.approx(0.5 / 3)
    assert math.isfinite(rows["nue"].cells["total"].dts)
    text = RM.render_results_md(recs, {"command": "x"})
    assert "Left out of DTS (1 episode(s); failures in SR and SPL): NUE (full) s0/9," in text
    assert "Left out of DTS" not in RM.render_results_md(hand_records(), {"command": "x"})


# --- several training seeds per method ------------------------------------------------------------
SEEDED = {  # method run -> success on episodes 0..3 (easy, easy, medium, hard); SPL 1 on success, DTS 1.0 on failure
    "nue": (1, 1, 0, 0), "nue@s1": (1, 0, 0, 0),
    "abl_at_cbam": (1, 1, 1, 0), "abl_at_cbam@s1": (1, 1, 0, 0), "abl_at_cbam@s2": (1, 1, 1, 1),
    "fr": (0, 0, 1, 0),
}


def seeded_records():
    bins = ("easy", "easy", "medium", "hard")
    return [rec(i, bins[i], bool(ok), 2.0, 2.0, 0.5 if ok else 1.8, method=m)
            for m, oks in SEEDED.items() for i, ok in enumerate(oks)]


def test_a_method_with_several_seeds_is_one_row_of_seed_means_with_their_range():
    """NUE's two seeds: totals 2 / 4 and 1 / 4 -> SR .375 (.25-.5), SPL the same, DTS .5 and .75 -> .625; easy 2 / 2
    and 1 / 2 -> .75 (.5-1), DTS 0 and .5 -> .25. The no-f_u ablation's three: 3, 2, 4 of 4 -> .75 (.5-1). FR stays a
    single run with its Wilson interval."""
    rows = {r.method: r for r in R.build_table(seeded_records())}
    assert list(rows) == ["fr", "abl_at_cbam", "nue"]
    nue, abl, fr = rows["nue"], rows["abl_at_cbam"], rows["fr"]
    assert (nue.seeds, nue.runs, abl.runs, fr.seeds, fr.runs) == (2, ("nue", "nue@s1"),
                                                                  ("abl_at_cbam", "abl_at_cbam@s1", "abl_at_cbam@s2"), 1, ())
    t = nue.cells["total"]
    assert (t.n, t.successes, t.sr, t.spl, t.dts) == (8, 3, pytest.approx(0.375), pytest.approx(0.375), pytest.approx(0.625))
    assert math.isnan(t.sr_lo) and math.isnan(t.sr_hi)  # no Wilson interval over the seeds' runs of one episode
    assert (t.spread.seeds, t.spread.sr, t.spread.spl, t.spread.dts) == (2, (0.25, 0.5), (0.25, 0.5), (0.5, 0.75))
    assert (t.spread.successes, t.spread.episodes) == ((2, 1), (4, 4))
    e = nue.cells["easy"]
    assert (e.sr, e.spread.sr, e.dts, e.spread.dts) == (0.75, (0.5, 1.0), pytest.approx(0.25), (0.0, 0.5))
    assert (abl.cells["total"].sr, abl.cells["total"].spread.sr) == (pytest.approx(0.75), (0.5, 1.0))
    assert [c.sr for c in abl.seed_totals] == [0.75, 0.5, 1.0]
    assert fr.cells["total"].spread is None and fr.cells["total"].sr == 0.25 and fr.cells["total"].sr_hi > 0.25
    md = R.format_markdown(list(rows.values()), R.paper_table())
    assert ("| NUE (full) | 4 x 2 | 75.0 (50.0–100.0) | 0.750 (0.500–1.000) | 0.250 (0.000–0.500) | 0.0 (0.0–0.0) |"
            in md)
    assert md.count("| NUE (full) | 4 x 2 |") == 1 and "| FR | 4 | 0.0 [0.0, " in md
    assert "| 37.5 (25.0–50.0) | 0.375 (0.250–0.500) | 0.625 (0.500–0.750) |" in md
    counts = R.format_counts_markdown(list(rows.values()))
    assert "| NUE (full) | 2, 1 / 2 | 0, 0 / 1 | 0, 0 / 1 | 2, 1 / 4 |" in counts and "| FR | 0 / 2 | 1 / 1 |" in counts
    seeds = R.format_seeds_markdown(list(rows.values()))
    assert "| NUE (full) | `nue@s1` | 4 | 25.0 [" in seeds and seeds.count("\n") == 2 + 5  # header + 5 seeds' runs
    assert R.format_seeds_markdown([fr]) == "" and R.seed_notes([fr]) == ""
    table = {r["method"]: r for r in csv.DictReader(io.StringIO(R.format_csv(list(rows.values()))))}
    assert table["nue"]["seeds"] == "2" and table["fr"]["seeds"] == "1"
    assert (table["nue"]["total_sr"], table["nue"]["total_sr_min"], table["nue"]["total_sr_max"]) == ("37.50", "25.00", "50.00")
    assert table["nue"]["total_sr_lo"] == "" and table["fr"]["total_sr_min"] == ""
    assert "sr_min" not in R.format_csv([fr])  # a table of single runs keeps its columns
    assert r"37.5\,{\scriptsize(25.0--50.0)}" in R.format_latex(list(rows.values()))
    assert R.method_label("nue@s1") == "NUE (full) @s1" and R.method_label("custom@s1") == "custom@s1"


def test_runs_of_one_method_stand_together_and_seed_0_is_named_beside_the_others():
    keys = ["expert", "nue@s2", "fr", "vgm@s1", "nue", "vgm", "nue_v6@s1", "nue_v6", "nue@s1+swap", "nue+swap", "nue@s1"]
    assert R.order_methods(keys) == ["fr", "vgm", "vgm@s1", "nue", "nue@s1", "nue@s2", "expert", "nue+swap",
                                     "nue@s1+swap", "nue_v6", "nue_v6@s1"]
    assert R.order_methods(["nue@s1"]) == ["nue@s1"]  # a seed's run without its seed 0 still has its place
    assert [R.run_label(k, keys) for k in ("nue", "nue@s1", "fr", "nue+swap")] == [
        "NUE (full) @s0", "NUE (full) @s1", "FR", "nue+swap @s0"]
    assert R.run_label("nue", ["nue", "fr@s1"]) == "NUE (full)"  # no other seed of its own


def test_paired_differences_pool_seeds_x_episodes():
    """Per episode, each method's seed mean: no-f_u (1, 1, 2/3, 1/3), NUE (1, .5, 0, 0), FR (0, 0, 1, 0) -> SR
    differences +.375 and -.125; every (method seed, NUE seed) pair of runs has its own: 3 x 2 and 1 x 2."""
    diffs = {(d.method, d.metric): d for d in R.paired_differences(seeded_records())}
    abl, fr = diffs["abl_at_cbam", "sr"], diffs["fr", "sr"]
    assert (abl.n_pairs, abl.seeds, abl.reference_seeds, abl.mean) == (4, 3, 2, pytest.approx(0.375))
    assert (fr.seeds, fr.reference_seeds, fr.mean) == (1, 2, pytest.approx(-0.125))
    assert diffs["abl_at_cbam", "spl"].mean == pytest.approx(0.375)  # SPL is 1 on every success here
    assert [(p.run, p.reference_run) for p in abl.seed_pairs] == [
        (a, n) for a in ("abl_at_cbam", "abl_at_cbam@s1", "abl_at_cbam@s2") for n in ("nue", "nue@s1")]
    assert [p.mean for p in abl.seed_pairs] == pytest.approx([0.25, 0.5, 0.0, 0.25, 0.5, 0.75])
    assert abl.lo <= abl.mean <= abl.hi and len(fr.seed_pairs) == 2
    md = R.paired_markdown(list(diffs.values()))
    assert "| f_u=off AT=on CBAM=on | 4 (3 x 2 seeds) | +37.5 [" in md and "two-level bootstrap" in md


def test_the_two_level_bootstrap_sees_the_seeds_disagree():
    """A's two seeds: success everywhere / nowhere; the reference fails everywhere. The drawn A seeds' mean is 0, .5
    or 1 (probabilities 1/4, 1/2, 1/4) whatever episodes are drawn: estimate .5, 95% interval [0, 1]. Averaging the
    seeds first and resampling episodes only gives [.5, .5]. With one seed each it is the episode bootstrap."""
    a, b = np.stack([np.ones(50), np.zeros(50)]), np.zeros((1, 50))
    mean, lo, hi = R.seed_episode_bootstrap(a, b)
    assert (mean[0], lo[0], hi[0]) == (0.5, 0.0, 1.0)
    assert [v[0] for v in R.paired_bootstrap(a.mean(axis=0) - b[0])] == [0.5, 0.5, 0.5]
    rng = np.random.default_rng(3)
    x, y = rng.random((1, 40, 2)), rng.random((1, 40, 2))
    for got, want in zip(R.seed_episode_bootstrap(x, y, n_boot=2000), R.paired_bootstrap(x[0] - y[0], n_boot=2000)):
        assert got == pytest.approx(want)


def test_the_two_level_ratio_of_means():
    """A's two seeds see 2 and 4 m² from every start, the reference's one seed 2 m²: the drawn A seeds' mean is 2, 3
    or 4 m² whatever starts are drawn, so the ratio is 1.5 with 95% interval [1, 2]."""
    from nue.evaluate.stats import seed_episode_ratio

    a, b = np.stack([np.full(30, 2.0), np.full(30, 4.0)]), np.full((1, 30), 2.0)
    r, lo, hi = seed_episode_ratio(a, b)
    assert (r[0], lo[0], hi[0]) == (1.5, 1.0, 2.0)
    r, lo, hi = seed_episode_ratio(b, a)  # the other way round: 2 / 3, between 2 / 4 and 2 / 2
    assert r[0] == pytest.approx(2 / 3) and (lo[0], hi[0]) == (0.5, 1.0)


def test_a_verdict_that_depends_on_the_seed_is_named():
    """f_u alone: seed 0 succeeds on all 30 episodes, seed 1 on none, like NUE (one run). Seed 0 vs NUE is resolved,
    seed 1 vs NUE not; pooled over seeds x episodes the interval is [0, +100] (not resolved)."""
    recs = [rec(i, "easy", False) for i in range(30)]
    recs += [rec(i, "easy", True, method="abl_fu") for i in range(30)]
    recs += [rec(i, "easy", False, method="abl_fu@s1") for i in range(30)]
    sr, _ = R.paired_differences(recs)
    assert (sr.mean, sr.lo, sr.hi, sr.resolved) == (0.5, 0.0, 1.0, False)
    assert [(p.run, p.mean, p.lo, p.hi) for p in sr.seed_pairs] == [("abl_fu", 1.0, 1.0, 1.0), ("abl_fu@s1", 0.0, 0.0, 0.0)]
    note = R.seed_dependence_markdown([sr])
    assert note == ("- f_u=on AT=off CBAM=off vs NUE (full), SR: pooled not resolved (CI contains 0); of the 2 pairs of "
                    "seeds' runs 1 resolved with f_u=on AT=off CBAM=off ahead, 1 not resolved\n")
    md = R.paired_markdown([sr])
    assert "| f_u=on AT=off CBAM=off | 30 (2 x 1 seeds) | +50.0 [+0.0, +100.0] | not resolved" in md
    assert md.endswith(f"Verdicts that depend on the seed:\n\n{note}")
    agree = R.paired_differences([r for r in recs if r.method != "abl_fu@s1"])
    assert R.seed_dependence_markdown(agree) == ""
    assert R.paired_markdown(agree) == R.format_paired_markdown(agree) + f"\n{R.HOLM_NOTE}\n"


def test_bootstrap_p_and_holm_by_hand():
    """p = 2 min(P(mean <= 0), P(mean >= 0)) of the resamples; Holm rejects in order of p while p <= alpha / (m - i)."""
    from nue.evaluate.stats import bootstrap_p, holm

    means = np.array([[-0.1, 0.0], [0.2, 0.0], [0.3, 0.1], [0.4, 0.1], [0.5, 0.2]] * 2)  # 10 resamples, 2 columns
    assert bootstrap_p(means).tolist() == pytest.approx([0.4, 0.8])  # 2 of 10 <= 0; 4 of 10 are 0 (count as <= 0)
    assert holm([0.01, 0.04, 0.03]) == [True, False, False]  # 0.01 <= .05/3; 0.03 > .05/2 stops
    assert holm([0.01, 0.02, 0.04]) == [True, True, True]  # .0167, .025, .05
    assert holm([0.2, float("nan"), 0.01]) == [False, False, True]  # NaN neither rejects nor counts: .01 <= .05/2
    assert holm([]) == []


def test_the_paired_table_says_which_verdicts_survive_holm():
    """Three rows against NUE on the same 40 episodes: one better everywhere (p = 0, holds), one better on 5 of 40
    episodes only (resolved alone, p about 0.01: holds at Holm's second threshold .05/2), one better on 1 of 40 (not
    resolved: no Holm cell); with p 0.04 the second no longer holds."""
    n = 40
    recs = [rec(i, "easy", False) for i in range(n)]
    recs += [rec(i, "easy", True, method="abl_none") for i in range(n)]
    recs += [rec(i, "easy", i < 5, method="abl_fu") for i in range(n)]
    recs += [rec(i, "easy", i < 1, method="fr") for i in range(n)]
    diffs = R.paired_differences(recs, metrics=("sr",))
    by = {d.method: d for d in diffs}
    assert by["abl_none"].p == 0.0 and by["abl_fu"].resolved and not by["fr"].resolved
    # 5 of 40 successes: P(resampled mean <= 0) = (35/40)^40 = 0.0048 -> p about 0.0097 <= .05/2 (second smallest)
    assert by["abl_fu"].p == pytest.approx(2 * (35 / 40) ** 40, abs=0.004)
    kept = R.holm_verdicts(diffs)
    assert kept == {("abl_none", "sr"): True, ("abl_fu", "sr"): True, ("fr", "sr"): False}
    md = R.format_paired_markdown(diffs)
    assert "Holm over 3 rows" in md and md.count("| holds |") == 2
    strict = [dataclasses.replace(d, p=0.04) if d.method == "abl_fu" else d for d in diffs]
    assert R.holm_verdicts(strict)[("abl_fu", "sr")] is False
    assert "not resolved (p 0.040)" in R.format_paired_markdown(strict)


def test_results_md_with_seeds_has_the_seed_notes_and_a_single_seed_one_has_none():
    seeded = RM.render_results_md(seeded_records(), {"command": "nue reproduce --recipe v7"})
    assert "| NUE (full) | 4 x 2 |" in seeded and "Training seeds (each run's totals):" in seeded
    assert R.SEED_NOTES in seeded and R.PAIRED_SEED_NOTES in seeded
    covered = [rec(0, "easy", True, method=m, coverage=c)
               for m, c in (("nue", [1.0, 3.0]), ("nue@s1", [2.0, 5.0]), ("fr", [1.0, 1.0]),
                            ("nue_v6", [9.0, 9.0]), ("nue_v6@s1", [9.0, 9.0]))]
    curves = R.coverage_curves(covered)
    assert list(curves) == ["fr", "nue"] and curves["nue"].tolist() == [1.5, 4.0]  # the seeds' runs averaged
    # earlier recipes' rows are left out (another seen-floor definition before 7a2b8f9), and the note says so
    text = RM.render_results_md(covered, {"command": "nue reproduce --recipe v7"})
    coverage = text.split("## Exploration coverage")[1].split("\n## ")[0]
    assert R.COVERAGE_NOTE in coverage and "| NUE (full) | 4.0 |" in coverage and "nue_v6" not in coverage
    plain = RM.render_results_md(hand_records(), {"command": "nue reproduce --recipe v6"})
    assert "Training seeds" not in plain and "two-level" not in plain


def test_sling_rows_are_labelled_and_carry_the_paper_s_sling_totals():
    from types import SimpleNamespace

    rows = [SimpleNamespace(method="nue"), SimpleNamespace(method="sling+nue@s1")]
    note = R.sling_notes(rows)
    assert "SLING+OVRL 56.64% SR, SPL 0.379" in note and "SLING+DDPPO 33.50% SR" in note  # paper_table1.csv's totals
    assert R.sling_notes(rows[:1]) == ""
    assert R.method_label("sling+nue@s1") == "SLING + NUE @s1" and R.canonical_method("SLING + FR") == "sling+fr"


def test_memory_baseline_rows_carry_the_paper_s_rows_and_the_msm_note():
    from types import SimpleNamespace

    paper = R.paper_table()
    assert paper["vgm"]["total"][0] == 41.37 and paper["nrns"]["total"][0] == 30.73  # paper_table1.csv, VGM / NRNS
    assert R.method_label("nrns@s2") == "NRNS @s2" and R.canonical_method("VGM") == "vgm"
    rows = [SimpleNamespace(method="nue"), SimpleNamespace(method="vgm@s1")]
    note = R.msm_note(rows)
    assert "not identified" in note and "30.50% SR, SPL 0.167" in note and "docs/msm.md" in note
    assert R.msm_note(rows[:1]) == ""


def test_report_reference_compares_candidates_to_a_variant_of_nue(tmp_path, capsys):
    """``nue report --reference nue_lean``: paired differences to it (NUE won 2 of 4 where nue_lean won 0: +50
    points); a reference with no records is a one-line error."""
    from tests.test_bad_input import run_cli

    recs = hand_records() + [rec(i, d, False, method="nue_lean") for i, d in enumerate(("easy", "easy", "medium", "hard"))]
    f = tmp_path / "r.jsonl"
    f.write_text("".join(json.dumps(r.to_dict()) + "\n" for r in recs))
    code, out, err = run_cli(capsys, "report", f, "--reference", "nue_lean", "--out", tmp_path / "rep")
    assert code == 0, err
    table = (tmp_path / "rep" / "table.md").read_text()
    assert "## Paired differences to nue_lean" in table and "| NUE (full) | 4 | +50.0 [" in table
    handoff = {"closest_geodesic": 5.0, "closest_step": 0, "exploit_steps": 0, "first_near_step": None,
               "first_seen_step": None, "outcome": "never_near", "search_steps": 9, "steps_near": 0}
    with_handoff = [dataclasses.replace(r, extra={**r.extra, "handoff": handoff}) for r in recs]
    R.write_report(with_handoff, tmp_path / "rep3", compare_to="nue_lean")
    assert "| method | episodes | nue_lean − method: never near" in (tmp_path / "rep3" / "table.md").read_text()
    code, out, err = run_cli(capsys, "report", f, "--reference", "vgm", "--out", tmp_path / "rep2")
    assert code == 2 and "--reference" in err and "'vgm'" in err and str(f) in err
