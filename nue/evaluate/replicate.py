"""Table I's recipe trained twice (issue 42): a generated check of how far Table I's comparisons carry over to another
training of the same recipe.

Issue 43's runs ``nue_gru_lean_mix`` and ``fr_mix`` (``results/mix/``) are the recipe of Table I's NUE and FR (same
demonstrations, samples, settings and training seeds 0-2), trained on another CPU: floating-point rounding differs,
so the weights do too, and they are a second draw of each training run. RESULTS.generalisation.json names them
(``replicates``: Table I's key -> the manifest's key) and this section shows, per set both ran:

* each model's SR in Table I's runs and in the replicate, and the paired difference "Table I's runs - replicate"
  (how much a whole training run of the same recipe moves the number);
* every comparison of Table I's reference (NUE) with another replicated model in Table I's runs, in the replicate,
  and pooled over both (the replicate's runs counted as further training runs: ``nue@s3`` ... ``nue@s5``).

Every difference is :func:`nue.evaluate.generalisation.pair_differences` (per episode the mean over a side's training
runs; two-level bootstrap over runs, then episodes; 10,000 resamples, seed 0). The pooled interval treats the six runs
of a model as independent draws; two runs of one seed share their initial weights and batch order, which it does not
model.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Mapping, Sequence

from nue.evaluate.generalisation import pair_differences
from nue.evaluate.paired import PairedDiff
from nue.evaluate.table import (build_table, canonical_method, is_earlier_recipe, method_label, seed_run_name,
                                split_seed)
from nue.sim.record import EpisodeRecord

REPLICATE_PREFIX = "replicate:"
"""Key prefix of a replicate's runs when they sit beside Table I's (``replicate:nue@s1``)."""


def _runs(records: Sequence[EpisodeRecord], key: str) -> list[EpisodeRecord]:
    """The records of every training run of method ``key`` (current recipe only)."""
    return [r for r in records if not is_earlier_recipe(r.method) and canonical_method(split_seed(r.method)[0]) == key]


def _renamed(records: Sequence[EpisodeRecord], key: str, offset: int = 0, prefix: str = "") -> list[EpisodeRecord]:
    """``records`` (one model's runs) under ``prefix + key``, seed index shifted by ``offset``."""
    return [replace(r, method=seed_run_name(prefix + key, split_seed(r.method)[1] + offset)) for r in records]


def _seed_count(records: Sequence[EpisodeRecord]) -> int:
    return len({split_seed(r.method)[1] for r in records})


def _diff(d: PairedDiff | None) -> str:
    if d is None:
        return "–"
    mark = " resolved" if d.resolved else ""
    return f"{100 * d.mean:+.1f} [{100 * d.lo:+.1f}, {100 * d.hi:+.1f}] ({d.n_pairs}, {d.seeds} x {d.reference_seeds}){mark}"


def _common(*groups: Sequence[EpisodeRecord]) -> set[tuple[str, str]]:
    """The (scene, episode) keys every training run in ``groups`` ran."""
    runs: dict[tuple[int, str], set] = {}
    for i, g in enumerate(groups):
        for r in g:
            runs.setdefault((i, r.method), set()).add((r.scene, r.episode_id))
    return set.intersection(*runs.values()) if runs else set()


def _sr(records: Sequence[EpisodeRecord], key: str, episodes: set[tuple[str, str]]) -> str:
    """Seed-mean SR of ``key`` over ``episodes`` and its run count."""
    rows = [r for r in build_table([r for r in records if (r.scene, r.episode_id) in episodes]) if r.method == key]
    if not rows:
        return "–"
    return f"{100 * rows[0].cells['total'].sr:.1f} ({_seed_count(records)})"


def replicate_markdown(table_sets: Mapping[str, Sequence[EpisodeRecord]],
                       replicate_sets: Mapping[str, Sequence[EpisodeRecord]], replicates: Mapping[str, str],
                       reference: str = "nue", label=method_label) -> str:
    """The section's tables (see the module doc) over the sets both ran; '' when no replicated model ran a set in
    both. ``replicates``: Table I's method key -> the replicate's method key in ``replicate_sets``."""
    keys = {canonical_method(k): canonical_method(v) for k, v in replicates.items()}
    names = [n for n in table_sets if n in replicate_sets
             and any(_runs(table_sets[n], k) and _runs(replicate_sets[n], v) for k, v in keys.items())]
    if not names:
        return ""
    header = "| | " + " | ".join(f"`{n}`" for n in names) + " |\n|" + "---|" * (len(names) + 1)
    sr_lines, same_lines, cmp_lines = [], [], []
    for k, v in keys.items():
        cells_sr, cells_same = [], []
        for n in names:
            mine, theirs = _runs(table_sets[n], k), _runs(replicate_sets[n], v)
            common = _common(mine, theirs)
            cells_sr.append(f"{_sr(mine, k, common)} / {_sr(theirs, v, common)}" if common else "–")
            both = {n: mine + _renamed(theirs, k, prefix=REPLICATE_PREFIX)}
            found = pair_differences(both, [(k, REPLICATE_PREFIX + k)]).get((k, REPLICATE_PREFIX + k), {})
            cells_same.append(_diff(found.get(n)))
        sr_lines.append(f"| {label(k)}: SR % (runs), Table I's / replicate | " + " | ".join(cells_sr) + " |")
        same_lines.append(f"| {label(k)}: Table I's runs − replicate | " + " | ".join(cells_same) + " |")
    ref = canonical_method(reference)
    for k in (k for k in keys if k != ref and ref in keys):
        rows: dict[str, list[str]] = {"Table I's runs": [], "replicate": [], "both, pooled": []}
        for n in names:
            own = {m: _runs(table_sets[n], m) for m in (ref, k)}
            rep = {m: _runs(replicate_sets[n], keys[m]) for m in (ref, k)}
            pooled = [r for m in (ref, k) for r in own[m] + _renamed(rep[m], m, offset=_seed_count(own[m]))]
            tagged = [r for m in (ref, k) for r in _renamed(rep[m], m)]
            for row, recs in zip(rows, (own[ref] + own[k], tagged, pooled)):
                # ref - k as the other sections compute it (the same resamples, so the same interval)
                rows[row].append(_diff(pair_differences({n: recs}, [(ref, k)]).get((ref, k), {}).get(n)))
        cmp_lines += [f"| {label(ref)} − {label(k)}, {row} | " + " | ".join(cells) + " |" for row, cells in rows.items()]
    return ("SR of each model in Table I's runs and in the replicate (seed means over the episodes every run of both "
            "ran; runs in brackets), and paired "
            "differences in SR points with their 95% interval (episodes, runs x runs); *resolved*: the interval "
            "excludes 0 (no multiple-comparison correction: this table checks the others):\n\n"
            + "\n".join([header, *sr_lines, *same_lines, *cmp_lines]) + "\n\n"
            "The pooled rows count the replicate's runs as further training runs of the model (3 + 3); the interval "
            "treats them as independent, which two runs of one seed (same initial weights and batch order, another "
            "CPU) may not fully be, and covers neither other demonstrations nor other houses.\n")


REPLICATE_TITLE = "Table I's recipe trained again"
"""The section's title."""


def replicate_section(table_sets: Mapping[str, Sequence[EpisodeRecord]],
                      replicate_sets: Mapping[str, Sequence[EpisodeRecord]], replicates: Mapping[str, str],
                      about: str = "", label=method_label) -> str:
    """RESULTS.md's replication section: title, ``about``, :func:`replicate_markdown`; '' when nothing compares."""
    table = replicate_markdown(table_sets, replicate_sets, replicates, label=label)
    if not table:
        return ""
    return f"## {REPLICATE_TITLE}\n\n" + (f"{about}\n\n" if about else "") + table
