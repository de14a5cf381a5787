"""Table I as data: the known methods and their order, per-cell SR (+ 95% Wilson interval) / SPL / DTS
pooled over episodes, and the paper's reference numbers (``paper_table1.csv`` next to this module).

Rows are FR, Nav-A3C, the five ablations, NUE (``nue.policy.config`` preset names or the paper's
labels both work), then unknown methods alphabetically; columns are easy, medium, hard (then any
other difficulty) and ``total``, pooled over all of a method's episodes.

A method trained with several seeds has one record method name per seed (:func:`seed_run_name`: ``nue``, ``nue@s1``,
``nue@s2``; ``nue@s1+swap`` for the swapped-maps control) and one row: the seed mean of each cell with the spread
(min–max) of the per-seed values (:func:`make_seed_cell`).
"""

from __future__ import annotations

import csv
import math
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
    paper_row: str | None
    """The row's ``method`` in ``paper_table1.csv``; None for our rows the paper has no counterpart of."""


METHODS: tuple[MethodInfo, ...] = (
    MethodInfo("fr", "FR", "FR"),
    MethodInfo("nav_a3c", "Nav-A3C", "Nav-A3C"),
    MethodInfo("vgm", "VGM", "VGM"),
    MethodInfo("nrns", "NRNS", "NRNS"),
    MethodInfo("abl_none", "f_u=off AT=off CBAM=off", "ablation f_u=off AT=off CBAM=off"),
    MethodInfo("abl_fu", "f_u=on AT=off CBAM=off", "ablation f_u=on AT=off CBAM=off"),
    MethodInfo("abl_at_cbam", "f_u=off AT=on CBAM=on", "ablation f_u=off AT=on CBAM=on"),
    MethodInfo("abl_fu_cbam", "f_u=on AT=off CBAM=on", "ablation f_u=on AT=off CBAM=on"),
    MethodInfo("abl_fu_at", "f_u=on AT=on CBAM=off", "ablation f_u=on AT=on CBAM=off"),
    MethodInfo("nue", "NUE (full)", "NUE (full)"),
    MethodInfo("sling+fr", "SLING + FR", None),
    MethodInfo("sling+nav_a3c", "SLING + Nav-A3C", None),
    MethodInfo("sling+nue", "SLING + NUE", None),
)
_BY_KEY = {m.key: m for m in METHODS}
_norm = lambda s: re.sub(r"[^a-z0-9]", "", str(s).lower())  # noqa: E731
_ALIASES = {_norm(a): m.key for m in METHODS for a in (m.key, m.label, m.paper_row) if a}
_ALIASES.update({_norm("ablation " + m.label): m.key for m in METHODS})


SEED_MARK = "@s"
"""Separates a model from its training seed index in a run's name: ``<model>@s<k>`` (k >= 1; seed 0 is ``<model>``)."""
_SEED_RUN = re.compile(r"^(.+)@s([1-9][0-9]*)(\+swap)?$")


_EARLIER_RECIPE = re.compile(r"_v[0-9]+[a-z]?(@s[0-9]+)?(\+swap)?$")


def is_earlier_recipe(method: str) -> bool:
    """Whether a record's method names an earlier recipe's model (``nue_v2``, ``fr_v1``) or an earlier run of a
    recipe (``nue_v5a``), with or without the swapped-maps control: a ``_v<N>`` or ``_v<N><letter>`` suffix
    (then a training seed's ``@s<k>``, then ``+swap``). A current recipe's seed run (``nue@s1``) is not one."""
    return bool(_EARLIER_RECIPE.search(method))


def seed_run_name(model: str, k: int) -> str:
    """The run folder / record method name of training seed ``k`` of ``model``: ``model`` for k = 0 (a single-seed
    recipe's names are unchanged), ``model@s<k>`` for k >= 1 (``nue@s2``)."""
    if k < 0:
        raise ValueError(f"seed index {k} < 0")
    return model if k == 0 else f"{model}{SEED_MARK}{k}"


def split_seed(method: str) -> tuple[str, int]:
    """(method without its seed, seed index) of a record method name: ``nue@s2`` -> (``nue``, 2), ``nue@s1+swap`` ->
    (``nue+swap``, 1), ``nue`` -> (``nue``, 0), ``nue_v5a`` -> (``nue_v5a``, 0)."""
    m = _SEED_RUN.match(method)
    return (m.group(1) + (m.group(3) or ""), int(m.group(2))) if m else (method, 0)


