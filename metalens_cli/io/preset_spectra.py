"""A preset's spectra: the nanofin's conversion efficiency η(λ) and the channels' S^c(λ).

η comes from the preset's ``[nanofin]``: a table (linear between its wavelengths, flat beyond),
a CSV (likewise), or ``efficiency = "rcwa"``: RCWA of the preset's fin (material on substrate,
``harmonics`` per axis; :func:`metalens_cli.optics.nanofin.fin_response`) over the sensor's
wavelength range, sampled adaptively (:func:`adaptive_samples`), joined by PCHIP (flat beyond
the range) and cached on disk under a hash of the fin, the indices over the range, the
harmonics, the solver and the sampling rules (:mod:`metalens_cli.io.cache`): the first command
computes it, every later one reads it (an entry that is not finite η in 0..1 at increasing
wavelengths across the range is set aside and recomputed). The interpolation is within 1e-3 of η computed directly
between the samples, except within 1 nm of the features narrower than the finest step that the
report lists as ``unresolved_m`` (tests/io/test_preset_spectra.py). Resolving those (down to
0.002 nm) for the paper's fin changes ∫S^c by < 1e-3 and the shape of S^c by a total-variation
distance of 2.5e-3 in R, 1e-4 or less in G and B (benchmarks/bench_eta_features.py).
Wavelengths are metres.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from metalens_cli.constants import PAPER_BANDS_M
from metalens_cli.io import cache
from metalens_cli.io.spectra_files import camera_from_csv, efficiency_from_csv, filter_from_csv
from metalens_cli.optics.spectra import (
    SpectralSensitivity,
    bandpass_transmission,
    camera_response,
    efficiency_from_table,
    spectral_sensitivity,
    wavelength_grid,
)

RCWA_STEP_M = 10e-9  # first sampling of η(λ); refined where η is not predictable from its samples
RCWA_TOLERANCE = 1e-3  # refine an interval whose midpoint η differs from the interpolation by more
RCWA_MIN_STEP_M = 0.5e-9  # ... down to this step (a Rayleigh anomaly is a kink no step resolves)
CACHE_KIND = "nanofin"


@dataclass(frozen=True)
class FinEfficiency:
    """η(λ) of a preset's fin: ``values`` at ``wavelengths_m`` as computed or tabulated, and
    ``report``, the JSON that says which η a result used (``source``: table, csv or rcwa; for
    rcwa the fin, materials, harmonics, solver, seconds and cache entry)."""

    wavelengths_m: np.ndarray
    values: np.ndarray
    report: dict
    pchip: bool = False

    def at(self, wavelengths_m) -> np.ndarray:
        """η at ``wavelengths_m``, in 0..1."""
        w = np.asarray(wavelengths_m, dtype=float)
        if not self.pchip:
            return efficiency_from_table(w, self.wavelengths_m, self.values)
        return _interpolate(self.wavelengths_m, self.values, w)


def _interpolate(known_m: np.ndarray, values: np.ndarray, wavelengths_m: np.ndarray) -> np.ndarray:
    """PCHIP (monotone piecewise cubic: no overshoot at kinks) through the samples, flat beyond."""
    from scipy.interpolate import PchipInterpolator

    inside = np.clip(wavelengths_m, known_m[0], known_m[-1])
    return np.clip(PchipInterpolator(known_m, values)(inside), 0.0, 1.0)


def adaptive_samples(
    compute: Callable[[np.ndarray], np.ndarray], wavelength_range_m: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Wavelengths, ``compute(wavelengths)`` there, and the centres of features too narrow to
    resolve. Sampled every ``RCWA_STEP_M`` across the range (at least 4 samples), then refined:
    each round computes the midpoint of every interval still in question (all, at first), keeps
    it, and questions the two halves of those whose midpoint differs from the interpolation of
    the others by more than ``RCWA_TOLERANCE``; an interval in question that is already
    ``RCWA_MIN_STEP_M`` wide is reported as unresolved instead. η of a fin oscillates smoothly
    over ~100 nm but has Rayleigh-anomaly kinks (where a diffraction order starts to propagate in
    the substrate: λ = n_sub·p/√(m² + n²)) and guided-mode resonances below 1 nm wide: features
    of the periodic array that the rotating fins of a lens smear out."""
    lo, hi = wavelength_range_m
    w = np.linspace(lo, hi, max(4, int(np.ceil((hi - lo) / RCWA_STEP_M - 1e-9)) + 1))
    v = compute(w)
    open_, unresolved = np.ones(w.size - 1, bool), []
    while True:
        wide = np.diff(w) >= 2 * RCWA_MIN_STEP_M
        unresolved += list((w[:-1] + w[1:])[open_ & ~wide] / 2)
        index = np.nonzero(open_ & wide)[0]
        if not index.size:
            return w, v, np.unique(np.round(np.array(unresolved, dtype=float), 10))
        middle = (w[index] + w[index + 1]) / 2
        computed = compute(middle)
        missed = np.abs(_interpolate(w, v, middle) - computed) > RCWA_TOLERANCE
        w, v = np.concatenate([w, middle]), np.concatenate([v, computed])
        order = np.argsort(w)
        w, v = w[order], v[order]
        questioned = np.isin(w, middle[missed])
        open_ = questioned[:-1] | questioned[1:]


