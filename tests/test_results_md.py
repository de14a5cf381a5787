"""RESULTS.md is generated: regenerating it from the committed records and metadata changes nothing."""

from __future__ import annotations

from pathlib import Path

import pytest

from nue.evaluate.results_md import committed_explore, committed_held_out, committed_inputs, render_results_md

ROOT = Path(__file__).resolve().parent.parent


def test_results_md_regenerates_from_the_records():
    results, records, meta = ROOT / "RESULTS.md", ROOT / "results" / "records.jsonl", ROOT / "RESULTS.meta.json"
    if not results.is_file():
        pytest.skip("no RESULTS.md committed yet")
    assert records.is_file() and meta.is_file(), "RESULTS.md needs results/records.jsonl and RESULTS.meta.json"
    main, meta_d, sets, main_name = committed_inputs(ROOT)
    assert main_name == "val252" and list(sets) == ["val", "val_plain"]
    text = render_results_md(main, meta_d, sets=sets, main_name=main_name, explore=committed_explore(ROOT),
                             held_out=committed_held_out(ROOT))
    assert text == results.read_text()
