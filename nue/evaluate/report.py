"""Evaluation report: Table I from episode records as Markdown / CSV / LaTeX next to the paper's numbers,
paired-bootstrap differences to NUE, the coverage curves, and the text of RESULTS.md.

* Table data (rows, cells, SR with its 95% Wilson score interval, the paper's numbers):
  :mod:`nue.evaluate.table`; the statistics: :mod:`nue.evaluate.stats`.
* Paired differences to NUE (over episodes; over training seeds x episodes for a method run with several seeds):
  :mod:`nue.evaluate.paired`. The episode count resolves the ordering when the interval excludes 0.
* Several training seeds of a method (runs ``<model>@s<k>``): one row of seed means with the range over the seeds
  (:func:`nue.evaluate.table.make_seed_cell`), the seeds' runs in a table of their own (:func:`format_seeds_markdown`).
* ``write_report(records, out_dir)`` -> table.md, table.csv, table.tex (the coverage figure is
  :func:`nue.viz.coverage.write_coverage_figure`'s). The text of RESULTS.md, built from these pieces, is
  :mod:`nue.evaluate.results_md`'s.
"""

from __future__ import annotations

import csv
import io
import math
import re
from pathlib import Path
from typing import Mapping, Sequence

from scipy.stats import kendalltau

from nue.evaluate.coverage import COVERAGE_NOTE, coverage_curves  # noqa: F401  (re-exported)
from nue.evaluate.diagnose import DIAGNOSTICS_NOTES, format_record_diagnostics, record_diagnostics
from nue.evaluate.metrics import unreachable_end
from nue.evaluate.paired import (  # noqa: F401  (re-exported)
    METRIC_FNS, PairedDiff, SeedPairDiff, holm_verdicts, in_holm_family, paired_differences, seed_dependence_markdown,
)
from nue.evaluate.record_keys import OnDropped
from nue.evaluate.stats import paired_bootstrap, seed_episode_bootstrap, wilson_interval  # noqa: F401  (re-exported)
from nue.evaluate.table import (  # noqa: F401  (re-exported)
    DIFFICULTIES, METHODS, Cell, TableRow, build_table, by_method, canonical_method, method_label,
    order_methods, run_label,
    paper_table, seed_run_name, split_seed,
)
from nue.evaluate.row_notes import MEMORY_BASELINES, msm_note, sling_notes  # noqa: F401 (re-exported)
from nue.sim.record import EpisodeRecord


# --- formatting ---------------------------------------------------------------------------------
def _f(x: float, spec: str) -> str:
    return "–" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, spec)


def _sr_text(c: Cell, ci: bool = True) -> str:
    if c.n == 0:
        return "–"
    s = _f(100 * c.sr, ".1f")
    if c.spread is not None:  # several seeds: the range over the seeds, not a Wilson interval
        return f"{s} ({_range_text(c.spread.sr, '.1f', 100)})" if ci else s
    return f"{s} [{100 * c.sr_lo:.1f}, {100 * c.sr_hi:.1f}]" if ci else s


def _range_text(lo_hi: tuple[float, float], spec: str, scale: float = 1.0) -> str:
    return f"{_f(scale * lo_hi[0], spec)}–{_f(scale * lo_hi[1], spec)}"


def _cell_texts(c: Cell) -> tuple[str, str, str]:
    """SR, SPL and DTS of a cell as Table I shows them (several seeds: each with its range over the seeds)."""
    if c.spread is None or c.n == 0:
        return _sr_text(c), _f(c.spl, ".3f"), _f(c.dts, ".3f")
    return (_sr_text(c), f"{_f(c.spl, '.3f')} ({_range_text(c.spread.spl, '.3f')})",
            f"{_f(c.dts, '.3f')} ({_range_text(c.spread.dts, '.3f')})")


def _n_text(row: TableRow) -> str:
    """Episodes of a row: ``n``, or ``n x seeds`` (the episodes of one seed's run) when each seed ran as many."""
    c = row.cells["total"]
    if c.spread is None:
        return str(c.n)
    per_seed = set(c.spread.episodes)
    return f"{per_seed.pop()} x {c.spread.seeds}" if len(per_seed) == 1 else f"{c.n} ({c.spread.seeds} seeds)"


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
    for _source, row, p in _rows_with_paper(rows, paper):
        if p is None:
            cells = [c for g in groups for c in _cell_texts(row.cells[g])]
            lines.append(f"| {row.label} | {_n_text(row)} | " + " | ".join(cells) + " |")
        else:
            cells = [c for g in groups for c in _paper_cells(p, g)]
            lines.append("| *paper* | | " + " | ".join(f"*{c}*" for c in cells) + " |")
    return "\n".join(lines) + "\n"


