"""Evaluation report: Table I from episode records as Markdown / CSV / LaTeX next to the paper's numbers,
paired-bootstrap differences to NUE, the coverage curves, and the text of RESULTS.md.

* Table data (rows, cells, SR with its 95% Wilson score interval, the paper's numbers):
  :mod:`nue.evaluate.table`; the statistics: :mod:`nue.evaluate.stats`.
* Paired differences: per method, ``d_i = x_method,i - x_NUE,i`` over the episodes both ran
  (matched on (scene, episode_id); repeated runs of a key are averaged), their mean and the 95%
  percentile interval of 10,000 paired-bootstrap resamples (``numpy.random.default_rng(0)`` per
  comparison). The episode count resolves the ordering when the interval excludes 0.
* ``write_report(records, out_dir)`` -> table.md, table.csv, table.tex (the coverage figure is
  :func:`nue.viz.coverage.write_coverage_figure`'s). The text of RESULTS.md, built from these pieces, is
  :mod:`nue.evaluate.results_md`'s.
"""

from __future__ import annotations

import csv
import io
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
from scipy.stats import kendalltau

from nue.evaluate import coverage as cov
from nue.evaluate.diagnose import DIAGNOSTICS_NOTES, format_record_diagnostics, read_records, record_diagnostics
from nue.evaluate.metrics import dts, spl, success, unreachable_end
from nue.evaluate.record_keys import OnDropped
from nue.evaluate.stats import paired_bootstrap, wilson_interval  # noqa: F401  (re-exported)
from nue.evaluate.table import (  # noqa: F401  (re-exported)
    DIFFICULTIES, METHODS, Cell, TableRow, build_table, by_method, canonical_method, method_label, order_methods,
    paper_table,
)
from nue.sim.record import EpisodeRecord

METRIC_FNS = {"sr": success, "spl": spl, "dts": dts}


# --- paired differences -------------------------------------------------------------------------
@dataclass(frozen=True)
class PairedDiff:
    """Mean paired difference (method - reference) of one metric, with its bootstrap interval."""

    method: str
    """Method key."""
    reference: str
    """Reference method key (``nue``)."""
    metric: str
    """``sr`` (fraction), ``spl`` or ``dts``."""
    n_pairs: int
    """Episodes both methods ran."""
    mean: float
    """Mean of ``x_method - x_reference`` over the pairs."""
    lo: float
    """2.5th percentile of the bootstrap means."""
    hi: float
    """97.5th percentile of the bootstrap means."""

    @property
    def resolved(self) -> bool:
        """The interval excludes 0: the episodes settle which method is ahead."""
        return self.n_pairs > 0 and (self.lo > 0 or self.hi < 0)

    def verdict(self, higher_is_better: bool = True) -> str:
        if self.n_pairs == 0:
            return "no common episodes"
        if not self.resolved:
            return "not resolved (CI contains 0)"
        ahead = (self.lo > 0) == higher_is_better
        return f"resolved: {method_label(self.method) if ahead else method_label(self.reference)} ahead"


def _per_key(records: Sequence[EpisodeRecord], metrics: Sequence[str]) -> dict[tuple[str, str], np.ndarray]:
    acc: dict[tuple[str, str], list] = {}
    for r in records:
        acc.setdefault((r.scene, r.episode_id), []).append([METRIC_FNS[m](r) for m in metrics])
    return {k: np.mean(v, axis=0) for k, v in acc.items()}


def paired_differences(records: Sequence[EpisodeRecord], reference: str = "nue", metrics: Sequence[str] = ("sr", "spl"),
                       n_boot: int = 10_000, seed: int = 0) -> list[PairedDiff]:
    """Paired differences to ``reference`` for every other method, per metric (see module doc).

    Empty when the reference has no records; a method sharing no episode gets ``n_pairs = 0``, NaN.
    """
    groups = by_method(records)
    ref = canonical_method(reference)
    if ref not in groups:
        return []
    ref_vals = _per_key(groups[ref], metrics)
    out = []
    for key, recs in groups.items():
        if key == ref:
            continue
        vals = _per_key(recs, metrics)
        common = sorted(set(vals) & set(ref_vals))
        if common:
            d = np.array([vals[c] - ref_vals[c] for c in common])
            mean, lo, hi = paired_bootstrap(d, n_boot, seed)
        else:
            mean = lo = hi = np.full(len(metrics), math.nan)
        out += [PairedDiff(key, ref, m, len(common), float(mean[j]), float(lo[j]), float(hi[j]))
                for j, m in enumerate(metrics)]
    return out


