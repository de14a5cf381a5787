"""The coverage figures: mean seen floor area (m²) against the step, one line per row of the table.

``coverage.png`` (the report's, from goal episodes) and ``explore_<set>.png`` (the exploration benchmark's fixed-length
runs, where success never ends a run and the curves measure exploration alone). Which lines a figure shows is
:func:`coverage_lines` (data, tested); :func:`plot_coverage` only draws them. A row trained with several seeds is
one line, the mean over all its seeds' episodes, with a band from the lowest to the highest of its seeds' mean
curves. Earlier recipes' rows (``nue_v6``) are left out: the tables list them, the figure shows the current rows.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import cycle
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from nue.evaluate.coverage import COVERAGE_KEY, mean_coverage_curves, pad_curves
from nue.evaluate.report import method_label
from nue.evaluate.table import canonical_method, is_earlier_recipe, order_methods, split_seed
from nue.sim.record import EpisodeRecord
from nue.viz.plot import plt, save_figure

REFERENCES = frozenset({"expert", "expert-explore", "random"})
"""Rows that are not learned models: the experts and the random walk (drawn dotted)."""
BASELINES = frozenset({"fr", "nav_a3c", "vgm", "nrns", "msm"})
"""The paper's baselines with their own model (drawn dashed)."""
STYLES = {"nue": "-", "baseline": "--", "control": "-.", "reference": ":"}
"""Line style per kind of row: NUE and its ablations, a baseline, a control (swapped maps, SLING's last mile), a
reference."""


@dataclass(frozen=True)
class CoverageLine:
    """One line of a coverage figure."""

    key: str
    """The row's canonical method key (seeds folded: ``nue`` for ``nue`` and ``nue@s1``)."""
    label: str
    """Legend text."""
    mean: np.ndarray
    """(L,) mean seen floor area at steps 1..L over all the row's episodes, m²."""
    band: tuple[np.ndarray, np.ndarray] | None
    """(lo (L,), hi (L,)): the lowest and highest of the seeds' mean curves, m²; None for a single run."""
    seeds: int
    """Training seeds of the row."""
    kind: str
    """A key of :data:`STYLES`."""


def row_kind(key: str) -> str:
    """The kind of a canonical row key (:data:`STYLES`)."""
    if key in REFERENCES:
        return "reference"
    if key.endswith("+swap") or key.startswith("sling+"):
        return "control"
    return "baseline" if key in BASELINES or not (key == "nue" or key.startswith("abl_")) else "nue"


def coverage_lines(records: Sequence[EpisodeRecord]) -> list[CoverageLine]:
    """The lines of a coverage figure of ``records``, in Table I order: every current row carrying coverage (earlier
    recipes' rows left out), a row's seeds pooled."""
    current = [r for r in records if not is_earlier_recipe(r.method)]

    def key(r: EpisodeRecord) -> str:
        return canonical_method(split_seed(r.method)[0])

    means = mean_coverage_curves(current, order_methods({key(r) for r in current}), method_of=key)
    if not means:
        return []
    length = len(next(iter(means.values())))
    per_seed: dict[str, dict[int, list]] = {}
    for r in current:
        cov = r.extra.get(COVERAGE_KEY) if isinstance(r.extra, Mapping) else None
        if cov is not None:
            per_seed.setdefault(key(r), {}).setdefault(split_seed(r.method)[1], []).append(cov)
    lines = []
    for k, mean in means.items():
        seeds = [pad_curves(c, length).mean(axis=0) for _, c in sorted(per_seed[k].items())]
        band = (np.min(seeds, axis=0), np.max(seeds, axis=0)) if len(seeds) > 1 else None
        label = method_label(k) + (f" ({len(seeds)} seeds)" if len(seeds) > 1 else "")
        lines.append(CoverageLine(k, label, mean, band, len(seeds), row_kind(k)))
    return lines


GOAL_TITLE = "Seen floor area in goal episodes\n(a finished episode keeps its final area)"
"""Title of the report's figure: goal episodes end at success, so a curve mixes how fast a model succeeds with how
much it explores (the exploration benchmark's figure does not)."""


def plot_coverage(lines: Sequence[CoverageLine], path, title: str = GOAL_TITLE) -> Path:
    """Save a PNG of seen floor area (m²) vs step, one line per entry of ``lines`` (its seed band shaded; NUE (full)
    in black), the legend beside the axes."""
    ncol = 1 if len(lines) <= 16 else 2
    fig, ax = plt.subplots(figsize=(6.4 + 2.4 * ncol, 4.4))
    tab20 = [plt.get_cmap("tab20")(i) for i in range(20)]
    # NUE (full) in black on top; the others in tab10's hues, then their light tones (tab20 pairs them)
    colours = cycle(tab20[0::2] + tab20[1::2])
    for line in lines:
        steps = np.arange(1, len(line.mean) + 1)
        main = line.key == "nue"
        colour = "black" if main else next(colours)
        ax.plot(steps, line.mean, lw=2.4 if main else 1.5, color=colour, ls=STYLES[line.kind], label=line.label,
                zorder=3 if main else 2)
        if line.band is not None:
            ax.fill_between(steps, line.band[0], line.band[1], color=colour, alpha=0.15, lw=0)
    if lines:
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0, ncol=ncol,
                  frameon=False)
    else:
        ax.text(0.5, 0.5, "no coverage recorded", ha="center", va="center", transform=ax.transAxes)
    ax.set_xlabel("step")
    ax.set_ylabel("seen floor area (m²)")
    ax.set_title(title, fontsize=11)
    ax.grid(alpha=0.3)
    fig.subplots_adjust(left=0.08, right=6.0 / (6.4 + 2.4 * ncol), top=0.88, bottom=0.12)
    return save_figure(fig, path)


def write_coverage_figure(records: Sequence[EpisodeRecord], out_dir, name: str = "coverage.png",
                          title: str = GOAL_TITLE) -> dict[str, Path]:
    """``out_dir/<name>`` of the records' rows (the report's figure); returns ``{name: path}``."""
    return {name: plot_coverage(coverage_lines(records), Path(out_dir) / name, title)}
