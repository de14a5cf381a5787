"""The generalisation table (issue 43, item 3): hand-computed SR / SPL and drops, seed means, the independent
bootstrap, paired differences on each family, the RESULTS.md section only when asked for, and ``nue report
--generalisation`` writing it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nue.evaluate.generalisation import generalisation_markdown, generalisation_rows, independent_drop
from nue.evaluate.metrics import EpisodeRecord
from nue.evaluate.results_md import generalisation_section, render_results_md
from nue.sim.episode_sets import held_out_sets

from .conftest import nue_here


def rec(i, ok, method="nue", scene="val_00", path=2.0):
    return EpisodeRecord(episode_id=f"easy_{i:03d}", scene=scene, difficulty="easy", success=ok, geodesic_start=2.0,
                         path_length=path, final_geodesic=0.5 if ok else 3.0, final_euclidean=0.5 if ok else 3.0,
                         success_radius=0.8, method=method, extra={})


def sets():
    """val252: NUE 4/4 (SPL 1, 1, .5, .5 -> .75), FR 2/4; val_pale: NUE 1/4, FR two seeds 2/4 and 4/4."""
    ref = [rec(i, True, path=2.0 if i < 2 else 4.0) for i in range(4)]
    ref += [rec(i, i < 2, "fr") for i in range(4)]
    pale = [rec(i, i == 0, scene="val_pale_00") for i in range(4)]
    pale += [rec(i, i < 2, "fr", scene="val_pale_00") for i in range(4)]  # seed 0 keeps the plain name
    pale += [rec(i, True, "fr@s1", scene="val_pale_00") for i in range(4)]
    return {"val252": ref, "val_pale": pale}


def test_rows_by_hand():
    rows = {r.method: r for r in generalisation_rows(sets(), "val252", ["val_plain", "val_pale"])}
    assert list(rows) == ["fr", "nue"]  # Table I order; val_plain ran by no one
    nue, fr = rows["nue"], rows["fr"]
    assert nue.cells["val252"].sr == 1.0 and nue.cells["val252"].spl == pytest.approx(0.75)
    assert nue.cells["val_pale"].sr == 0.25 and nue.drops["val_pale"]["sr"].mean == pytest.approx(0.75)
    assert nue.drops["val_pale"]["spl"].mean == pytest.approx(0.75 - 0.25)
    assert fr.cells["val_pale"].sr == pytest.approx(0.75)  # seed mean of 0.5 and 1.0
    assert fr.drops["val_pale"]["sr"].mean == pytest.approx(0.0)  # only seed 0 ran both sets: 2/4 on each
    assert set(nue.drops) == {"val_pale"}
    s = sets()
    s["val252"] += [rec(i, False, "fr@s1") for i in range(4)]  # now both seeds ran both sets
    fr = {r.method: r for r in generalisation_rows(s, "val252", ["val_pale"])}["fr"]
    assert fr.cells["val252"].sr == pytest.approx(0.25)  # seed means (.5 + 0) / 2
    assert fr.drops["val_pale"]["sr"].mean == pytest.approx(0.25 - 0.75)  # per-episode seed means (1, 1, .5, .5)


def test_independent_drop_interval():
    same = independent_drop(np.ones(10), np.ones(10))
    assert (same.mean, same.lo, same.hi) == (0.0, 0.0, 0.0)
    d = independent_drop(np.r_[np.ones(50), np.zeros(50)], np.zeros(100))
    assert d.mean == 0.5 and 0.38 < d.lo < 0.45 and 0.55 < d.hi < 0.62  # +-1.96 * sqrt(.25 / 100) = +-0.098


def test_markdown_and_the_results_md_section_only_when_asked():
    text = generalisation_markdown(sets(), "val252", ["val_pale"])
    assert "| NUE (full) | 100.0 / 0.750 | 25.0 / 0.250 | +75.0 [" in text
    assert "Paired differences to NUE on `val_pale`" in text and "| FR | 4 (2 x 1 seeds) | +50.0 [" in text
    assert held_out_sets() == ["val_plain", "val_pale"]
    s = sets()
    assert generalisation_section("val252", {"val252": s["val252"]}) == ""
    meta = {"command": "c", "date": "d", "commit": "x", "machine": "m"}
    plain = render_results_md(s["val252"], meta, sets={"val_pale": s["val_pale"]}, main_name="val252")
    assert "Generalisation" not in plain
    both = render_results_md(s["val252"], meta, sets={"val_pale": s["val_pale"]}, main_name="val252",
                             generalisation="val252")
    assert both.startswith(plain) and "## Generalisation to held-out styles" in both[len(plain):]


def test_report_cli_writes_the_table(tmp_path):
    from nue.cli import main

    files = {}
    for name, recs in sets().items():
        files[name] = tmp_path / f"{name}.jsonl"
        files[name].write_text("".join(json.dumps(r.to_dict()) + "\n" for r in recs))
    explore = tmp_path / "explore.jsonl"  # exploration-benchmark runs: their own figure
    explore.write_text("".join(json.dumps({**r.to_dict(), "extra": {"coverage": [1.0, 2.0, 2.5]}}) + "\n"
                               for r in sets()["val252"]))
    out = tmp_path / "report"
    try:
        main(["report", str(files["val252"]), "--name", "val252", "--set", f"val_pale={files['val_pale']}",
              "--out", str(out), "--generalisation", "val252", "--explore", f"val252={explore}"])
    except SystemExit as exc:
        assert exc.code in (0, None)
    assert "| NUE (full) | 100.0 / 0.750 | 25.0 / 0.250 | +75.0 [" in (out / "generalisation.md").read_text()
    assert (out / "explore_val252.png").read_bytes()[:4] == b"\x89PNG"


def _with_outcome(r, outcome):
    h = {"first_seen_step": None, "first_near_step": None, "closest_geodesic": 3.0, "closest_step": 0, "steps_near": 0,
         "search_steps": 0, "exploit_steps": 0, "outcome": outcome}
    return EpisodeRecord(**{**r.__dict__, "extra": {"handoff": h}})


def test_failure_split_shares_by_hand_and_differences_to_another_reference():
    from nue.evaluate.generalisation import failure_split

    s = sets()
    kinds = ["success", "found_then_lost", "never_near", "never_near"]  # NUE on val_pale: 1 success, 3 failures
    pale = [_with_outcome(r, kinds[i]) if r.method == "nue" else r for i, r in enumerate(s["val_pale"][:4])]
    # FR's two seeds: seed 0 fails episodes 2, 3 (one lost, one never near), seed 1 never fails
    fr0 = [_with_outcome(r, ["success", "success", "found_then_lost", "never_near"][i])
           for i, r in enumerate(s["val_pale"][4:8])]
    fr1 = [_with_outcome(r, "success") for r in s["val_pale"][8:]]
    split = failure_split(pale + fr0 + fr1)
    assert split["nue"] == (0.25, 0.0, 0.5, 1)
    assert split["fr"] == (0.125, 0.0, 0.125, 2)  # seed shares (1/4, 0) and (1/4, 0), averaged
    text = generalisation_markdown({"val252": s["val252"], "val_pale": pale + fr0 + fr1}, "val252", ["val_pale"],
                                   compare_to="fr")
    assert "| NUE (full) | – | 25.0 / 0.0 / 50.0 |" in text and "| FR | – | 12.5 / 0.0 / 12.5 (2 runs) |" in text
    assert "Paired differences to FR on `val_pale`" in text and "| NUE (full) | 4 (1 x 2 seeds) | -50.0 [" in text


def test_report_set_takes_several_files_by_comma_and_glob(tmp_path):
    s = sets()
    (tmp_path / "val252.jsonl").write_text("".join(json.dumps(r.to_dict()) + "\n" for r in s["val252"]))
    for name, method in (("nue", "nue"), ("fr_a", "fr"), ("fr_b", "fr@s1")):
        recs = [r for r in s["val_pale"] if r.method == method]
        (tmp_path / f"pale_{name}.jsonl").write_text("".join(json.dumps(r.to_dict()) + "\n" for r in recs))
    out = tmp_path / "report"
    res = nue_here("report", tmp_path / "val252.jsonl", "--name", "val252", "--set",
                   f"val_pale={tmp_path / 'pale_nue.jsonl'},{tmp_path / 'pale_fr_*.jsonl'}", "--out", out,
                   "--generalisation", "val252")
    assert res.returncode == 0, res.stderr
    text = (out / "generalisation.md").read_text()
    assert "| NUE (full) | 100.0 / 0.750 | 25.0 / 0.250 | +75.0 [" in text and "| FR | 50.0 / " in text  # FR: 2 seeds
    res = nue_here("report", tmp_path / "val252.jsonl", "--set", f"val_pale={tmp_path / 'none_*.jsonl'}",
                   "--out", tmp_path / "r2")
    assert res.returncode == 2 and "--set" in res.stderr and "none_*.jsonl" in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1


def test_pairs_table_by_hand_with_holm_across_its_cells():
    from nue.evaluate.generalisation import pair_differences, pairs_markdown

    s = sets()
    diffs = pair_differences(s, [("nue", "fr")])
    ref, pale = diffs[("nue", "fr")]["val252"], diffs[("nue", "fr")]["val_pale"]
    assert ref.mean == pytest.approx(0.5) and (ref.seeds, ref.reference_seeds) == (1, 1)
    # val_pale: NUE (1, 0, 0, 0) against FR's per-episode seed means (1, 1, .5, .5)
    assert pale.mean == pytest.approx(-0.5) and (pale.seeds, pale.reference_seeds) == (1, 2)
    text = pairs_markdown(s, [("nue", "fr"), ("fr", "nue")], label=lambda k: {"nue": "N", "fr": "F"}[k])
    assert "| N − F | +50.0 [" in text and "(4, 1 x 1)" in text and "| F − N | -50.0 [" in text
    assert "(4, 2 x 1)" in text and "across the 4 cells" in text
    assert pair_differences(s, [("nue", "expert")]) == {}


def _write(path, recs):
    path.write_text("".join(json.dumps(r.to_dict()) + "\n" for r in recs))
    return path


def test_results_md_section_from_a_manifest_and_bad_manifests(tmp_path):
    from nue.errors import DataError
    from nue.evaluate.results_md import load_held_out

    s = sets()
    _write(tmp_path / "a.jsonl", s["val252"])
    _write(tmp_path / "b.jsonl", s["val_pale"])
    manifest = tmp_path / "RESULTS.generalisation.json"
    manifest.write_text(json.dumps({"reference": "val252", "sets": {"val252": ["a.jsonl"], "val_pale": ["b.jsonl"]},
                                    "pairs": [["nue", "fr"]], "labels": {"fr": "FR (old houses)"},
                                    "about": "Rows of recipe X."}))
    held = load_held_out(manifest)
    meta = {"command": "c", "date": "d", "commit": "x", "machine": "m"}
    text = render_results_md(s["val252"], meta, held_out=held)
    section = text[text.index("## Generalisation to held-out styles"):]
    assert section.startswith("## Generalisation to held-out styles\n\nRows of recipe X.\n\nEach model on `val252`")
    assert "| FR (old houses) | 50.0 / " in section and "| NUE (full) − FR (old houses) | +50.0 [" in section
    # with the main records' own section (their held-out sets given): that one first, the manifest's under its title
    manifest.write_text(json.dumps({**json.loads(manifest.read_text()), "title": "Held out: recipe X"}))
    both = render_results_md(s["val252"], meta, sets={"val_pale": s["val_pale"]}, main_name="val252",
                             generalisation="val252", held_out=load_held_out(manifest))
    own, held_section = both.index("## Generalisation to held-out styles\n"), both.index("## Held out: recipe X\n")
    assert own < held_section and "Rows of recipe X." in both[held_section:] and "Rows of recipe X." not in both[:held_section]
    manifest.write_text(json.dumps({"reference": "val252", "sets": {"val252": ["a.jsonl", "gone.jsonl"]}}))
    with pytest.raises(DataError, match="gone.jsonl"):
        load_held_out(manifest)
    manifest.write_text(json.dumps({"reference": "val9", "sets": {"val252": ["a.jsonl"]}}))
    with pytest.raises(DataError, match="val9"):
        load_held_out(manifest)
    # nue report --results-md reads the manifest beside it: a bad one is one line, exit 2
    res = nue_here("report", tmp_path / "a.jsonl", "--out", tmp_path / "r", "--results-md", tmp_path / "RESULTS.md")
    assert res.returncode == 2 and "RESULTS.generalisation.json" in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1
    res = nue_here("report", tmp_path / "a.jsonl", "--out", tmp_path / "r", "--pair", "nue,fr")
    assert res.returncode == 2 and "--pair" in res.stderr and "--generalisation" in res.stderr
