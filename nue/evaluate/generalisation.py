"""The generalisation table (issue 43): per model, SR / SPL on a reference set of the training style (``val252``)
and on each held-out style family (``val_plain``, ``val_pale``), the drop from the reference to each family, and
the paired differences between models on each family.

A drop compares two sets of different houses, so it is not paired: its 95% interval is a bootstrap that resamples
each set's episodes independently (10,000 resamples, seed 0), each episode's result the mean over the method's
training seeds that ran it, counting only the seeds that ran both sets (when they share one). Several training
seeds of a method (runs ``<model>@s<k>``) are one row of seed means, as in Table I; the paired differences on a family
are :func:`nue.evaluate.paired.paired_differences` (seed-pooled when several seeds exist), to one reference or
between named pairs of rows on every set (:func:`pairs_markdown`). Earlier recipes' rows (``*_v<N>``) are left out, as in Table I.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from nue.evaluate.paired import METRIC_FNS, PairedDiff, paired_differences
from nue.evaluate.stats import holm
from nue.evaluate.table import (Cell, build_table, by_method_and_seed, canonical_method, method_label, order_methods,
                                split_seed)
from nue.sim.record import EpisodeRecord


@dataclass(frozen=True)
class Drop:
    """Reference-set value minus family value of one metric (positive = worse on the family)."""

    mean: float
    """Difference of the two sets' means (SR as a fraction)."""
    lo: float
    """2.5th percentile of the independent bootstrap of the two sets."""
    hi: float
    """97.5th percentile."""


@dataclass(frozen=True)
class GeneralisationRow:
    """One model's cells on the reference set and on every family, and its drops."""

    method: str
    """Canonical method key."""
    cells: dict[str, Cell]
    """Set name -> the total cell (seed means with several seeds), for the sets the model ran."""
    drops: dict[str, dict[str, Drop]]
    """Family name -> metric (``sr``, ``spl``) -> drop from the reference set."""


def _episode_means(records: Sequence[EpisodeRecord], metric: str) -> np.ndarray:
    """Per episode (scene, episode id), the mean of ``metric`` over the runs (training seeds) that ran it."""
    acc: dict[tuple[str, str], list[float]] = {}
    for r in records:
        acc.setdefault((r.scene, r.episode_id), []).append(METRIC_FNS[metric](r))
    return np.array([np.mean(acc[k]) for k in sorted(acc)], dtype=float)


def independent_drop(a: np.ndarray, b: np.ndarray, n_boot: int = 10_000, seed: int = 0) -> Drop:
    """mean(a) - mean(b) with a 95% interval from resampling ``a`` and ``b`` independently."""
    rng = np.random.default_rng(seed)
    ma = a[rng.integers(0, len(a), (n_boot, len(a)))].mean(1)
    mb = b[rng.integers(0, len(b), (n_boot, len(b)))].mean(1)
    lo, hi = np.percentile(ma - mb, [2.5, 97.5])
    return Drop(float(a.mean() - b.mean()), float(lo), float(hi))


def _current(records: Sequence[EpisodeRecord]) -> list[EpisodeRecord]:
    from nue.evaluate.results_md import is_earlier_recipe

    return [r for r in records if not is_earlier_recipe(r.method)]


def generalisation_rows(sets: Mapping[str, Sequence[EpisodeRecord]], reference: str,
                        families: Sequence[str]) -> list[GeneralisationRow]:
    """A row per model that ran ``reference`` and at least one of ``families`` (names of ``sets``)."""
    current = {name: _current(sets[name]) for name in [reference, *families] if name in sets}
    cells = {name: {row.method: row.cells["total"] for row in build_table(recs)} for name, recs in current.items()}
    by_set = {name: by_method_and_seed(recs) for name, recs in current.items()}

    def runs(name: str, method: str, seeds: set[int]) -> list[EpisodeRecord]:
        return [r for k, run in by_set[name][method].items() if k in seeds for r in run]

    rows = []
    for method in order_methods(cells.get(reference, {})):
        ran = [f for f in families if method in cells.get(f, {})]
        if not ran:
            continue
        drops = {}
        for f in ran:  # over the training seeds that ran both sets (all of each set's when they share none)
            both = set(by_set[reference][method]) & set(by_set[f][method])
            a = runs(reference, method, both or set(by_set[reference][method]))
            b = runs(f, method, both or set(by_set[f][method]))
            drops[f] = {m: independent_drop(_episode_means(a, m), _episode_means(b, m)) for m in ("sr", "spl")}
        rows.append(GeneralisationRow(method, {n: cells[n][method] for n in [reference, *ran]}, drops))
    return rows


