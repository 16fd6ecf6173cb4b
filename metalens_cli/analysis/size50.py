"""size50: the target size a detector finds half the time, the task counterpart of MTF50.

P(found | size s) = 1 / (1 + exp(−(a + b·ln s))), fitted by maximum likelihood (Newton's method
with a weak ridge ``RIDGE`` on b, which keeps a perfectly separated sample finite: its size50
then falls between the largest size never found and the smallest always found). size50 =
exp(−a / b). A sample with every target found is reported as ``below`` its smallest size, one
with none found as ``above`` its largest; one where larger targets are not found more often
(b ≤ 0) has no size50 (``flat``, None).

The interval resamples the units (clusters of targets that share an image and seed) with
``numpy.random.default_rng(seed)``; each resample's size50 is clamped to the sizes drawn, and the
percentile interval is taken over all resamples.
"""

from __future__ import annotations

import numpy as np

from metalens_cli.errors import InputError

RIDGE = 1e-3  # on b (per target), in units of ln(size)⁻²
NEWTON_STEPS = 50


def logistic_fit(log_size: np.ndarray, found: np.ndarray) -> tuple[float, float]:
    """(a, b) of P(found) = σ(a + b·ln s) by Newton's method on the ridge-penalised log likelihood."""
    x = np.stack([np.ones_like(log_size), log_size], axis=1)
    y = found.astype(float)
    n = len(y)
    beta = np.zeros(2)
    penalty = np.diag([0.0, RIDGE * n])
    for _ in range(NEWTON_STEPS):
        p = 1.0 / (1.0 + np.exp(-(x @ beta)))
        gradient = x.T @ (y - p) - penalty @ beta
        hessian = (x * (p * (1 - p))[:, None]).T @ x + penalty + 1e-12 * np.eye(2)
        step = np.linalg.solve(hessian, gradient)
        beta += step
        if np.abs(step).max() < 1e-10:
            break
    return float(beta[0]), float(beta[1])


def _size50(log_size: np.ndarray, found: np.ndarray) -> tuple[float | None, str | None]:
    """(size50 clamped to the sizes drawn, "below"/"above"/None), or (None, "flat")."""
    lo, hi = float(np.exp(log_size.min())), float(np.exp(log_size.max()))
    if found.all():
        return lo, "below"
    if not found.any():
        return hi, "above"
    a, b = logistic_fit(log_size, found)
    if b <= 0:
        return None, "flat"
    s = float(np.exp(-a / b))
    return (lo, "below") if s < lo else (hi, "above") if s > hi else (s, None)


def size50(sizes, found, units, confidence: float = 0.95, n_resamples: int = 1000, seed: int = 0) -> dict:
    """{"size50", "ci": [lo, hi], "bound": None | "below" | "above" | "flat", "n"} of targets of
    ``sizes`` (> 0) that were ``found`` (bool), grouped in ``units`` (one label per target); a flat
    sample's size50 and CI are None, and flat resamples are left out of the interval."""
    s = np.asarray(sizes, dtype=float)
    f = np.asarray(found, dtype=bool)
    u = np.asarray(units)
    if s.ndim != 1 or s.size == 0 or f.shape != s.shape or u.shape != s.shape:
        raise InputError("sizes", f"shapes {s.shape}, {f.shape}, {u.shape}", "three equal, non-empty 1-D sequences")
    if not (np.isfinite(s).all() and (s > 0).all()):
        raise InputError("sizes", "a size ≤ 0 or not finite", "sizes > 0")
    log_size = np.log(s)
    value, bound = _size50(log_size, f)
    labels, members = np.unique(u, return_inverse=True)
    groups = [np.flatnonzero(members == k) for k in range(len(labels))]
    rng = np.random.default_rng(seed)
    draws = []
    for _ in range(n_resamples if len(groups) > 1 else 0):
        take = np.concatenate([groups[k] for k in rng.integers(0, len(groups), len(groups))])
        draws.append(_size50(log_size[take], f[take])[0])
    draws = [d for d in draws if d is not None]
    tail = 100 * (1 - confidence) / 2
    if value is None:
        ci = None
    else:
        ci = [float(v) for v in np.percentile(draws, [tail, 100 - tail])] if draws else [value, value]
    return {"size50": value, "ci": ci, "bound": bound, "n": int(s.size)}


def describe(row: dict) -> str:
    """A row's ``size50`` with its ``size50_ci``, or the bound (``size50_bound``) it lies beyond."""
    value, bound = row["size50"], row["size50_bound"]
    if bound == "below":
        return f"≤ {value:.3g}"
    if bound == "above":
        return f"> {value:.3g}"
    if bound == "flat":
        return "— (larger not found more often)"
    lo, hi = row["size50_ci"]
    return f"{value:.3g} [{lo:.3g}, {hi:.3g}]"
