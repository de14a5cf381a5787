"""RESULTS.md is generated: regenerating it from the committed records and metadata changes nothing."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from nue.evaluate.report import load_records
from nue.evaluate.results_md import render_results_md, results_set_files

ROOT = Path(__file__).resolve().parent.parent


def test_results_md_regenerates_from_the_records():
    results, records, meta = ROOT / "RESULTS.md", ROOT / "results" / "records.jsonl", ROOT / "RESULTS.meta.json"
    if not results.is_file():
        pytest.skip("no RESULTS.md committed yet")
    assert records.is_file() and meta.is_file(), "RESULTS.md needs results/records.jsonl and RESULTS.meta.json"
    sets = {name: load_records(path) for name, path in results_set_files(ROOT).items()}
    text = render_results_md(load_records(records), json.loads(meta.read_text()), sets=sets)
    assert text == results.read_text()