def _count_text(c: Cell) -> str:
    """``k / n``; several seeds: each seed's ``k`` over the common ``n`` (``40, 42, 45 / 84``), else ``k / n`` each."""
    if c.spread is None or c.n == 0:
        return f"{c.successes} / {c.n}"
    if len(set(c.spread.episodes)) == 1:
        return f"{', '.join(map(str, c.spread.successes))} / {c.spread.episodes[0]}"
    return ", ".join(f"{k} / {n}" for k, n in zip(c.spread.successes, c.spread.episodes))


def format_counts_markdown(rows: Sequence[TableRow]) -> str:
    """Episodes (and successes) per cell: ``k / n`` (several seeds: per seed, :func:`_count_text`)."""
    groups = _groups(rows)
    lines = ["| method | " + " | ".join(g.capitalize() for g in groups) + " |", "|" + "---|" * (len(groups) + 1)]
    lines += [f"| {r.label} | " + " | ".join(_count_text(r.cells[g]) for g in groups) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def format_seeds_markdown(rows: Sequence[TableRow]) -> str:
    """Each training seed's run of the rows with several seeds: its totals (SR % [95% Wilson CI], SPL, DTS); '' when
    every row is a single run."""
    lines = ["| method | run | n | SR % | SPL | DTS |", "|---|---|---|---|---|---|"]
    for r in rows:
        for run, c in zip(r.runs, r.seed_totals):
            lines.append(f"| {r.label} | `{run}` | {c.n} | {_sr_text(c)} | {_f(c.spl, '.3f')} | {_f(c.dts, '.3f')} |")
    return "\n".join(lines) + "\n" if len(lines) > 2 else ""


def format_csv(rows: Sequence[TableRow], paper: Mapping | None = None) -> str:
    """Wide CSV in the layout of ``paper_table1.csv`` (SR in %), plus n, k and the SR interval per group, and ``source``."""
    groups = _groups(rows)
    seeded = any(r.seeds > 1 for r in rows)  # then a seeds column and the range over seeds of each value
    extra = ("sr_min", "sr_max", "spl_min", "spl_max", "dts_min", "dts_max") if seeded else ()
    cols = ["method", "label", "source", *(["seeds"] if seeded else [])] + [
        f"{g}_{c}" for g in groups for c in ("n", "k", "sr", "sr_lo", "sr_hi", "spl", "dts", *extra)]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for source, row, p in _rows_with_paper(rows, paper):
        vals: list = [row.method, row.label, source, *([row.seeds if p is None else ""] if seeded else [])]
        for g in groups:
            c = row.cells[g]
            if p is not None:
                sr, s, d = _paper_cells(p, g, "")
                vals += ["", "", sr, "", "", s, d, *[""] * len(extra)]
            elif c.n == 0:
                vals += [0, 0, "", "", "", "", "", *[""] * len(extra)]
            else:
                vals += [c.n, c.successes, *(_f(100 * v, ".2f").replace("–", "") for v in (c.sr, c.sr_lo, c.sr_hi)),
                         f"{c.spl:.4f}", f"{c.dts:.4f}"]
                if seeded and c.spread is not None:
                    sp = c.spread
                    vals += [f"{100 * sp.sr[0]:.2f}", f"{100 * sp.sr[1]:.2f}", *(f"{v:.4f}" for v in (*sp.spl, *sp.dts))]
                elif seeded:
                    vals += [""] * len(extra)
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
    for _source, row, p in _rows_with_paper(rows, paper):
        if p is None:
            cells = []
            for g in groups:
                c = row.cells[g]
                if c.n and c.spread is not None:  # several seeds: the seed mean and the range over the seeds
                    sp = c.spread
                    cells += [rf"{100 * c.sr:.1f}\,{{\scriptsize({_range_text(sp.sr, '.1f', 100)})}}".replace("–", "--"),
                              *(rf"{v:.3f}\,{{\scriptsize({_range_text(r, '.3f')})}}".replace("–", "--")
                                for v, r in ((c.spl, sp.spl), (c.dts, sp.dts)))]
                    continue
                sr = "--" if c.n == 0 else rf"{100 * c.sr:.1f}\,{{\scriptsize[{100 * c.sr_lo:.1f}, {100 * c.sr_hi:.1f}]}}"
                cells += [sr, _f(c.spl, ".3f").replace("–", "--"), _f(c.dts, ".3f").replace("–", "--")]
            out.append(_tex(row.label) + " & " + " & ".join(cells) + r" \\")
        else:
            cells = [rf"\textit{{{v}}}" for g in groups for v in _paper_cells(p, g, "--")]
            out.append(r"\quad\textit{paper} & " + " & ".join(cells) + r" \\")
    out += [r"\bottomrule", r"\end{tabular}"]
    return "\n".join(out) + "\n"


def format_paired_markdown(diffs: Sequence[PairedDiff]) -> str:
    """Table of paired differences to the reference: SR in percentage points, SPL as is, with verdicts; a resolved
    verdict says whether it survives the Holm correction across the table's rows (:func:`holm_verdicts`)."""
    by: dict[str, dict[str, PairedDiff]] = {}
    for d in diffs:
        by.setdefault(d.method, {})[d.metric] = d
    metrics = list(dict.fromkeys(d.metric for d in diffs))
    ref = method_label(diffs[0].reference) if diffs else "NUE (full)"
    scale = {"sr": 100.0}
    unit = {"sr": " (pp)"}
    kept = holm_verdicts(diffs)
    rows = {m: sum(1 for d in diffs if d.metric == m and in_holm_family(d)) for m in metrics}
    head = ["method", "pairs"] + [h for m in metrics for h in (f"Δ{m.upper()}{unit.get(m, '')} vs {ref} [95% CI]", "verdict",
                                                              f"Holm over {rows[m]} rows")]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for key in order_methods(by):
        cells = []
        for m in metrics:
            d, s = by[key][m], scale.get(m, 1.0)
            fmt = ".1f" if m == "sr" else ".3f"
            after = ("" if not d.resolved or not in_holm_family(d) else "holds" if kept[(key, m)]
                     else f"not resolved (p {_f(d.p, '.3f')})")
            cells += [f"{_f(s * d.mean, '+' + fmt)} [{_f(s * d.lo, '+' + fmt)}, {_f(s * d.hi, '+' + fmt)}]",
                      d.verdict(higher_is_better=m != "dts"), after]
        first = next(iter(by[key].values()))
        seeds = f" ({first.seeds} x {first.reference_seeds} seeds)" if first.seed_pairs else ""
        lines.append(f"| {method_label(key)} | {first.n_pairs}{seeds} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


# --- files --------------------------------------------------------------------------------------
def load_records(*paths, drop_duplicates: bool = False, on_dropped: OnDropped | None = None) -> list[EpisodeRecord]:
    """Records from JSON-lines files (one ``EpisodeRecord.to_dict()`` per line; blank lines skipped),
    checked by :func:`nue.evaluate.diagnose.read_records` (a bad file or line, or a key recorded twice in a file,
    raises DataError; ``drop_duplicates`` keeps the first record of each key instead), with the hand-off files
    beside them attached (:func:`nue.evaluate.handoff_job.load_records_with_handoff`)."""
    from nue.evaluate.handoff_job import load_records_with_handoff

    return load_records_with_handoff(*paths, drop_duplicates=drop_duplicates, on_dropped=on_dropped)


SEED_NOTES = (
    "Rows with several training seeds (n = episodes x seeds; each seed's run trained from the same demonstrations "
    "and evaluated on the same episodes with the same per-episode seeds, only the training seed differs): each cell "
    "is the mean over the seeds of each run's own SR / SPL / DTS, with the range over the seeds (min–max of the "
    "per-seed values) in parentheses in place of the Wilson interval; the runs are listed under *Training seeds*. "
    "The coverage curves pool a method's seeds too; the closed-loop diagnostics and the hand-off tables list each "
    "seed's run (`<label> @s<k>`)."
)
PAIRED_SEED_NOTES = (
    "With several training seeds on either side (pairs: episodes (method's x NUE's seeds)), a difference is the mean "
    "over the episodes every seed's run of both ran of the method's seed mean minus NUE's, and its interval a "
    "two-level bootstrap (10,000 resamples, seed 0): each resample draws each side's seeds with replacement, then the "
    "episodes (paired), so it covers both the sampling of episodes and of training seeds (with 3 seeds it "
    "understates the seed part: the bootstrap variance of a mean of 3 draws is 2/3 of the unbiased one). Each pair "
    "of seeds' runs also gets its own episode bootstrap; a comparison whose verdict differs between them is listed "
    "below the table."
)


def seed_notes(rows: Sequence[TableRow]) -> str:
    """:data:`SEED_NOTES` and the *Training seeds* table (:func:`format_seeds_markdown`) when some row has several
    seeds, with a blank line before; then :func:`sling_notes`; '' when neither applies (such a table is unchanged)."""
    seeds = format_seeds_markdown(rows)
    return ((f"\n{SEED_NOTES}\n\nTraining seeds (each run's totals):\n\n{seeds}" if seeds else "") + sling_notes(rows)
            + msm_note(rows))


HOLM_NOTE = (
    "Multiple comparisons: the table compares every row with the same reference, so some intervals exclude 0 by "
    "chance. \"Holm over k rows\" corrects each metric's k comparisons together (Holm-Bonferroni, family-wise 5%, "
    "on two-sided bootstrap p-values from the same resamples as the intervals): \"holds\" when a resolved verdict "
    "survives it. The family is every row of the current recipe in the table, controls (+swap) and training seeds' "
    "rows included; earlier recipes' rows (`_v<N>`) are listed for history and not counted."
)


def paired_markdown(diffs: Sequence[PairedDiff]) -> str:
    """The paired-differences table with :data:`HOLM_NOTE`, then (several training seeds) :data:`PAIRED_SEED_NOTES`
    and the comparisons whose verdict depends on the seed (:func:`nue.evaluate.paired.seed_dependence_markdown`)."""
    text = format_paired_markdown(diffs) + (f"\n{HOLM_NOTE}\n" if diffs else "")
    if not any(d.seed_pairs for d in diffs):
        return text
    depends = seed_dependence_markdown(diffs)
    return (f"{text}\n{PAIRED_SEED_NOTES}\n\n" + (f"Verdicts that depend on the seed:\n\n{depends}" if depends else
                                                "No verdict depends on the seed: every pair of seeds' runs agrees with the pooled one.\n"))


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


def handoff_markdown(records: Sequence[EpisodeRecord], reference: str = "nue") -> str:
    """The hand-off table (:func:`nue.evaluate.handoff.format_handoff_markdown`) per method of the table (canonical
    names, table order) with its notes, and the failure classes' paired differences to ``reference``; '' when no
    record carries a hand-off."""
    from nue.evaluate.handoff import format_handoff_markdown, format_outcome_differences, handoff_summaries, outcome_differences

    key = lambda r: canonical_method(r.method)  # noqa: E731
    summaries = handoff_summaries(records, method_of=key)
    if not summaries:
        return ""
    ordered = {k: summaries[k] for k in order_methods(summaries)}
    labels = {k: run_label(k, ordered) for k in ordered}
    text = f"{format_handoff_markdown(ordered, labels)}\n{HANDOFF_NOTES}\n"
    diffs = outcome_differences(records, reference=canonical_method(reference), method_of=key)
    if diffs:
        rank = {k: i for i, k in enumerate(order_methods({d.method for d in diffs}))}
        diffs = sorted(diffs, key=lambda d: rank[d.method])
        ref = reference_label(reference)
        text += (f"\nPaired differences of the failure classes to {ref} (the share of episodes, {ref}'s minus the "
                 f"method's; below 0 = {ref} fails that way less often; 95% paired bootstrap over the episodes both "
                 "ran; a method's training seeds are pooled, seeds x episodes, as in the paired differences of SR):\n\n"
                 f"{format_outcome_differences(diffs, {d.method: method_label(d.method) for d in diffs}, ref)}")
    return text


def reference_label(reference: str) -> str:
    """"NUE" for the default reference, else the method's row label."""
    key = canonical_method(reference)
    return "NUE" if key == "nue" else method_label(key)


def write_report(records: Sequence[EpisodeRecord], out_dir, reference: bool = True, task: str = "paper",
                 compare_to: str = "nue") -> dict[str, Path]:
    """Write ``table.md`` (table, counts, paired differences, closed-loop diagnostics), ``table.csv`` and
    ``table.tex``.

    Returns ``{name: path}``. ``reference``: interleave the paper's rows; ``task``: the preset of the action ids;
    ``compare_to``: the method the paired differences are to (NUE; a candidate such as ``nue_lean`` to compare
    variants of it).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows = build_table(records)
    paper = paper_table() if reference else None
    md = (f"# Table I\n\n{format_markdown(rows, paper)}\n{NOTES}\n{seed_notes(rows)}\n## Episodes per cell (successes / episodes)\n\n"
          f"{format_counts_markdown(rows)}\n{unreachable_markdown(records)}## Paired differences to {reference_label(compare_to)}\n\n"
          f"{paired_markdown(paired_differences(records, reference=compare_to))}"
          f"\n## Closed-loop diagnostics\n\n{closed_loop_markdown(records, task)}")
    handoff = handoff_markdown(records, compare_to)
    if handoff:
        md += f"\n## Exploration -> exploitation hand-off\n\n{handoff}"
    paths = {"table.md": out / "table.md", "table.csv": out / "table.csv", "table.tex": out / "table.tex"}
    paths["table.md"].write_text(md)
    paths["table.csv"].write_text(format_csv(rows, paper))
    paths["table.tex"].write_text(format_latex(rows, paper))
    return paths


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