# --- formatting ---------------------------------------------------------------------------------
def _f(x: float, spec: str) -> str:
    return "–" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, spec)


def _sr_text(c: Cell, ci: bool = True) -> str:
    if c.n == 0:
        return "–"
    s = _f(100 * c.sr, ".1f")
    return f"{s} [{100 * c.sr_lo:.1f}, {100 * c.sr_hi:.1f}]" if ci else s


def _rows_with_paper(rows: Sequence[TableRow], paper) -> list[tuple[str, TableRow, Mapping | None]]:
    """(source, our row, paper numbers or None) in display order: each of our rows, then its paper row."""
    out: list[tuple[str, TableRow, Mapping | None]] = []
    for r in rows:
        out.append(("ours", r, None))
        if paper and r.method in paper:
            out.append(("paper", r, paper[r.method]))
    return out


def _paper_cells(p: Mapping, g: str, dash: str = "–") -> tuple[str, str, str]:
    return (f"{p[g][0]:.2f}", f"{p[g][1]:.3f}", f"{p[g][2]:.3f}") if g in p else (dash,) * 3


def _groups(rows: Sequence[TableRow]) -> list[str]:
    return list(rows[0].cells) if rows else [*DIFFICULTIES, "total"]


def format_markdown(rows: Sequence[TableRow], paper: Mapping | None = None) -> str:
    """Markdown Table I: SR % [95% Wilson CI], SPL, DTS per group; with ``paper``, each row is followed by the paper's."""
    groups = _groups(rows)
    head = ["method", "n"] + [f"{g.capitalize()} {m}" for g in groups for m in ("SR %", "SPL", "DTS")]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for source, row, p in _rows_with_paper(rows, paper):
        if p is None:
            cells = [c for g in groups for c in (_sr_text(row.cells[g]), _f(row.cells[g].spl, ".3f"), _f(row.cells[g].dts, ".3f"))]
            lines.append(f"| {row.label} | {row.cells['total'].n} | " + " | ".join(cells) + " |")
        else:
            cells = [c for g in groups for c in _paper_cells(p, g)]
            lines.append("| *paper* | | " + " | ".join(f"*{c}*" for c in cells) + " |")
    return "\n".join(lines) + "\n"


