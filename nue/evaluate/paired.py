"""Paired differences to a reference method (NUE), per metric: over the episodes both ran, and for a method trained
with several seeds over training seeds x episodes, with the note on verdicts that depend on the seed.

* One run each: ``d_i = x_method,i - x_NUE,i`` over the episodes both ran (matched on (scene, episode_id); repeated
  runs of a key are averaged), their mean and the 95% percentile interval of 10,000 paired-bootstrap resamples of
  the episodes (:func:`nue.evaluate.stats.paired_bootstrap`, ``numpy.random.default_rng(0)`` per comparison).
* Several training seeds on either side (runs ``<model>@s<k>``, :func:`nue.evaluate.table.split_seed`): the mean
  over the episodes every seed of both ran of (the method's seed mean - NUE's seed mean), with a two-level
  bootstrap interval: each resample draws each method's seeds with replacement, then the episodes (paired)
  (:func:`nue.evaluate.stats.seed_episode_bootstrap`). It covers the sampling of episodes and of training seeds,
  the latter understated with few seeds. Each (method seed, NUE seed) pair of runs also gets its own
  episode-only interval (``PairedDiff.seed_pairs``): :func:`seed_dependence_markdown` names the comparisons whose
  verdict differs between those pairs.
* Multiple comparisons: each difference also carries a bootstrap p-value, and :func:`holm_verdicts` says which
  resolved verdicts survive a Holm-Bonferroni correction across all the rows compared with the reference.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from nue.evaluate.metrics import dts, spl, success
from nue.evaluate.stats import holm, paired_bootstrap, paired_bootstrap_p, seed_episode_bootstrap_p
from nue.evaluate.table import by_method_and_seed, canonical_method, is_earlier_recipe, method_label, seed_runs
from nue.sim.record import EpisodeRecord

METRIC_FNS = {"sr": success, "spl": spl, "dts": dts}


@dataclass(frozen=True)
class SeedPairDiff:
    """The paired difference of one training seed's run of a method to one seed's run of the reference, over the
    same episodes as the pooled one (episode bootstrap only)."""

    run: str
    """The method's run (record method name, ``abl_fu@s1``)."""
    reference_run: str
    """The reference's run (``nue@s2``)."""
    mean: float
    """Mean of ``x_run - x_reference_run`` over the episodes."""
    lo: float
    """2.5th percentile of the bootstrap means."""
    hi: float
    """97.5th percentile of the bootstrap means."""


def _direction(lo: float, hi: float) -> int:
    """+1: the interval lies above 0, -1: below, 0: it contains 0 (or is NaN)."""
    return 1 if lo > 0 else -1 if hi < 0 else 0


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
    """Episodes both methods ran (with several seeds: that every seed of both ran)."""
    mean: float
    """Mean of ``x_method - x_reference`` over the pairs (each side's seed mean per episode)."""
    lo: float
    """2.5th percentile of the bootstrap means."""
    hi: float
    """97.5th percentile of the bootstrap means."""
    seeds: int = 1
    """Training seeds of the method in the difference."""
    reference_seeds: int = 1
    """Training seeds of the reference in the difference."""
    seed_pairs: tuple[SeedPairDiff, ...] = ()
    """With several seeds on either side: every (method seed, reference seed) pair of runs; else empty."""
    p: float = math.nan
    """Two-sided bootstrap p-value of "no difference", from the same resamples as the interval
    (:func:`nue.evaluate.stats.bootstrap_p`); what :func:`holm_verdicts` corrects across the comparisons."""

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
    """Paired differences to ``reference`` for every other method, per metric (see the module doc).

    A method or reference with several training seeds is compared over the episodes every one of the seeds' runs
    ran, with the two-level (seeds, then episodes) bootstrap, and every pair of seeds' runs gets its own episode
    bootstrap (``seed_pairs``, the same ``seed``); one run each keeps the episode bootstrap of the differences.
    Empty when the reference has no records; a method sharing no episode gets ``n_pairs = 0``, NaN.
    """
    groups = by_method_and_seed(records)
    ref = canonical_method(reference)
    if ref not in groups:
        return []
    names = seed_runs(records)
    ref_vals = [_per_key(recs, metrics) for recs in groups[ref].values()]
    out = []
    for key, seeds in groups.items():
        if key == ref:
            continue
        vals = [_per_key(recs, metrics) for recs in seeds.values()]
        common = sorted(set.intersection(*(set(v) for v in (*vals, *ref_vals))))
        pairs: list[list[SeedPairDiff]] = [[] for _ in metrics]
        if not common:
            mean = lo = hi = pvals = np.full(len(metrics), math.nan)
        elif len(vals) == len(ref_vals) == 1:
            d = np.array([vals[0][c] - ref_vals[0][c] for c in common])
            mean, lo, hi, pvals = paired_bootstrap_p(d, n_boot, seed)
        else:
            a = np.array([[v[c] for c in common] for v in vals])  # (seeds, episodes, metrics)
            b = np.array([[v[c] for c in common] for v in ref_vals])
            mean, lo, hi, pvals = seed_episode_bootstrap_p(a, b, n_boot, seed)
            runs = [(i, j) for i in range(len(vals)) for j in range(len(ref_vals))]
            # one call for every pair: its columns share the resampled episodes, as separate calls with ``seed`` would
            pm, plo, phi = paired_bootstrap(np.concatenate([a[i] - b[j] for i, j in runs], axis=1), n_boot, seed)
            for p, (i, j) in enumerate(runs):
                for m in range(len(metrics)):
                    c = p * len(metrics) + m
                    pairs[m].append(SeedPairDiff(names[key][i], names[ref][j], float(pm[c]), float(plo[c]), float(phi[c])))
        out += [PairedDiff(key, ref, m, len(common), float(mean[j]), float(lo[j]), float(hi[j]), len(vals),
                           len(ref_vals), tuple(pairs[j]), float(pvals[j])) for j, m in enumerate(metrics)]
    return out


