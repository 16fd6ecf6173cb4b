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


def crossover(levels, differences, confidence: float = 0.95, n_resamples: int = 2000, seed: int = 0) -> dict:
    """Where a paired difference (design − versus, one row per level, one column per unit, the
    same units in every row) stops being positive as the light falls.

    ``levels``: finite light levels (electrons), increasing. Per level: the mean difference and
    its percentile-bootstrap interval (:func:`mean_ci`). The crossover is the level where the
    mean difference, linear in log(level) between adjacent levels, last rises through 0 (above
    it the mean is positive at every level); its interval comes from resampling the units (the
    same resample at every level). A crossover below the lowest level or above the highest is
    censored there: ``crossover`` None and ``below``/``above`` True. Returns {"means", "cis",
    "wins" (per level: the whole interval above 0), "crossover", "crossover_ci", "below", "above"}.
    """
    x = np.log(np.asarray(levels, dtype=np.float64))
    d = np.asarray(differences, dtype=np.float64)
    if x.ndim != 1 or d.shape[:1] != x.shape or d.ndim != 2 or not np.all(np.diff(x) > 0):
        raise InputError(
            "light levels", f"{len(levels)} levels for differences {d.shape}", "increasing levels, one row each"
        )
    stats = [mean_ci(row, confidence, n_resamples, seed, metric="difference") for row in d]

    def where(means: np.ndarray) -> float:
        """log level of the crossover of one mean curve, ±inf when censored below/above."""
        if means[-1] <= 0:
            return np.inf
        negative = np.nonzero(means <= 0)[0]
        if not negative.size:
            return -np.inf
        i = negative[-1]
        return x[i] + (x[i + 1] - x[i]) * (-means[i]) / (means[i + 1] - means[i])

    centre = where(d.mean(axis=1))
    rng = np.random.default_rng(seed)
    draws = np.array(
        [where(d[:, rng.integers(0, d.shape[1], d.shape[1])].mean(axis=1)) for _ in range(int(n_resamples))]
    )
    tail = (1 - confidence) / 2
    lo, hi = np.quantile(np.clip(draws, x[0], x[-1]), [tail, 1 - tail])
    return {
        "levels": [float(v) for v in levels],
        "means": [s["mean"] for s in stats],
        "cis": [s["ci"] for s in stats],
        "wins": [s["ci"][0] > 0 for s in stats],
        "crossover": None if not np.isfinite(centre) else float(np.exp(centre)),
        "crossover_ci": [float(np.exp(lo)), float(np.exp(hi))],
        "below": bool(centre == -np.inf),
        "above": bool(centre == np.inf),
    }
