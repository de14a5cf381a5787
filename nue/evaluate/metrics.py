"""Navigation metrics as pure functions of an :class:`EpisodeRecord`, and their aggregation.

- success S: the episode ended in success under its task preset;
- SPL = S * l / max(l, p), l = geodesic start->goal distance, p = path travelled (Anderson et al. 2018);
- DTS = 0 on success, else max(d_geo(final, goal) - r, 0) with the preset's success radius r
  (Chaplot et al. 2020);
- totals are pooled over episodes, not the mean of per-difficulty means.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Iterable, Sequence


@dataclass(frozen=True)
class EpisodeRecord:
    """What one finished episode produced; everything the metrics need."""

    episode_id: str
    """Episode identifier (unique within its scene)."""
    scene: str
    """Scene name."""
    difficulty: str
    """Difficulty bin (``easy`` / ``medium`` / ``hard``)."""
    success: bool
    """Whether the episode ended in success under its task preset."""
    geodesic_start: float
    """Geodesic start->goal distance l, metres."""
    path_length: float
    """Distance travelled p, metres."""
    final_geodesic: float
    """Geodesic distance from the final position to the goal, metres."""
    final_euclidean: float
    """Euclidean xy distance from the final position to the goal, metres."""
    success_radius: float
    """The task preset's success radius r, metres."""
    collisions: int = 0
    """Number of steps in which a forward move was blocked."""
    steps: int = 0
    """Number of actions taken."""
    path_type: str = ""
    """``straight`` or ``curved`` (geodesic / euclidean < 1.2)."""
    method: str = ""
    """Name of the agent (e.g. ``expert``, ``nue``)."""
    wall_time: float = 0.0
    """Seconds the episode took."""
    extra: dict = field(default_factory=dict)
    """Free-form additions (seed, checkpoint, ...)."""

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "EpisodeRecord":
        return cls(**d)


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
    """Distance to success: 0 on success, else max(final geodesic distance - r, 0)."""
    if r.success:
        return 0.0
    return max(r.final_geodesic - r.success_radius, 0.0)


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
    """Means of the metrics over ``records`` (NaN for an empty group)."""
    n = len(records)
    if n == 0:
        nan = math.nan
        return Summary(0, nan, nan, nan, nan, nan)
    mean = lambda f: sum(f(r) for r in records) / n  # noqa: E731
    return Summary(n, mean(success), mean(spl), mean(dts), mean(path_length), mean(collisions))


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
