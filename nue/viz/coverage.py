"""The exploration-coverage figure: mean seen floor area (m²) against the step, one line per method.

The curves come from :func:`nue.evaluate.report.coverage_curves` (per-step areas of the records,
averaged per method by :func:`nue.evaluate.coverage.mean_coverage_curves`); this module only draws them.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from nue.evaluate.report import coverage_curves, method_label
from nue.sim.record import EpisodeRecord
from nue.viz.plot import plt, save_figure


def plot_coverage(curves: Mapping[str, np.ndarray], path, labels: Mapping[str, str] | None = None,
                  title: str = "Exploration coverage") -> Path:
    """Save a PNG of seen floor area (m²) vs step, one line per method (``curves``: name -> (L,) m²)."""
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for name, c in curves.items():
        ax.plot(np.arange(1, len(c) + 1), c, lw=1.6, label=(labels or {}).get(name, name))
    if curves:
        ax.legend(fontsize=8, loc="lower right")
    else:
        ax.text(0.5, 0.5, "no coverage recorded", ha="center", va="center", transform=ax.transAxes)
    ax.set_xlabel("step")
    ax.set_ylabel("seen floor area (m²)")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, path)


def write_coverage_figure(records: Sequence[EpisodeRecord], out_dir) -> dict[str, Path]:
    """``out_dir/coverage.png`` of the records' methods (the report's figure); returns ``{"coverage.png": path}``."""
    curves = coverage_curves(records)
    path = plot_coverage(curves, Path(out_dir) / "coverage.png", {k: method_label(k) for k in curves})
    return {"coverage.png": path}