def _cell(c: Cell | None) -> str:
    return "–" if c is None or c.n == 0 else f"{100 * c.sr:.1f} / {c.spl:.3f}"


def _drop(d: Drop | None, scale: float, spec: str) -> str:
    return "–" if d is None else f"{scale * d.mean:+{spec}} [{scale * d.lo:+{spec}}, {scale * d.hi:+{spec}}]"


def failure_split(records: Sequence[EpisodeRecord]) -> dict[str, tuple[float, float, float, int]]:
    """Per model (canonical key), its failures by hand-off class as shares of its episodes (mean over its training-seed
    runs): (found then lost, near but unseen, never near, runs), over the records that carry a hand-off
    (:mod:`nue.evaluate.handoff`)."""
    from nue.evaluate.handoff import record_handoff

    counts: dict[str, dict[str, list[float]]] = {}
    for key, seeds in by_method_and_seed(records).items():
        for run in seeds.values():
            outcomes = [h.outcome for h in map(record_handoff, run) if h is not None]
            if outcomes:
                counts.setdefault(key, {}).setdefault("runs", []).append(1)
                for c in ("found_then_lost", "near_unseen", "never_near"):
                    counts[key].setdefault(c, []).append(outcomes.count(c) / len(outcomes))
    return {k: (float(np.mean(v["found_then_lost"])), float(np.mean(v["near_unseen"])), float(np.mean(v["never_near"])),
                len(v["runs"])) for k, v in counts.items()}


def _failure_table(sets: Mapping[str, Sequence[EpisodeRecord]], names: Sequence[str], methods: Sequence[str],
                   label=method_label) -> str:
    """Markdown: per model, each set's failures split by hand-off class (per run); '' when no record has a hand-off."""
    split = {n: failure_split(_current(sets[n])) for n in names}
    if not any(split.values()):
        return ""
    lines = ["| method | " + " | ".join(f"`{n}`: found then lost / near, unseen / never near" for n in names) + " |",
             "|" + "---|" * (len(names) + 1)]
    for m in methods:
        cells = []
        for n in names:
            f = split[n].get(m)
            cells.append("–" if f is None else f"{100 * f[0]:.1f} / {100 * f[1]:.1f} / {100 * f[2]:.1f}"
                         + (f" ({f[3]} runs)" if f[3] > 1 else ""))
        lines.append(f"| {label(m)} | " + " | ".join(cells) + " |")
    return ("Failures by hand-off class (docs/exploration.md), % of the episodes of a training-seed run (mean over the "
            "runs): *found then lost* saw the goal and came within 2 m but did not finish, *never near* never came "
            "within 2 m:\n\n" + "\n".join(lines) + "\n")


def pair_differences(sets: Mapping[str, Sequence[EpisodeRecord]], pairs: Sequence[tuple[str, str]],
                     metric: str = "sr") -> dict[tuple[str, str], dict[str, PairedDiff]]:
    """Per pair ``(a, b)`` of method keys and per set where both ran: the paired difference a - b of ``metric``
    (:func:`nue.evaluate.paired.paired_differences` on the two methods' records alone, seed-pooled when either has
    several training seeds)."""
    out: dict[tuple[str, str], dict[str, PairedDiff]] = {}
    for a, b in pairs:
        a, b = canonical_method(a), canonical_method(b)
        for name, recs in sets.items():
            two = [r for r in _current(recs) if canonical_method(split_seed(r.method)[0]) in (a, b)]
            found = [d for d in paired_differences(two, reference=b, metrics=(metric,)) if d.method == a and d.n_pairs]
            if found:
                out.setdefault((a, b), {})[name] = found[0]
    return out


def pairs_holm(diffs: Mapping[tuple[str, str], Mapping[str, PairedDiff]]) -> dict[tuple[tuple[str, str], str], bool]:
    """Per cell ``(pair, set)`` of :func:`pair_differences`' result: whether "no difference" is rejected after a
    Holm-Bonferroni correction across all the cells (5% family-wise)."""
    cells = [(k, n) for k, row in diffs.items() for n in row]
    return dict(zip(cells, holm([diffs[k][n].p for k, n in cells])))