def preset_efficiency(
    nanofin, wavelength_range_m: tuple[float, float], on_progress: Callable[[int, int], None] | None = None
) -> FinEfficiency:
    """η(λ) of a preset's ``[nanofin]`` (a :class:`~metalens_cli.io.presets.NanofinConfig`),
    RCWA over ``wavelength_range_m`` (the sensor's) when it says ``efficiency = "rcwa"``;
    ``on_progress(done, total)`` is called after each batch of wavelengths while RCWA runs (not
    on a cache hit), ``total`` one ahead of ``done``: the refinement decides how many there are."""
    if nanofin.efficiency_csv is not None:
        grid = wavelength_grid()
        return FinEfficiency(
            grid, efficiency_from_csv(nanofin.efficiency_csv, grid), {"source": "csv", "file": nanofin.efficiency_csv}
        )
    if nanofin.efficiency != "rcwa":
        table = np.array(nanofin.efficiency_wavelengths_m), np.array(nanofin.efficiency, dtype=float)
        return FinEfficiency(
            *table, {"source": "table", "wavelengths_m": table[0].tolist(), "values": table[1].tolist()}
        )
    return _rcwa_efficiency(nanofin, wavelength_range_m, on_progress)


def _rcwa_efficiency(nanofin, wavelength_range_m: tuple[float, float], on_progress) -> FinEfficiency:
    from metalens_cli.io.materials import parse_material
    from metalens_cli.optics import nanofin as rcwa

    fin = rcwa.Fin(nanofin.pitch_m, nanofin.height_m, nanofin.width_m, nanofin.length_m)
    fin_material = parse_material(nanofin.material, "nanofin.material")
    substrate = parse_material(nanofin.substrate, "nanofin.substrate")
    probe = np.linspace(*wavelength_range_m, 64)  # the key: the indices over the range, whatever the sampling
    inputs = {
        "fin_m": [fin.period_m, fin.height_m, fin.width_m, fin.length_m],
        "range_m": list(wavelength_range_m),
        "fin_index": fin_material.index(probe, "nanofin.material"),
        "substrate_index": substrate.index(probe, "nanofin.substrate"),
        "harmonics": nanofin.harmonics,
        "solver": rcwa.SOLVER,
        "sampling": [RCWA_STEP_M, RCWA_TOLERANCE, RCWA_MIN_STEP_M],
    }
    done = [0]

    def compute(w: np.ndarray) -> np.ndarray:
        response = rcwa.fin_response(
            fin,
            fin_material.index(w, "nanofin.material"),
            substrate.index(w, "nanofin.substrate"),
            w,
            nanofin.harmonics,
        )
        done[0] += w.size
        if on_progress is not None:
            on_progress(done[0], done[0] + 1)  # the total is unknown until the refinement stops
        return response.conversion

    def sample() -> dict[str, np.ndarray]:
        start = time.perf_counter()
        wavelengths_m, values, unresolved = adaptive_samples(compute, wavelength_range_m)
        return {
            "wavelengths_m": wavelengths_m,
            "conversion": values,
            "unresolved_m": unresolved,
            "seconds": np.array(time.perf_counter() - start),
        }

    entry = cache.cached(
        CACHE_KIND, cache.input_key(inputs), sample, lambda arrays: _efficiency_problem(arrays, wavelength_range_m)
    )
    stored = entry.arrays
    wavelengths_m = stored["wavelengths_m"]
    report = {
        "source": "rcwa",
        "fin": {"period_m": fin.period_m, "height_m": fin.height_m, "width_m": fin.width_m, "length_m": fin.length_m},
        "material": nanofin.material,
        "substrate": nanofin.substrate,
        "harmonics": nanofin.harmonics,
        "solver": rcwa.SOLVER,
        "samples": int(wavelengths_m.size),
        "range_m": [float(wavelengths_m[0]), float(wavelengths_m[-1])],
        "unresolved_m": stored["unresolved_m"].tolist(),
        "seconds": float(stored["seconds"]),
        "cached": entry.hit,
        "cache_entry": None if entry.path is None else str(entry.path),
    }
    return FinEfficiency(wavelengths_m, np.asarray(stored["conversion"], dtype=float), report, pchip=True)


