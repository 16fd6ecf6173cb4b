"""Choosing the nanofin: η over a grid of fin widths and lengths, per pass band, and the fin to
fabricate (Suppl. Note 7 of the paper).

Per geometry (width w along x, length l along y) and pass band (centre c, FWHM b): η is
averaged over ``BAND_SAMPLES`` wavelengths evenly across [c − b/2, c + b/2]; the score of a
fin is the mean of its band efficiencies. The recommended fin has the best score among those
whose neighbourhood (every grid fin within ± ``tolerance_m`` in both w and l: the fabrication
tolerance) keeps at least ``keep`` of that score; the neighbourhood is cut at the grid's edges.
The map is computed with a cheap truncation; ``metalens nanofin sweep`` then recomputes the
chosen fin with a converged one.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from metalens_cli.errors import InputError
from metalens_cli.optics.nanofin import Fin, fin_response

BAND_SAMPLES = 3


@dataclass
class FinMap:
    """``eta`` (L, W, B): band-mean η per fin length (rows), width (columns) and band; ``score``
    (L, W) its mean over the bands; the grid in metres; ``wavelengths_m`` (B, BAND_SAMPLES)."""

    widths_m: np.ndarray
    lengths_m: np.ndarray
    bands_m: list[tuple[float, float]]
    wavelengths_m: np.ndarray
    eta: np.ndarray
    harmonics: int
    seconds: float

    @property
    def score(self) -> np.ndarray:
        return self.eta.mean(axis=-1)


def band_wavelengths(bands_m: list[tuple[float, float]]) -> np.ndarray:
    """(B, BAND_SAMPLES) wavelengths evenly across each band's FWHM (centre included)."""
    return np.array([np.linspace(c - b / 2, c + b / 2, BAND_SAMPLES) for c, b in bands_m])


def fin_map(period_m: float, height_m: float, widths_m, lengths_m, bands_m, fin_index: Callable, substrate_index: Callable,
            harmonics: int, on_progress: Callable[[int, int], None] | None = None) -> FinMap:
    """η of every (length, width) fin of the grid that fits in its cell (others NaN), averaged per
    band; ``fin_index``/``substrate_index`` map wavelengths (m) to complex indices."""
    widths, lengths = np.asarray(widths_m, float), np.asarray(lengths_m, float)
    waves = band_wavelengths(bands_m)
    flat = waves.ravel()
    n_fin, n_sub = fin_index(flat), substrate_index(flat)
    eta = np.full((lengths.size, widths.size, len(bands_m)), np.nan)
    total, seconds = lengths.size * widths.size, 0.0
    for i, length in enumerate(lengths):
        for j, width in enumerate(widths):
            if width <= period_m and length <= period_m:
                r = fin_response(Fin(period_m, height_m, width, length), n_fin, n_sub, flat, harmonics)
                eta[i, j] = r.conversion.reshape(waves.shape).mean(axis=1)
                seconds += float(r.seconds.sum())
            if on_progress is not None:
                on_progress(i * widths.size + j + 1, total)
    if np.isnan(eta).all():
        raise InputError("width", "no fin of the grid fits in its cell", "widths and lengths up to the period")
    return FinMap(widths, lengths, list(bands_m), waves, eta, harmonics, seconds)


def recommend(m: FinMap, tolerance_m: float = 10e-9, keep: float = 0.95) -> dict:
    """The recommended fin (see the module docstring): ``width_m``, ``length_m``, ``score``,
    ``worst_neighbour`` (the lowest score within the tolerance), ``eta_per_band``, and whether a
    fin met the ``keep`` rule (``robust``; when none does, the best score is returned)."""
    score = np.where(np.isnan(m.score), -np.inf, m.score)
    best = None
    for i, j in sorted(np.ndindex(score.shape), key=lambda ij: -score[ij]):
        if not np.isfinite(score[i, j]):
            break
        rows = np.abs(m.lengths_m - m.lengths_m[i]) <= tolerance_m * (1 + 1e-9)
        cols = np.abs(m.widths_m - m.widths_m[j]) <= tolerance_m * (1 + 1e-9)
        worst = float(score[np.ix_(rows, cols)].min())
        if best is None:
            best = (i, j, worst, False)
        if worst >= keep * score[i, j]:
            best = (i, j, worst, True)
            break
    i, j, worst, robust = best
    return {"width_m": float(m.widths_m[j]), "length_m": float(m.lengths_m[i]), "score": float(score[i, j]),
            "worst_neighbour": worst, "eta_per_band": m.eta[i, j].tolist(), "robust": robust,
            "tolerance_m": tolerance_m, "keep": keep}
