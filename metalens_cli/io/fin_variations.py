"""A preset's nanofin as fabricated: sizes biased and spread, and what that does to its light.

For a fin along x with zeroth-order Jones coefficients t_xx, t_yy (power-normalised, by RCWA,
``optics.nanofin``), the converted amplitude is a = (t_xx − t_yy)/2 and the co-polarised power
|t_xx + t_yy|²/4. Fabricated fins have width w + b_w + ε_w and length l + b_l + ε_l, ε ~ N(0, σ²)
independently per fin; over the fins (Gauss-Hermite quadrature in ε, ``NODES`` nodes per spread
axis) the lens's converted light splits into

- coherent |E a|² (focused like the design: its ratio to the design fin's |a₀|² is κ(λ)),
- scattered E|a|² − |E a|² (phases that vary from fin to fin: a flat veil, ``optics.fabrication``),
- unconverted E[co-polarised power].

Each (fin, wavelengths) response is computed once and kept in the cache (``io.cache``, kind
``nanofin-variations``), keyed by the fin, the materials' indices, the harmonics and the solver.
Lengths in SI metres.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from metalens_cli.errors import InputError
from metalens_cli.io import cache

CACHE_KIND = "nanofin-variations"
NODES = 5  # Gauss-Hermite nodes per spread axis: exact for polynomials of degree 9 in ε


@dataclass(frozen=True)
class FinLight:
    """Per wavelength (W,): the fabricated fins' ``coherent``, ``scattered`` and ``unconverted``
    power fractions, and the design fin's ``design_conversion`` |a₀|² and ``design_unconverted``
    (all by the same RCWA); ``solves`` fin responses computed (0: all cached) in ``seconds``."""

    wavelengths_m: np.ndarray
    coherent: np.ndarray
    scattered: np.ndarray
    unconverted: np.ndarray
    design_conversion: np.ndarray
    design_unconverted: np.ndarray
    solves: int
    seconds: float

    @property
    def kappa(self) -> np.ndarray:
        """Coherent light over the design fin's converted light, per wavelength."""
        return self.coherent / self.design_conversion


def _response(nanofin, width_m: float, length_m: float, wavelengths_m: np.ndarray, counter: list) -> dict:
    """Converted amplitude a (complex) and co-polarised power of one fin size, cached."""
    from metalens_cli.io.materials import parse_material
    from metalens_cli.optics import nanofin as rcwa

    for value, option in ((width_m, "--width-bias"), (length_m, "--length-bias")):
        if not 0 < value <= nanofin.pitch_m:
            raise InputError(
                option,
                f"makes a fin {value * 1e9:.4g} nm across in a {nanofin.pitch_m * 1e9:.4g} nm cell",
                "errors that keep every fin (quadrature nodes at ±2.9σ included) inside its cell",
            )
    fin = rcwa.Fin(nanofin.pitch_m, nanofin.height_m, width_m, length_m)
    material = parse_material(nanofin.material, "nanofin.material")
    substrate = parse_material(nanofin.substrate, "nanofin.substrate")
    n_fin = material.index(wavelengths_m, "nanofin.material")
    n_sub = substrate.index(wavelengths_m, "nanofin.substrate")
    inputs = {
        "fin_m": [fin.period_m, fin.height_m, fin.width_m, fin.length_m],
        "wavelengths_m": wavelengths_m,
        "fin_index": n_fin,
        "substrate_index": n_sub,
        "harmonics": nanofin.harmonics,
        "solver": rcwa.SOLVER,
    }

    def compute() -> dict[str, np.ndarray]:
        counter[0] += 1
        r = rcwa.fin_response(fin, n_fin, n_sub, wavelengths_m, nanofin.harmonics)
        return {"t_xx": r.t_xx, "t_yy": r.t_yy, "co_polarized": r.co_polarized}

    def problem(arrays):
        shape = (wavelengths_m.size,)
        bad = [
            k for k in ("t_xx", "t_yy", "co_polarized") if arrays[k].shape != shape or not np.isfinite(arrays[k]).all()
        ]
        return f"{', '.join(bad)} not finite or of another shape" if bad else None

    arrays = cache.cached(CACHE_KIND, cache.input_key(inputs), compute, problem).arrays
    return {"a": (arrays["t_xx"] - arrays["t_yy"]) / 2, "co": np.asarray(arrays["co_polarized"], dtype=float)}


def fabricated_fin_light(nanofin, wavelengths_m, errors) -> FinLight:
    """The coherent, scattered and unconverted light of ``nanofin`` (a preset's ``[nanofin]``)
    fabricated with the width and length bias and spread of ``errors``
    (``optics.fabrication.FabricationErrors``) at ``wavelengths_m`` (module docstring)."""
    start = time.perf_counter()
    w = np.asarray(wavelengths_m, dtype=float)
    counter = [0]
    design = _response(nanofin, nanofin.width_m, nanofin.length_m, w, counter)
    x, weights = np.polynomial.hermite.hermgauss(NODES)
    offsets = np.sqrt(2.0) * x  # ε = √2·σ·x for the weight exp(−x²)/√π
    weights = weights / np.sqrt(np.pi)
    widths = [(nanofin.width_m + errors.width_bias_m + errors.width_sigma_m * o, q) for o, q in zip(offsets, weights)]
    lengths = [
        (nanofin.length_m + errors.length_bias_m + errors.length_sigma_m * o, q) for o, q in zip(offsets, weights)
    ]
    widths = widths if errors.width_sigma_m else [(nanofin.width_m + errors.width_bias_m, 1.0)]
    lengths = lengths if errors.length_sigma_m else [(nanofin.length_m + errors.length_bias_m, 1.0)]
    mean_a = np.zeros(w.size, complex)
    mean_power = np.zeros(w.size)
    mean_co = np.zeros(w.size)
    for width, qw in widths:
        for length, ql in lengths:
            r = (
                design
                if (width, length) == (nanofin.width_m, nanofin.length_m)
                else _response(nanofin, width, length, w, counter)
            )
            mean_a += qw * ql * r["a"]
            mean_power += qw * ql * np.abs(r["a"]) ** 2
            mean_co += qw * ql * r["co"]
    coherent = np.abs(mean_a) ** 2
    return FinLight(
        w,
        coherent,
        np.maximum(mean_power - coherent, 0.0),
        mean_co,
        np.abs(design["a"]) ** 2,
        design["co"],
        counter[0],
        time.perf_counter() - start,
    )
