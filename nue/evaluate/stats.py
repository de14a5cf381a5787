"""Small statistics for evaluation reports: Wilson score interval of a success rate, paired bootstrap of differences
(over episodes, or over training seeds and episodes)."""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

Z95 = 1.959963984540054
"""Two-sided 95% standard-normal quantile."""


def wilson_interval(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval for a binomial proportion k / n, as fractions; (nan, nan) for n = 0.

    With p = k / n: ``(p + z²/2n ± z·sqrt(p(1-p)/n + z²/4n²)) / (1 + z²/n)``, z = 1.96 for 95%.
    Unlike the normal (Wald) interval it stays inside [0, 1] and is not empty at k = 0 or k = n.
    Example: k = 8, n = 10 -> (0.490, 0.943).
    """
    if n == 0:
        return math.nan, math.nan
    p, z2 = k / n, z * z
    centre = (p + z2 / (2 * n)) / (1 + z2 / n)
    half = z / (1 + z2 / n) * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n))
    return max(0.0, centre - half), min(1.0, centre + half)


def bootstrap_p(means: np.ndarray) -> np.ndarray:
    """Two-sided percentile-bootstrap p-value of "the difference is 0" per column of resampled ``means``
    (n_boot, k): ``min(1, 2 min(P(mean <= 0), P(mean >= 0)))``, the smallest level at which the matching percentile
    interval would exclude 0. Example: 10 resamples with 1 of them <= 0 and 9 > 0 give p = 0.2."""
    means = np.asarray(means, dtype=np.float64)
    return np.minimum(1.0, 2.0 * np.minimum((means <= 0).mean(axis=0), (means >= 0).mean(axis=0)))


def holm(p: Sequence[float], alpha: float = 0.05) -> list[bool]:
    """Holm-Bonferroni step-down over a family of comparisons: which null hypotheses are rejected at family-wise
    level ``alpha``. Sorted ascending, the i-th smallest p (i from 0) is compared with ``alpha / (m - i)``; rejection
    stops at the first that fails. NaN p-values never reject (and do not count in m).

    Example: p = (0.01, 0.04, 0.03), alpha 0.05 -> 0.01 <= 0.05/3 rejects, 0.03 > 0.05/2 stops: (True, False, False).
    """
    idx = [i for i in np.argsort(np.asarray(p, dtype=np.float64)) if not math.isnan(p[i])]
    out = [False] * len(p)
    for rank, i in enumerate(idx):
        if p[i] > alpha / (len(idx) - rank):
            break
        out[i] = True
    return out


def _paired_means(d: np.ndarray, n_boot: int, seed: int, chunk: int) -> tuple[np.ndarray, np.ndarray]:
    """(estimate (k,), resampled means (n_boot, k)) of :func:`paired_bootstrap`."""
    d = np.asarray(d, dtype=np.float64)
    d = d[:, None] if d.ndim == 1 else d
    n = d.shape[0]
    rng = np.random.default_rng(seed)
    means = np.empty((n_boot, d.shape[1]))
    for s in range(0, n_boot, chunk):
        b = min(chunk, n_boot - s)
        idx = rng.integers(0, n, size=(b, n))
        # how often each row was drawn, so the resamples' means are one matrix product (as in _seed_episode_parts)
        times = np.bincount((idx + n * np.arange(b)[:, None]).ravel(), minlength=b * n).reshape(b, n)
        means[s:s + b] = (times.astype(np.float64) @ d) / n
    return d.mean(axis=0), means


def paired_bootstrap_p(d: np.ndarray, n_boot: int = 10_000, seed: int = 0, level: float = 0.95,
                       chunk: int = 1000) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`paired_bootstrap` and the :func:`bootstrap_p` of the same resamples: ``(mean, lo, hi, p)``."""
    est, means = _paired_means(d, n_boot, seed, chunk)
    lo, hi = np.quantile(means, [(1 - level) / 2, (1 + level) / 2], axis=0)
    return est, lo, hi, bootstrap_p(means)


def paired_bootstrap(d: np.ndarray, n_boot: int = 10_000, seed: int = 0, level: float = 0.95,
                     chunk: int = 1000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Means and percentile interval of paired differences ``d`` (n,) or (n, k), resampling rows.

    Each resample draws n rows with replacement and takes the column means; the interval is the
    ``(1 - level) / 2`` and ``(1 + level) / 2`` quantiles of those means (percentile bootstrap).
    Returns ``(mean (k,), lo (k,), hi (k,))``; all k columns share the same resampled rows
    (``numpy.random.default_rng(seed)``, drawn ``chunk`` resamples at a time).
    """
    mean, lo, hi, _ = paired_bootstrap_p(d, n_boot, seed, level, chunk)
    return mean, lo, hi


def seed_episode_bootstrap_p(a: np.ndarray, b: np.ndarray, n_boot: int = 10_000, seed: int = 0, level: float = 0.95,
                             chunk: int = 1000) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`seed_episode_bootstrap` and the :func:`bootstrap_p` of the same resamples: ``(mean, lo, hi, p)``."""
    est, means = _seed_episode_means(a, b, n_boot, seed, chunk)
    lo, hi = np.quantile(means, [(1 - level) / 2, (1 + level) / 2], axis=0)
    return est, lo, hi, bootstrap_p(means)


def seed_episode_bootstrap(a: np.ndarray, b: np.ndarray, n_boot: int = 10_000, seed: int = 0, level: float = 0.95,
                           chunk: int = 1000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Paired difference of two methods trained with several seeds: mean and two-level percentile interval.

    ``a``: (S_a, n, k) outcomes of method A's S_a training seeds on n episodes (k metrics); ``b``: (S_b, n, k) of
    the reference on the same episodes in the same order. The estimate is ``mean_i (ā_i - b̄_i)``, ā_i the mean of
    episode i over A's seeds. Each resample draws S_a of A's seeds and S_b of the reference's with replacement, then
    n episodes with replacement (the same episodes for both: paired), and takes the mean over the drawn episodes of
    (drawn A seeds' mean - drawn reference seeds' mean); the interval is the ``(1 - level) / 2`` and
    ``(1 + level) / 2`` quantiles of those means. It so covers both the sampling of episodes and of training seeds
    (with few seeds it understates the seed part: the plug-in variance of a mean of S draws is (S - 1) / S of the
    unbiased one). With S_a = S_b = 1 it is :func:`paired_bootstrap` of ``a[0] - b[0]``.

    Example: A's two seeds succeed on every episode / on none, the reference's one seed on none. The drawn A seeds'
    mean is 0, 0.5 or 1 with probabilities 1/4, 1/2, 1/4 whatever episodes are drawn, so the estimate is 0.5 and the
    95% interval [0, 1]; :func:`paired_bootstrap` of the seed-averaged differences (0.5 on every episode) gives
    [0.5, 0.5], blind to the seeds' disagreement.

    Returns ``(mean (k,), lo (k,), hi (k,))``; ``numpy.random.default_rng(seed)``, ``chunk`` resamples at a time.
    """
    mean, lo, hi, _ = seed_episode_bootstrap_p(a, b, n_boot, seed, level, chunk)
    return mean, lo, hi


def seed_episode_ratio(a: np.ndarray, b: np.ndarray, n_boot: int = 10_000, seed: int = 0, level: float = 0.95,
                       chunk: int = 1000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ratio of means ``mean(a) / mean(b)`` of two methods' paired outcomes, each with several training seeds, and
    its two-level percentile interval: the resamples of :func:`seed_episode_bootstrap` (seeds of each side with
    replacement, then the same episodes for both), each giving (drawn A seeds' mean) / (drawn reference seeds' mean)
    over the drawn episodes. Shapes as there: ``a`` (S_a, n, k), ``b`` (S_b, n, k), or (S, n) for one metric.

    Example: A's two seeds see 2 and 4 m² on every start, the reference's one seed 2 m²: the estimate is 1.5 and the
    95% interval [1, 2] (the drawn A seeds' mean is 2, 3 or 4 m²), whatever starts are drawn.

    Returns ``(ratio (k,), lo (k,), hi (k,))``; a reference mean of 0 counts as 1e-12."""
    (est_a, est_b), (ma, mb) = _seed_episode_parts(a, b, n_boot, seed, chunk)
    ratios = ma / np.maximum(mb, 1e-12)
    lo, hi = np.quantile(ratios, [(1 - level) / 2, (1 + level) / 2], axis=0)
    return est_a / np.maximum(est_b, 1e-12), lo, hi


def _seed_episode_means(a: np.ndarray, b: np.ndarray, n_boot: int, seed: int, chunk: int) -> tuple[np.ndarray, np.ndarray]:
    """(estimate (k,), resampled means (n_boot, k)) of :func:`seed_episode_bootstrap`."""
    (est_a, est_b), (ma, mb) = _seed_episode_parts(a, b, n_boot, seed, chunk)
    return est_a - est_b, ma - mb


def _seed_episode_parts(a: np.ndarray, b: np.ndarray, n_boot: int, seed: int,
                        chunk: int) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """((estimate of A (k,), of B (k,)), (resampled means of A (n_boot, k), of B)) of the two-level bootstrap."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    a = a[..., None] if a.ndim == 2 else a
    b = b[..., None] if b.ndim == 2 else b
    if a.shape[1:] != b.shape[1:]:
        raise ValueError(f"episodes x metrics differ: {a.shape[1:]} vs {b.shape[1:]}")
    (sa, n, k), sb = a.shape, b.shape[0]
    rng = np.random.default_rng(seed)
    means_a, means_b = np.empty((n_boot, k)), np.empty((n_boot, k))
    flat_a = a.transpose(1, 0, 2).reshape(n, sa * k)
    flat_b = b.transpose(1, 0, 2).reshape(n, sb * k)
    for s in range(0, n_boot, chunk):
        m = min(chunk, n_boot - s)
        wa = rng.multinomial(sa, np.full(sa, 1 / sa), size=m) / sa  # (m, S_a): each drawn seed's weight
        wb = rng.multinomial(sb, np.full(sb, 1 / sb), size=m) / sb
        idx = rng.integers(0, n, size=(m, n))
        # how often each episode was drawn, so a seed's mean over the drawn episodes is one matrix product
        times = np.bincount((idx + n * np.arange(m)[:, None]).ravel(), minlength=m * n).reshape(m, n).astype(np.float64)
        per_seed_a = (times @ flat_a).reshape(m, sa, k) / n
        per_seed_b = (times @ flat_b).reshape(m, sb, k) / n
        means_a[s:s + m] = np.einsum("ms,msk->mk", wa, per_seed_a)
        means_b[s:s + m] = np.einsum("ms,msk->mk", wb, per_seed_b)
    return (a.mean(axis=(0, 1)), b.mean(axis=(0, 1))), (means_a, means_b)
