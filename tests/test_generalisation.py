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
    assert fr.drops["val_pale"]["sr"].mean == pytest.approx(0.5 - 0.75)  # per-episode seed means (1, 1, .5, .5)
    assert set(nue.drops) == {"val_pale"}


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
    out = tmp_path / "report"
    try:
        main(["report", str(files["val252"]), "--name", "val252", "--set", f"val_pale={files['val_pale']}",
              "--out", str(out), "--generalisation", "val252"])
    except SystemExit as exc:
        assert exc.code in (0, None)
    assert "| NUE (full) | 100.0 / 0.750 | 25.0 / 0.250 | +75.0 [" in (out / "generalisation.md").read_text()
