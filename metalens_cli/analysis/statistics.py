"""Bootstrap confidence intervals of a metric's mean over independent evaluation units.

A sample is one value per unit (e.g. one image × noise seed), in the metric's own units. The
interval is the percentile bootstrap of the sample mean (``scipy.stats.bootstrap`` with
``method="percentile"``; BCa's jackknife acceleration is unstable for the few units an
evaluation has), resampled with ``numpy.random.default_rng(seed)`` so that a call is
reproducible. A single unit or all-equal values have nothing to resample: the interval is
[mean, mean].
"""

from __future__ import annotations

import numpy as np
import scipy.stats

from metalens_cli.errors import InputError


def _sample(values, metric: str) -> np.ndarray:
    """``values`` as a finite, non-empty 1-D float64 array."""
    x = np.asarray(values, dtype=np.float64)
    if x.ndim != 1 or x.size == 0:
        raise InputError(metric, f"values of shape {x.shape}", "a non-empty 1-D sequence, one value per unit")
    if not np.isfinite(x).all():
        raise InputError(metric, f"{np.count_nonzero(~np.isfinite(x))} non-finite of {x.size} values", "finite values")
    return x


def mean_ci(
    values, confidence: float = 0.95, n_resamples: int = 2000, seed: int = 0, *, metric: str = "metric"
) -> dict:
    """{"mean", "ci": [lo, hi], "n"}: the mean of ``values`` (one per unit) and its two-sided
    percentile-bootstrap interval at ``confidence``; ``metric`` names the values in errors."""
    if not 0 < confidence < 1:
        raise InputError(f"{metric} confidence", repr(confidence), "a level strictly between 0 and 1")
    if int(n_resamples) != n_resamples or n_resamples < 1:
        raise InputError(f"{metric} bootstrap resamples", repr(n_resamples), "a positive integer")
    x = _sample(values, metric)
    mean = float(np.mean(x))
    if x.size == 1 or np.all(x == x[0]):
        return {"mean": mean, "ci": [mean, mean], "n": int(x.size)}
    ci = scipy.stats.bootstrap(
        (x,),
        np.mean,
        n_resamples=int(n_resamples),
        confidence_level=confidence,
        method="percentile",
        random_state=np.random.default_rng(seed),
    ).confidence_interval
    return {"mean": mean, "ci": [float(ci.low), float(ci.high)], "n": int(x.size)}


def paired_difference_ci(
    a, b, confidence: float = 0.95, n_resamples: int = 2000, seed: int = 0, *, metric: str = "metric"
) -> dict:
    """:func:`mean_ci` of the per-unit differences a − b (same units, same order in both)."""
    x, y = _sample(a, metric), _sample(b, metric)
    if x.size != y.size:
        raise InputError(metric, f"{x.size} and {y.size} values", "one value per unit in both, in the same order")
    return mean_ci(x - y, confidence, n_resamples, seed, metric=f"{metric} difference")