def canonical_method(name: str) -> str:
    """Our key for a method name (``"Nav-A3C"`` -> ``nav_a3c``, ``"NUE (full)"`` -> ``nue``).

    Case and punctuation are ignored; unknown names pass through unchanged."""
    return _ALIASES.get(_norm(name), name)


def method_label(key: str) -> str:
    """Row label of a method key (the key itself when unknown); one seed's run of a known method is labelled
    ``<label> @s<k>`` (``NUE (full) @s1``)."""
    if key in _BY_KEY:
        return _BY_KEY[key].label
    base, k = split_seed(key)
    return f"{_BY_KEY[base].label} {SEED_MARK}{k}" if k and base in _BY_KEY else key


def order_methods(keys) -> list[str]:
    """Known methods in Table I order, then the current recipe's others (experts, controls) alphabetically, then
    earlier recipes' rows (:func:`is_earlier_recipe`) alphabetically; each method's training seeds' runs
    (``<key>@s<k>``, :func:`split_seed`) follow it in seed order."""
    runs: dict[str, list[tuple[int, str]]] = {}
    for k in set(keys):
        base, seed = split_seed(k)
        runs.setdefault(base, []).append((seed, k))
    others = set(runs) - set(_BY_KEY)
    bases = ([m.key for m in METHODS if m.key in runs] + sorted(k for k in others if not is_earlier_recipe(k))
             + sorted(k for k in others if is_earlier_recipe(k)))
    return [k for b in bases for _, k in sorted(runs[b])]


def run_label(key: str, keys) -> str:
    """Row label of one training run in a table of runs: :func:`method_label`, with ``@s0`` on a seed-0 run when
    ``keys`` also holds another seed's run of its method (``NUE (full) @s0`` beside ``NUE (full) @s1``)."""
    base, seed = split_seed(key)
    if seed == 0 and any(split_seed(k)[0] == base and split_seed(k)[1] > 0 for k in keys):
        return f"{method_label(key)} {SEED_MARK}0"
    return method_label(key)


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
    spread: "SeedSpread | None" = None
    """Several training seeds: the per-seed values' range (then ``sr``, ``spl``, ``dts`` are seed means, ``n`` and
    ``successes`` sums over the seeds, and ``sr_lo`` / ``sr_hi`` NaN: a Wilson interval of the pooled episodes
    would treat the seeds' runs of one episode as independent); None for a single run."""


@dataclass(frozen=True)
class SeedSpread:
    """Range over training seeds of one cell: (min, max) of the per-seed values."""

    seeds: int
    """Training seeds of the cell."""
    sr: tuple[float, float]
    """Per-seed SR, fraction: (min, max)."""
    spl: tuple[float, float]
    """Per-seed mean SPL: (min, max)."""
    dts: tuple[float, float]
    """Per-seed mean DTS, metres: (min, max)."""
    successes: tuple[int, ...]
    """Successes per seed, seed 0 first."""
    episodes: tuple[int, ...]
    """Episodes per seed, seed 0 first."""


@dataclass(frozen=True)
class TableRow:
    """One method's row: a :class:`Cell` per group (difficulties, then ``total``)."""

    method: str
    """Method key (see :func:`canonical_method`)."""
    label: str
    """Display label."""
    cells: dict[str, Cell]
    """Group name -> cell."""
    runs: tuple[str, ...] = ()
    """Several training seeds: the record method names of the seeds' runs, by seed index; empty for a single run."""
    seed_totals: tuple[Cell, ...] = ()
    """Several training seeds: each run's own ``total`` cell, in the order of ``runs``."""

    @property
    def seeds(self) -> int:
        """Training seeds of the row (1 for a single run)."""
        return max(1, len(self.runs))


def make_cell(records: Sequence[EpisodeRecord]) -> Cell:
    """Pooled SR (+ Wilson interval), SPL and DTS of a group of records."""
    s = summarize(records)
    k = sum(1 for r in records if r.success)
    lo, hi = wilson_interval(k, s.n)
    return Cell(s.n, k, s.sr, lo, hi, s.spl, s.dts)


