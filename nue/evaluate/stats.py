"""Small statistics for evaluation reports: Wilson score interval of a success rate, paired bootstrap of differences."""

from __future__ import annotations

import math

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


def paired_bootstrap(d: np.ndarray, n_boot: int = 10_000, seed: int = 0, level: float = 0.95,
                     chunk: int = 1000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Means and percentile interval of paired differences ``d`` (n,) or (n, k), resampling rows.

    Each resample draws n rows with replacement and takes the column means; the interval is the
    ``(1 - level) / 2`` and ``(1 + level) / 2`` quantiles of those means (percentile bootstrap).
    Returns ``(mean (k,), lo (k,), hi (k,))``; all k columns share the same resampled rows
    (``numpy.random.default_rng(seed)``, drawn ``chunk`` resamples at a time).
    """
    d = np.asarray(d, dtype=np.float64)
    d = d[:, None] if d.ndim == 1 else d
    n = d.shape[0]
    rng = np.random.default_rng(seed)
    means = np.empty((n_boot, d.shape[1]))
    for s in range(0, n_boot, chunk):
        b = min(chunk, n_boot - s)
        means[s:s + b] = d[rng.integers(0, n, size=(b, n))].mean(axis=1)
    lo, hi = np.quantile(means, [(1 - level) / 2, (1 + level) / 2], axis=0)
    return d.mean(axis=0), lo, hi