def in_holm_family(diff: PairedDiff) -> bool:
    """Whether a comparison counts in :func:`holm_verdicts`' family: it has episodes and its method is not an earlier
    recipe's row (``nue_v5``, :func:`nue.evaluate.table.is_earlier_recipe`; those are listed for history)."""
    return diff.n_pairs > 0 and not is_earlier_recipe(diff.method)


def holm_verdicts(diffs: Sequence[PairedDiff], alpha: float = 0.05) -> dict[tuple[str, str], bool]:
    """Per (method, metric) of the family (:func:`in_holm_family`): whether the difference stays resolved when the
    family's comparisons with the reference on that metric are corrected together (Holm-Bonferroni at family-wise
    ``alpha``, :func:`nue.evaluate.stats.holm`, on the bootstrap p-values), so k rows against NUE at 5% face
    thresholds from ``alpha / k`` to ``alpha``. Comparisons outside the family are absent."""
    out: dict[tuple[str, str], bool] = {}
    for metric in dict.fromkeys(d.metric for d in diffs):
        family = [d for d in diffs if d.metric == metric and in_holm_family(d)]
        for d, rejected in zip(family, holm([d.p for d in family], alpha)):
            out[(d.method, metric)] = rejected and d.resolved
    return out


def seed_dependence_markdown(diffs: Sequence[PairedDiff]) -> str:
    """A bullet per comparison whose verdict depends on the training seed: the (method seed, reference seed) pairs
    of runs do not all agree, or the pooled verdict differs from theirs; '' when none does (or one run each).

    Example: ``- f_u=on AT=off CBAM=off vs NUE (full), SR: pooled not resolved (CI contains 0); of the 9 pairs of
    seeds' runs 2 resolved with NUE (full) ahead, 7 not resolved``."""
    lines = []
    for d in diffs:
        if not d.seed_pairs:
            continue
        better = d.metric != "dts"
        ways = [_direction(p.lo, p.hi) for p in d.seed_pairs]
        pooled = _direction(d.lo, d.hi) if d.n_pairs else 0
        if len(set(ways)) == 1 and ways[0] == pooled:
            continue
        ahead = {1: method_label(d.method) if better else method_label(d.reference),
                 -1: method_label(d.reference) if better else method_label(d.method)}
        counts = [f"{ways.count(w)} resolved with {ahead[w]} ahead" for w in (1, -1) if ways.count(w)]
        counts += [f"{ways.count(0)} not resolved"] if ways.count(0) else []
        lines.append(f"- {method_label(d.method)} vs {method_label(d.reference)}, {d.metric.upper()}: pooled "
                     f"{d.verdict(higher_is_better=better)}; of the {len(ways)} pairs of seeds' runs {', '.join(counts)}")
    return "\n".join(lines) + "\n" if lines else ""