def make_seed_cell(per_seed: Sequence[Sequence[EpisodeRecord]]) -> Cell:
    """A cell of a method with several training seeds, from each seed's records of the cell.

    SR, SPL and DTS are the means over seeds of each seed's own value (a seed with no episode in the cell is left
    out); ``spread`` holds their (min, max). Example: seeds with 3 / 4 and 1 / 4 successes -> SR 0.5, spread
    (0.25, 0.75); ``n`` = 8, ``successes`` = 4."""
    cells = [make_cell(recs) for recs in per_seed]
    ran = [c for c in cells if c.n]
    if not ran:
        return Cell(0, 0, math.nan, math.nan, math.nan, math.nan, math.nan,
                    SeedSpread(len(cells), (math.nan,) * 2, (math.nan,) * 2, (math.nan,) * 2,
                               tuple(0 for _ in cells), tuple(0 for _ in cells)))

    def mean_range(values: list[float]) -> tuple[float, tuple[float, float]]:
        ok = [v for v in values if not math.isnan(v)]
        return (sum(ok) / len(ok), (min(ok), max(ok))) if ok else (math.nan, (math.nan, math.nan))

    sr, sr_range = mean_range([c.sr for c in ran])
    spl, spl_range = mean_range([c.spl for c in ran])
    dts, dts_range = mean_range([c.dts for c in ran])
    spread = SeedSpread(len(cells), sr_range, spl_range, dts_range, tuple(c.successes for c in cells),
                        tuple(c.n for c in cells))
    return Cell(sum(c.n for c in cells), sum(c.successes for c in cells), sr, math.nan, math.nan, spl, dts, spread)


def groups_of(records: Sequence[EpisodeRecord]) -> list[str]:
    """Column groups: easy, medium, hard, any other difficulty (sorted), total."""
    return [*DIFFICULTIES, *sorted({r.difficulty for r in records} - set(DIFFICULTIES)), "total"]


def by_method(records: Sequence[EpisodeRecord]) -> dict[str, list[EpisodeRecord]]:
    """Records grouped by canonical method key, in table order."""
    out: dict[str, list[EpisodeRecord]] = {}
    for r in records:
        out.setdefault(canonical_method(r.method), []).append(r)
    return {k: out[k] for k in order_methods(out)}


def by_method_and_seed(records: Sequence[EpisodeRecord]) -> dict[str, dict[int, list[EpisodeRecord]]]:
    """Records grouped by canonical method key (a seed's run under its method, :func:`split_seed`), in table order,
    then by training seed index (ascending)."""
    out: dict[str, dict[int, list[EpisodeRecord]]] = {}
    for r in records:
        base, k = split_seed(r.method)
        out.setdefault(canonical_method(base), {}).setdefault(k, []).append(r)
    return {key: dict(sorted(out[key].items())) for key in order_methods(out)}


def seed_runs(records: Sequence[EpisodeRecord]) -> dict[str, tuple[str, ...]]:
    """Method key -> the record method names of its training seeds' runs, by seed index (one name: a single run)."""
    names: dict[tuple[str, int], str] = {}
    for r in records:
        base, k = split_seed(r.method)
        names.setdefault((canonical_method(base), k), r.method)
    return {key: tuple(names[key, k] for k in seeds) for key, seeds in by_method_and_seed(records).items()}


def build_table(records: Sequence[EpisodeRecord]) -> list[TableRow]:
    """Table I rows: one per method (table order), a cell per difficulty and the pooled total. A method with
    several training seeds gets one row of seed means (:func:`make_seed_cell`); a single run's row is pooled over
    its episodes (:func:`make_cell`)."""
    groups = groups_of(records)
    names = seed_runs(records)
    rows = []
    for key, seeds in by_method_and_seed(records).items():
        def pick(recs, g):
            return recs if g == "total" else [r for r in recs if r.difficulty == g]

        if len(seeds) == 1:
            (recs,) = seeds.values()
            cells = {g: make_cell(pick(recs, g)) for g in groups}
            rows.append(TableRow(key, method_label(key), cells))
        else:
            cells = {g: make_seed_cell([pick(recs, g) for recs in seeds.values()]) for g in groups}
            rows.append(TableRow(key, method_label(key), cells, names[key],
                                 tuple(make_cell(recs) for recs in seeds.values())))
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
