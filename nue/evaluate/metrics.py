"""Navigation metrics as pure functions of an :class:`EpisodeRecord`, and their aggregation.

- success S: the episode ended in success under its task preset;
- SPL = S * l / max(l, p), l = geodesic start->goal distance, p = path travelled (Anderson et al. 2018);
- DTS = 0 on success, else max(d_geo(final, goal) - r, 0) with the preset's success radius r
  (Chaplot et al. 2020);
- totals are pooled over episodes, not the mean of per-difficulty means.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable, Sequence

from nue.sim.record import EpisodeRecord

__all__ = ["EpisodeRecord", "aggregate", "collisions", "dts", "format_table", "path_length", "spl", "success",
           "summarize", "Summary", "unreachable_end"]


def success(r: EpisodeRecord) -> float:
    """1.0 if the episode succeeded, else 0.0."""
    return 1.0 if r.success else 0.0


def spl(r: EpisodeRecord) -> float:
    """Success weighted by path length: S * l / max(l, p)."""
    if not r.success:
        return 0.0
    denom = max(r.geodesic_start, r.path_length)
    return 1.0 if denom <= 0 else r.geodesic_start / denom


def dts(r: EpisodeRecord) -> float:
    """Distance to success: 0 on success, else max(final geodesic distance - r, 0); inf when the episode
    ended where the planning grid has no path to the goal (:func:`unreachable_end`)."""
    if r.success:
        return 0.0
    return max(r.final_geodesic - r.success_radius, 0.0)


def unreachable_end(r: EpisodeRecord) -> bool:
    """Whether a failed episode ended where the planning grid has no path to the goal (final geodesic inf):
    a pocket the robot slid into through a gap narrower than the grid's free cells. It has no DTS, so
    :func:`summarize` leaves it out of the DTS mean; it counts as a failure in SR and SPL."""
    return not r.success and not math.isfinite(r.final_geodesic)


def path_length(r: EpisodeRecord) -> float:
    return r.path_length


def collisions(r: EpisodeRecord) -> float:
    return float(r.collisions)


@dataclass(frozen=True)
class Summary:
    """Means over a group of episodes."""

    n: int
    sr: float
    spl: float
    dts: float
    path_length: float
    collisions: float


def summarize(records: Sequence[EpisodeRecord]) -> Summary:
    """Means of the metrics over ``records`` (NaN for an empty group); DTS over the episodes that have one
    (not :func:`unreachable_end`)."""
    n = len(records)
    if n == 0:
        nan = math.nan
        return Summary(0, nan, nan, nan, nan, nan)
    mean = lambda f: sum(f(r) for r in records) / n  # noqa: E731
    reachable = [dts(r) for r in records if not unreachable_end(r)]
    mean_dts = sum(reachable) / len(reachable) if reachable else math.nan
    return Summary(n, mean(success), mean(spl), mean_dts, mean(path_length), mean(collisions))


def aggregate(records: Iterable[EpisodeRecord], order: Sequence[str] = ("easy", "medium", "hard")) -> dict[str, Summary]:
    """Summaries per difficulty (in ``order``, then any others) and ``total`` pooled over all episodes."""
    records = list(records)
    groups = list(order) + sorted({r.difficulty for r in records} - set(order))
    out = {g: summarize([r for r in records if r.difficulty == g]) for g in groups}
    out["total"] = summarize(records)
    return out


def format_table(summaries: dict[str, Summary]) -> str:
    """A Markdown table of SR (%), SPL, DTS, path length and collisions per group."""
    lines = ["| group | n | SR % | SPL | DTS | path m | collisions |", "|---|---|---|---|---|---|---|"]
    for g, s in summaries.items():
        if s.n == 0:
            continue
        lines.append(
            f"| {g} | {s.n} | {100 * s.sr:.1f} | {s.spl:.3f} | {s.dts:.3f} | {s.path_length:.2f} | {s.collisions:.2f} |"
        )
    return "\n".join(lines)