def _efficiency_problem(stored: dict[str, np.ndarray], wavelength_range_m: tuple[float, float]) -> str | None:
    """Why a cached η(λ) is not one :func:`adaptive_samples` gives over ``wavelength_range_m``
    (None: it may be): wavelengths increasing from one end of the range to the other, η finite in
    0..1 at each, unresolved features inside the range, seconds ≥ 0."""
    lo, hi = wavelength_range_m
    span = lo * (1 - 1e-9), hi * (1 + 1e-9)
    reason = (
        cache.check_array(stored, "wavelengths_m", (None,), *span)
        or cache.check_array(stored, "conversion", stored["wavelengths_m"].shape, 0, 1)
        or cache.check_array(stored, "unresolved_m", (None,), *span)
        or cache.check_array(stored, "seconds", (), 0)
    )
    if reason is None and not (
        stored["wavelengths_m"].size >= 4
        and np.all(np.diff(stored["wavelengths_m"]) > 0)
        and np.allclose(stored["wavelengths_m"][[0, -1]], wavelength_range_m, rtol=1e-9, atol=0)
    ):
        return f"wavelengths_m: not at least 4 increasing wavelengths from {lo:g} to {hi:g} m"
    return reason


def efficiency_report(
    preset, bands_m: list[tuple[float, float]] | None = None, efficiency: FinEfficiency | None = None
) -> dict:
    """The JSON that says which η a result of ``preset`` used (``efficiency``, or the preset's),
    with η at the filter's band centres (or at 457, 530, 628 nm without a filter) and, given
    ``bands_m`` ([lo, hi] pairs), η's mean over each band (``band_mean``)."""
    efficiency = efficiency or preset_efficiency(preset.nanofin, preset.sensor.wavelength_range_m)
    centres = (
        preset.filter.centers_m
        if preset.filter is not None and preset.filter.centers_m
        else tuple(c for c, _ in PAPER_BANDS_M)
    )
    report = {**efficiency.report, "at_m": list(centres), "conversion": [float(v) for v in efficiency.at(centres)]}
    if bands_m is not None:
        report["band_mean"] = [float(efficiency.at(np.linspace(lo, hi, 65)).mean()) for lo, hi in bands_m]
    return report


def channel_throughput(preset) -> np.ndarray:
    """(3,) R, G, B: ∫S^c dλ with the preset's filter over ∫S^c dλ without it: the share of each
    channel's signal the filter passes (1 without a filter). Shot noise grows as it falls."""
    if preset is None or preset.filter is None:
        return np.ones(3)
    grid = wavelength_grid(*preset.sensor.wavelength_range_m, 0.5e-9)
    bare = preset_sensitivity(dataclasses.replace(preset, filter=None), grid).values.sum(axis=1)
    return preset_sensitivity(preset, grid).values.sum(axis=1) / bare


def camera_factors(preset, wavelengths_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The three factors of a preset's S^c on ``wavelengths_m`` (L,): the camera response (3, L),
    the filter's transmission (L,; ones without a filter) and the nanofin efficiency η (L,)
    (:func:`preset_efficiency`)."""
    grid = np.asarray(wavelengths_m, dtype=float)
    band_filter = preset.filter
    transmission = np.ones(grid.size)
    if band_filter is not None and band_filter.csv is not None:
        transmission = filter_from_csv(band_filter.csv, grid)
    elif band_filter is not None:
        transmission = bandpass_transmission(
            grid,
            band_filter.centers_m,
            band_filter.widths_m,
            edge_width_m=band_filter.edge_width_m,
            peak=band_filter.peak_transmission,
        )
    efficiency = preset_efficiency(preset.nanofin, preset.sensor.wavelength_range_m).at(grid)
    camera = preset.sensor.camera_response
    crf = camera_from_csv(camera, grid) if camera.lower().endswith(".csv") else camera_response(grid, camera)
    return crf, transmission, efficiency


def preset_sensitivity(preset, wavelengths_m: np.ndarray | None = None) -> SpectralSensitivity:
    """S^c of a preset's camera: its camera response (a colour-science name or a CSV) × its
    filter (bands or CSV; none: 1) × the nanofin efficiency η (:func:`camera_factors`).

    ``wavelengths_m`` defaults to a 1 nm grid over 380-780 nm.
    """
    grid = wavelength_grid() if wavelengths_m is None else np.asarray(wavelengths_m, dtype=float)
    return spectral_sensitivity(grid, *camera_factors(preset, grid))