def pairs_markdown(sets: Mapping[str, Sequence[EpisodeRecord]], pairs: Sequence[tuple[str, str]],
                   label=method_label, diffs: Mapping[tuple[str, str], Mapping[str, PairedDiff]] | None = None) -> str:
    """A table of :func:`pair_differences` in SR points (``diffs`` when computed already), a row per pair and a
    column per set, each cell's verdict after a Holm-Bonferroni correction across all the table's cells
    (:func:`pairs_holm`); '' when no pair ran together."""
    diffs = pair_differences(sets, pairs) if diffs is None else diffs
    if not diffs:
        return ""
    names = [n for n in sets if any(n in row for row in diffs.values())]
    cells = [(k, n) for k in diffs for n in names if n in diffs[k]]
    holds = pairs_holm(diffs)
    lines = ["| difference | " + " | ".join(f"`{n}`: ΔSR points [95% CI] (episodes, seeds)" for n in names) + " |",
             "|" + "---|" * (len(names) + 1)]
    for (a, b), row in diffs.items():
        out = []
        for n in names:
            d = row.get(n)
            if d is None:
                out.append("–")
                continue
            mark = "" if not d.resolved else " **resolved**" if holds[((a, b), n)] else " resolved, not after Holm"
            out.append(f"{100 * d.mean:+.1f} [{100 * d.lo:+.1f}, {100 * d.hi:+.1f}] ({d.n_pairs}, {d.seeds} x "
                       f"{d.reference_seeds}){mark}")
        lines.append(f"| {label(a)} − {label(b)} | " + " | ".join(out) + " |")
    return ("Paired differences between the rows on each set: per episode, each side's mean over its training seeds; "
            "95% interval of a two-level bootstrap (seeds, then episodes; the episodes alone with one run each), "
            f"10,000 resamples, seed 0. *Resolved*: the interval excludes 0; **bold**: it still holds after a "
            f"Holm-Bonferroni correction across the {len(cells)} cells of this table (5% family-wise). The interval "
            "covers the episodes and, with several seeds, the training seeds (understated with few); not the "
            "demonstrations, which each row's seeds share.\n\n" + "\n".join(lines) + "\n")


def generalisation_markdown(sets: Mapping[str, Sequence[EpisodeRecord]], reference: str,
                            families: Sequence[str], compare_to: str = "nue", pairs: Sequence[tuple[str, str]] = (),
                            labels: Mapping[str, str] | None = None) -> str:
    """The table of :func:`generalisation_rows`, each set's failures by hand-off class, then the paired differences:
    with ``pairs``, the table of :func:`pairs_markdown` on the reference set and every family; else to ``compare_to``
    (default NUE) on each family. ``labels``: row names by method key (default :func:`method_label`). '' when no
    model ran the reference set and a family."""
    from nue.evaluate.report import reference_label, paired_markdown

    def label(key: str) -> str:
        return (labels or {}).get(key) or method_label(key)

    rows = generalisation_rows(sets, reference, families)
    if not rows:
        return ""
    fams = [f for f in families if any(f in r.drops for r in rows)]
    head = ["method", f"`{reference}` SR % / SPL"]
    for f in fams:
        head += [f"`{f}` SR % / SPL", "SR drop, points [95% CI]", "SPL drop [95% CI]"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [label(r.method), _cell(r.cells.get(reference))]
        for f in fams:
            d = r.drops.get(f, {})
            cells += [_cell(r.cells.get(f)), _drop(d.get("sr"), 100, ".1f"), _drop(d.get("spl"), 1, ".3f")]
        lines.append("| " + " | ".join(cells) + " |")
    parts = ["\n".join(lines) + "\n",
             f"Drop: `{reference}` minus the family (positive = worse on the held-out style); sets of different houses, "
             "so the interval resamples each set's episodes independently (10,000 resamples, seed 0), each episode "
             "the mean over a model's training seeds, over the seeds that ran both sets. SR / SPL: seed means over "
             "the seeds that ran the set.\n"]
    failures = _failure_table(sets, [reference, *fams], [r.method for r in rows], label)
    if failures:
        parts.append(failures)
    if pairs:
        table = pairs_markdown({n: sets[n] for n in [reference, *fams]}, pairs, label)
        if table:
            parts.append(table)
        return "\n".join(parts)
    ref = reference_label(compare_to)
    for f in fams:
        diffs = paired_differences(_current(sets[f]), reference=canonical_method(compare_to))
        if diffs:
            parts.append(f"Paired differences to {ref} on `{f}` (95% paired bootstrap; seed-pooled with several "
                         f"seeds):\n\n{paired_markdown(diffs)}")
    return "\n".join(parts)
