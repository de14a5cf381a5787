"""Table I's recipe trained again (issue 42): hand-computed SRs and differences between Table I's runs and a replicate
of them, the pooled comparison counting both as training runs, and the RESULTS.md section from the generalisation
manifest's ``replicates`` (a misspelled key refused)."""

from __future__ import annotations

import json

import pytest

from nue.evaluate.metrics import EpisodeRecord
from nue.evaluate.replicate import REPLICATE_TITLE, replicate_markdown


def rec(i, ok, method):
    return EpisodeRecord(episode_id=f"easy_{i:03d}", scene="val_00", difficulty="easy", success=ok, geodesic_start=2.0,
                         path_length=2.0, final_geodesic=0.5 if ok else 3.0, final_euclidean=0.5 if ok else 3.0,
                         success_radius=0.8, method=method, extra={})


def runs(method, successes):
    """One run's 4 episodes, succeeding on the episode indices in ``successes``."""
    return [rec(i, i in successes, method) for i in range(4)]


# Table I: NUE 4/4 and 2/4 (per episode 1, 1, .5, .5), FR 2/4 and 0/4 (.5, .5, 0, 0)
TABLE = runs("nue", {0, 1, 2, 3}) + runs("nue@s1", {0, 1}) + runs("fr", {0, 1}) + runs("fr@s1", set())
# the replicate: NUE 3/4 twice (1, 1, 1, 0), FR 0/4 twice; and a model Table I does not have
REPLICATE = (runs("nue_mix", {0, 1, 2}) + runs("nue_mix@s1", {0, 1, 2}) + runs("fr_mix", set())
             + runs("fr_mix@s1", set()) + runs("zz_model", {0}))


def _row(text, start):
    return next(line for line in text.splitlines() if line.startswith(start))


def test_hand_computed_table():
    text = replicate_markdown({"val252": TABLE}, {"val252": REPLICATE}, {"nue": "nue_mix", "fr": "fr_mix"})
    assert _row(text, "| NUE (full): SR % (runs)") == "| NUE (full): SR % (runs), Table I's / replicate | 75.0 (2) / 75.0 (2) |"
    assert _row(text, "| FR: SR % (runs)").endswith("| 25.0 (2) / 0.0 (2) |")
    # Table I's runs - replicate, per episode (seed means): NUE (1, 1, .5, .5) - (1, 1, 1, 0) = 0; FR +.25
    assert _row(text, "| NUE (full): Table I's runs − replicate | +0.0 [")
    assert "(4, 2 x 2)" in _row(text, "| NUE (full): Table I's runs − replicate")
    assert _row(text, "| FR: Table I's runs − replicate | +25.0 [")
    # NUE - FR: Table I's (1, 1, .5, .5) - (.5, .5, 0, 0) = +50; replicate (1, 1, 1, 0) - 0 = +75;
    # pooled over 4 runs a side: (1, 1, .75, .25) - (.25, .25, 0, 0) = +62.5
    assert _row(text, "| NUE (full) − FR, Table I's runs | +50.0 [")
    assert _row(text, "| NUE (full) − FR, replicate | +75.0 [")
    pooled = _row(text, "| NUE (full) − FR, both, pooled | +62.5 [")
    assert "(4, 4 x 4)" in pooled and pooled.endswith("resolved |")  # every resample's difference is > 0
    assert "zz_model" not in text  # only the named replicates


def test_only_common_episodes_and_sets_count():
    # a replicate run that ran 2 of the 4 episodes: the SR cells and differences use those 2
    short = [r for r in REPLICATE if r.method != "nue_mix@s1"] + runs("nue_mix@s1", {0, 1, 2})[:2]
    text = replicate_markdown({"val252": TABLE}, {"val252": short}, {"nue": "nue_mix", "fr": "fr_mix"})
    assert _row(text, "| NUE (full): SR % (runs)").endswith("| 100.0 (2) / 100.0 (2) |")
    assert "(2, 2 x 2)" in _row(text, "| NUE (full): Table I's runs − replicate")
    # no set in common, or no replicated model in a common set: no section
    assert replicate_markdown({"val252": TABLE}, {"val_plain": REPLICATE}, {"nue": "nue_mix"}) == ""
    assert replicate_markdown({"val252": TABLE}, {"val252": REPLICATE}, {"vgm": "nue_mix"}) == ""


def test_results_md_section_from_the_manifest(tmp_path):
    from nue.errors import DataError
    from nue.evaluate.results_md import load_held_out, render_results_md

    (tmp_path / "rep.jsonl").write_text("".join(json.dumps(r.to_dict()) + "\n" for r in REPLICATE))
    manifest = tmp_path / "RESULTS.generalisation.json"
    base = {"reference": "val252", "sets": {"val252": ["rep.jsonl"]}, "about": "Rows of recipe X."}
    meta = {"command": "c", "date": "d", "commit": "x", "machine": "m"}
    manifest.write_text(json.dumps(base))
    assert REPLICATE_TITLE not in render_results_md(TABLE, meta, main_name="val252", held_out=load_held_out(manifest))
    manifest.write_text(json.dumps({**base, "replicates": {"nue": "nue_mix", "fr": "fr_mix"},
                                    "replicate about": "Trained again on another CPU."}))
    text = render_results_md(TABLE, {**meta, "discussion": "D."}, main_name="val252", held_out=load_held_out(manifest))
    section = text[text.index(f"## {REPLICATE_TITLE}"):]
    assert section.startswith(f"## {REPLICATE_TITLE}\n\nTrained again on another CPU.\n\nSR of each model")
    assert "| NUE (full) − FR, both, pooled | +62.5 [" in section and section.index("## Discussion") > 0
    # Table I's own comparison has the interval of the section on the baselines (the same resamples)
    claimed = _row(text, "| NUE (full) − FR |").split(" | ")[1].split(" (")[0]
    assert _row(section, "| NUE (full) − FR, Table I's runs |").split(" | ")[1].split(" (")[0] == claimed
    manifest.write_text(json.dumps({**base, "replicates": {"nue": "nue_mxi"}}))
    with pytest.raises(DataError, match="nue_mxi"):
        load_held_out(manifest)