def format_counts_markdown(rows: Sequence[TableRow]) -> str:
    """Episodes (and successes) per cell: ``k / n``."""
    groups = _groups(rows)
    lines = ["| method | " + " | ".join(g.capitalize() for g in groups) + " |", "|" + "---|" * (len(groups) + 1)]
    lines += [f"| {r.label} | " + " | ".join(f"{r.cells[g].successes} / {r.cells[g].n}" for g in groups) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def format_csv(rows: Sequence[TableRow], paper: Mapping | None = None) -> str:
    """Wide CSV in the layout of ``paper_table1.csv`` (SR in %), plus n, k and the SR interval per group, and ``source``."""
    groups = _groups(rows)
    cols = ["method", "label", "source"] + [f"{g}_{c}" for g in groups for c in ("n", "k", "sr", "sr_lo", "sr_hi", "spl", "dts")]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for source, row, p in _rows_with_paper(rows, paper):
        vals: list = [row.method, row.label, source]
        for g in groups:
            c = row.cells[g]
            if p is not None:
                sr, s, d = _paper_cells(p, g, "")
                vals += ["", "", sr, "", "", s, d]
            elif c.n == 0:
                vals += [0, 0, "", "", "", "", ""]
            else:
                vals += [c.n, c.successes, *(f"{100 * v:.2f}" for v in (c.sr, c.sr_lo, c.sr_hi)), f"{c.spl:.4f}", f"{c.dts:.4f}"]
        w.writerow(vals)
    return buf.getvalue()


def _tex(s: str) -> str:
    return re.sub(r"([&%$#_{}])", r"\\\1", s)


def format_latex(rows: Sequence[TableRow], paper: Mapping | None = None) -> str:
    """A booktabs ``tabular`` of Table I; SR with its 95% Wilson interval in small type; paper rows in italics."""
    groups = _groups(rows)
    out = [r"\begin{tabular}{l" + " ccc" * len(groups) + "}", r"\toprule",
           " & " + " & ".join(rf"\multicolumn{{3}}{{c}}{{{g.capitalize()}}}" for g in groups) + r" \\",
           " ".join(rf"\cmidrule(lr){{{2 + 3 * i}-{4 + 3 * i}}}" for i in range(len(groups))),
           "Method & " + " & ".join("SR & SPL & DTS" for _ in groups) + r" \\", r"\midrule"]
    for source, row, p in _rows_with_paper(rows, paper):
        if p is None:
            cells = []
            for g in groups:
                c = row.cells[g]
                sr = "--" if c.n == 0 else rf"{100 * c.sr:.1f}\,{{\scriptsize[{100 * c.sr_lo:.1f}, {100 * c.sr_hi:.1f}]}}"
                cells += [sr, _f(c.spl, ".3f").replace("–", "--"), _f(c.dts, ".3f").replace("–", "--")]
            out.append(_tex(row.label) + " & " + " & ".join(cells) + r" \\")
        else:
            cells = [rf"\textit{{{v}}}" for g in groups for v in _paper_cells(p, g, "--")]
            out.append(r"\quad\textit{paper} & " + " & ".join(cells) + r" \\")
    out += [r"\bottomrule", r"\end{tabular}"]
    return "\n".join(out) + "\n"


def format_paired_markdown(diffs: Sequence[PairedDiff]) -> str:
    """Table of paired differences to the reference: SR in percentage points, SPL as is, with verdicts."""
    by: dict[str, dict[str, PairedDiff]] = {}
    for d in diffs:
        by.setdefault(d.method, {})[d.metric] = d
    metrics = list(dict.fromkeys(d.metric for d in diffs))
    ref = method_label(diffs[0].reference) if diffs else "NUE (full)"
    scale = {"sr": 100.0}
    unit = {"sr": " (pp)"}
    head = ["method", "pairs"] + [h for m in metrics for h in (f"Δ{m.upper()}{unit.get(m, '')} vs {ref} [95% CI]", "verdict")]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for key in order_methods(by):
        cells = []
        for m in metrics:
            d, s = by[key][m], scale.get(m, 1.0)
            fmt = ".1f" if m == "sr" else ".3f"
            cells += [f"{_f(s * d.mean, '+' + fmt)} [{_f(s * d.lo, '+' + fmt)}, {_f(s * d.hi, '+' + fmt)}]",
                      d.verdict(higher_is_better=m != "dts")]
        lines.append(f"| {method_label(key)} | {next(iter(by[key].values())).n_pairs} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


# --- files --------------------------------------------------------------------------------------
def load_records(*paths, drop_duplicates: bool = False, on_dropped: OnDropped | None = None) -> list[EpisodeRecord]:
    """Records from JSON-lines files (one ``EpisodeRecord.to_dict()`` per line; blank lines skipped),
    checked by :func:`nue.evaluate.diagnose.read_records` (a bad file or line, or a key recorded twice in a file,
    raises DataError; ``drop_duplicates`` keeps the first record of each key instead), with the hand-off files
    beside them attached (:func:`nue.evaluate.handoff_job.load_records_with_handoff`)."""
    from nue.evaluate.handoff_job import load_records_with_handoff

    return load_records_with_handoff(*paths, drop_duplicates=drop_duplicates, on_dropped=on_dropped)


NOTES = (
    "SR in %, with the 95% Wilson score interval in brackets; SPL; DTS in metres; Total pools all episodes "
    "(not the mean of the bins). *paper* rows: the paper's Table I (Gibson scenes in iGibson). Our scenes differ, "
    "so compare orderings, not values. The paper's FR total SPL (.012) cannot follow from its per-bin SPLs (a typo)."
)


def unreachable_markdown(records: Sequence[EpisodeRecord]) -> str:
    """A line naming the episodes left out of DTS (:func:`nue.evaluate.metrics.unreachable_end`), or ''."""
    ends = sorted((method_label(canonical_method(r.method)), r.scene, r.episode_id) for r in records if unreachable_end(r))
    if not ends:
        return ""
    names = ", ".join(f"{m} {s}/{e}" for m, s, e in ends)
    return (f"Left out of DTS ({len(ends)} episode(s); failures in SR and SPL): {names}, which ended where the "
            "planning grid has no path to the goal (a pocket reached through a gap narrower than its free cells).\n")


def closed_loop_markdown(records: Sequence[EpisodeRecord], task: str = "paper") -> str:
    """Per-method closed-loop diagnostics (:mod:`nue.evaluate.diagnose`) as a Markdown table plus its notes."""
    return f"{format_record_diagnostics(record_diagnostics(records, task))}\n{DIAGNOSTICS_NOTES}\n"


HANDOFF_NOTES = (
    "The goal is *in view* when its grid cell is seen as floor in the current depth frame within 3 m of the robot "
    "(the exploring expert's switch); search = steps before that, exploitation = steps from it to the end. A failure "
    "is *found, then lost* when the goal was in view or the robot came within 2 m geodesic of it (from farther away), "
    "*near, unseen* when it came within 3 m but neither, *never near* otherwise (`nue.evaluate.handoff`). Records "
    "made before the evaluation measured it carry it in `records_<set>.handoff.jsonl`, recomputed from their "
    "trajectories (depth re-rendered at the stored 1 cm / 1 mrad poses)."
)


def handoff_markdown(records: Sequence[EpisodeRecord]) -> str:
    """The hand-off table (:func:`nue.evaluate.handoff.format_handoff_markdown`) per method of the table (canonical
    names, table order) with its notes; '' when no record carries a hand-off."""
    from nue.evaluate.handoff import format_handoff_markdown, format_outcome_differences, handoff_summaries, outcome_differences

    key = lambda r: canonical_method(r.method)  # noqa: E731
    summaries = handoff_summaries(records, method_of=key)
    if not summaries:
        return ""
    ordered = {k: summaries[k] for k in order_methods(summaries)}
    labels = {k: method_label(k) for k in ordered}
    text = f"{format_handoff_markdown(ordered, labels)}\n{HANDOFF_NOTES}\n"
    diffs = outcome_differences(records, method_of=key)
    if diffs:
        rank = {k: i for i, k in enumerate(order_methods({d.method for d in diffs}))}
        diffs = sorted(diffs, key=lambda d: rank[d.method])
        text += ("\nPaired differences of the failure classes to NUE (the share of episodes, NUE's minus the method's; "
                 "below 0 = NUE fails that way less often; 95% paired bootstrap over the episodes both ran):\n\n"
                 f"{format_outcome_differences(diffs, labels)}")
    return text


def write_report(records: Sequence[EpisodeRecord], out_dir, reference: bool = True, task: str = "paper") -> dict[str, Path]:
    """Write ``table.md`` (table, counts, paired differences, closed-loop diagnostics), ``table.csv`` and
    ``table.tex``.

    Returns ``{name: path}``. ``reference``: interleave the paper's rows; ``task``: the preset of the action ids.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows = build_table(records)
    paper = paper_table() if reference else None
    md = (f"# Table I\n\n{format_markdown(rows, paper)}\n{NOTES}\n\n## Episodes per cell (successes / episodes)\n\n"
          f"{format_counts_markdown(rows)}\n{unreachable_markdown(records)}## Paired differences to NUE\n\n{format_paired_markdown(paired_differences(records))}"
          f"\n## Closed-loop diagnostics\n\n{closed_loop_markdown(records, task)}")
    handoff = handoff_markdown(records)
    if handoff:
        md += f"\n## Exploration -> exploitation hand-off\n\n{handoff}"
    paths = {"table.md": out / "table.md", "table.csv": out / "table.csv", "table.tex": out / "table.tex"}
    paths["table.md"].write_text(md)
    paths["table.csv"].write_text(format_csv(rows, paper))
    paths["table.tex"].write_text(format_latex(rows, paper))
    return paths


def coverage_curves(records: Sequence[EpisodeRecord]) -> dict[str, np.ndarray]:
    """Mean seen-area-vs-step curve (m²) per method of the table (canonical names, in table order)."""
    keys = order_methods({canonical_method(r.method) for r in records})
    return cov.mean_coverage_curves(records, keys, method_of=lambda r: canonical_method(r.method))


def ordering_markdown(rows: Sequence[TableRow], paper: Mapping) -> str:
    shared = [r for r in rows if r.method in paper and r.cells["total"].n]
    if len(shared) < 2:
        return ""
    ours = sorted(shared, key=lambda r: (-r.cells["total"].sr, r.label))
    theirs = sorted(shared, key=lambda r: (-paper[r.method]["total"][0], r.label))
    lines = ["| rank | ours (total SR %) | paper (total SR %) |", "|---|---|---|"]
    lines += [f"| {i + 1} | {a.label} ({100 * a.cells['total'].sr:.1f}) | {b.label} ({paper[b.method]['total'][0]:.2f}) |"
              for i, (a, b) in enumerate(zip(ours, theirs))]
    tau = kendalltau([r.cells["total"].sr for r in shared], [paper[r.method]["total"][0] for r in shared]).statistic
    return "\n".join(lines) + f"\n\nKendall's tau between the two orderings: {_f(float(tau), '.2f')}.\n"
