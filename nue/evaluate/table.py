"""Table I as data: the known methods and their order, per-cell SR (+ 95% Wilson interval) / SPL / DTS
pooled over episodes, and the paper's reference numbers (``paper_table1.csv`` next to this module).

Rows are FR, Nav-A3C, the five ablations, NUE (``nue.policy.config`` preset names or the paper's
labels both work), then unknown methods alphabetically; columns are easy, medium, hard (then any
other difficulty) and ``total``, pooled over all of a method's episodes.
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from nue.evaluate.metrics import summarize
from nue.evaluate.stats import wilson_interval
from nue.sim.record import EpisodeRecord

DIFFICULTIES = ("easy", "medium", "hard")
PAPER_CSV = Path(__file__).with_name("paper_table1.csv")


@dataclass(frozen=True)
class MethodInfo:
    """One known row of Table I."""

    key: str
    """Our preset name (``nue.policy.config.MODEL_PRESETS``)."""
    label: str
    """Row label in our tables."""
    paper_row: str
    """The row's ``method`` in ``paper_table1.csv``."""


METHODS: tuple[MethodInfo, ...] = (
    MethodInfo("fr", "FR", "FR"),
    MethodInfo("nav_a3c", "Nav-A3C", "Nav-A3C"),
    MethodInfo("abl_none", "f_u=off AT=off CBAM=off", "ablation f_u=off AT=off CBAM=off"),
    MethodInfo("abl_fu", "f_u=on AT=off CBAM=off", "ablation f_u=on AT=off CBAM=off"),
    MethodInfo("abl_at_cbam", "f_u=off AT=on CBAM=on", "ablation f_u=off AT=on CBAM=on"),
    MethodInfo("abl_fu_cbam", "f_u=on AT=off CBAM=on", "ablation f_u=on AT=off CBAM=on"),
    MethodInfo("abl_fu_at", "f_u=on AT=on CBAM=off", "ablation f_u=on AT=on CBAM=off"),
    MethodInfo("nue", "NUE (full)", "NUE (full)"),
)
_BY_KEY = {m.key: m for m in METHODS}
_norm = lambda s: re.sub(r"[^a-z0-9]", "", str(s).lower())  # noqa: E731
_ALIASES = {_norm(a): m.key for m in METHODS for a in (m.key, m.label, m.paper_row)}
_ALIASES.update({_norm("ablation " + m.label): m.key for m in METHODS})


def canonical_method(name: str) -> str:
    """Our key for a method name (``"Nav-A3C"`` -> ``nav_a3c``, ``"NUE (full)"`` -> ``nue``).

    Case and punctuation are ignored; unknown names pass through unchanged."""
    return _ALIASES.get(_norm(name), name)


def method_label(key: str) -> str:
    """Row label of a method key (the key itself when unknown)."""
    return _BY_KEY[key].label if key in _BY_KEY else key


def order_methods(keys) -> list[str]:
    """Known methods in Table I order, then the others alphabetically."""
    keys = set(keys)
    return [m.key for m in METHODS if m.key in keys] + sorted(keys - set(_BY_KEY))


@dataclass(frozen=True)
class Cell:
    """One (method, difficulty) cell of the table."""

    n: int
    """Episodes in the cell."""
    successes: int
    """Successful episodes k."""
    sr: float
    """Success rate k / n, fraction (NaN when n = 0)."""
    sr_lo: float
    """Lower end of the 95% Wilson interval of SR, fraction."""
    sr_hi: float
    """Upper end of the 95% Wilson interval of SR, fraction."""
    spl: float
    """Mean SPL."""
    dts: float
    """Mean DTS, metres."""


@dataclass(frozen=True)
class TableRow:
    """One method's row: a :class:`Cell` per group (difficulties, then ``total``)."""

    method: str
    """Method key (see :func:`canonical_method`)."""
    label: str
    """Display label."""
    cells: dict[str, Cell]
    """Group name -> cell."""


def make_cell(records: Sequence[EpisodeRecord]) -> Cell:
    """Pooled SR (+ Wilson interval), SPL and DTS of a group of records."""
    s = summarize(records)
    k = sum(1 for r in records if r.success)
    lo, hi = wilson_interval(k, s.n)
    return Cell(s.n, k, s.sr, lo, hi, s.spl, s.dts)


def groups_of(records: Sequence[EpisodeRecord]) -> list[str]:
    """Column groups: easy, medium, hard, any other difficulty (sorted), total."""
    return [*DIFFICULTIES, *sorted({r.difficulty for r in records} - set(DIFFICULTIES)), "total"]


def by_method(records: Sequence[EpisodeRecord]) -> dict[str, list[EpisodeRecord]]:
    """Records grouped by canonical method key, in table order."""
    out: dict[str, list[EpisodeRecord]] = {}
    for r in records:
        out.setdefault(canonical_method(r.method), []).append(r)
    return {k: out[k] for k in order_methods(out)}


def build_table(records: Sequence[EpisodeRecord]) -> list[TableRow]:
    """Table I rows: one per method (table order), a cell per difficulty and the pooled total."""
    groups = groups_of(records)
    rows = []
    for key, recs in by_method(records).items():
        cells = {g: make_cell(recs if g == "total" else [r for r in recs if r.difficulty == g]) for g in groups}
        rows.append(TableRow(key, method_label(key), cells))
    return rows


def paper_table(path: Path = PAPER_CSV) -> dict[str, dict[str, tuple[float, float, float]]]:
    """The paper's Table I: method key (ours, or the paper's name for other baselines) -> group -> (SR %, SPL, DTS)."""
    out = {}
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            out[canonical_method(row["method"])] = {
                g: (float(row[f"{g}_sr"]), float(row[f"{g}_spl"]), float(row[f"{g}_dts"]))
                for g in (*DIFFICULTIES, "total")
            }
    return out
