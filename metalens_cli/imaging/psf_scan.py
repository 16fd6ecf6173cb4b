"""PSF cubes over wavelength and depth (the core of ``metalens psf-scan``), with cost and accuracy.

A scan computes psf[i, j] for depths[i] × wavelengths[j] through :func:`compute_psf`, the
channel PSFs rgb[i, c] = Σ_j w[c, j]·psf[i, j] when a preset defines the spectra (S^c
quadrature on the scan wavelengths: filter × camera response, w summing to 1 per channel),
summaries of every PSF and of every channel PSF (its centre 5 × 5 energy is the spectrally
weighted mean of the wavelengths' own), and, on request, an accuracy report:
the sharpest PSF recomputed with doubled sampling and, for radial designs, with the direct
Rayleigh-Sommerfeld reference.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from metalens_cli.analysis.psf_metrics import summarize
from metalens_cli.io.designs import Design
from metalens_cli.optics.psf import compute_psf

COVERAGE_WARNING = 0.99
RS_WINDOW = 9  # central pixels compared with the direct Rayleigh-Sommerfeld reference


@dataclass
class ScanResult:
    """PSFs (D, W, N, N) and channel PSFs (D, 3, N, N) or None, float32 numpy, with reports."""

    psf: np.ndarray
    rgb: np.ndarray | None
    wavelengths_m: list[float]
    depths_m: list[float]
    pixel_pitch_m: float
    propagator: str
    grid: dict
    timing_s: dict
    metrics: list[dict]
    channel_metrics: list[dict] = field(default_factory=list)
    spectra: dict | None = None
    accuracy: dict | None = None
    warnings: list[str] = field(default_factory=list)


def relative_l2(a: np.ndarray, reference: np.ndarray) -> float:
    """‖a − reference‖₂ / ‖reference‖₂."""
    return float(np.linalg.norm(a - reference) / np.linalg.norm(reference))


def _channel_weights(design: Design, wavelengths_m, warnings: list[str]):
    from metalens_cli.io.preset_spectra import preset_sensitivity
    from metalens_cli.optics.spectra import CHANNELS, quadrature_weights

    weights = quadrature_weights(preset_sensitivity(design.preset), np.asarray(wavelengths_m))
    coverage = [float(c) for c in weights.coverage]
    for name, value in zip(CHANNELS, coverage):
        if value < COVERAGE_WARNING:
            warnings.append(
                f"channel {name}: the scan covers {100 * value:.1f} % of its spectral sensitivity; widen --wavelengths"
            )
    spectra = {
        "channels": list(CHANNELS),
        "camera_response": design.preset.sensor.camera_response,
        "filter": design.preset.filter is not None,
        "coverage": coverage,
    }
    return weights.weights, spectra


def run_scan(
    design: Design,
    wavelengths_m: list[float],
    depths_m: list[float],
    pixels: int,
    pixel_pitch_m: float,
    *,
    propagator: str = "auto",
    dtype: torch.dtype = torch.float32,
    device: str = "cpu",
    force: bool = False,
    check_accuracy: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> ScanResult:
    """Compute the cube. The radial path runs as one batch; 2-D paths go one wavelength at a
    time so that ``progress(done, total)`` can report. The channel weights (which refuse a
    wavelength list that cannot integrate S^c) are settled before any PSF is computed."""
    start = time.perf_counter()
    timing: dict[str, float] = {}
    warnings: list[str] = []
    weights, spectra = _channel_weights(design, wavelengths_m, warnings) if design.preset is not None else (None, None)
    batched = propagator == "radial" or (propagator == "auto" and design.lens.radial)
    groups = [wavelengths_m] if batched else [[w] for w in wavelengths_m]
    parts, result = [], None
    for done, group in enumerate(groups, start=1):
        result = compute_psf(
            design.lens,
            group,
            depths_m,
            pixels,
            pixel_pitch_m,
            distance_m=design.focal_length_m,
            propagator=propagator,
            dtype=dtype,
            device=device,
            force=force,
        )
        parts.append(result.psf.detach().to("cpu", torch.float32))
        for stage, seconds in result.timing_s.items():
            timing[stage] = timing.get(stage, 0.0) + seconds
        if progress is not None:
            progress(done, len(groups))
    psf = torch.cat(parts, dim=1).numpy()
    rgb = None if weights is None else np.einsum("cw,dwij->dcij", weights, psf).astype(np.float32)
    metrics = [
        {"depth_m": z, "wavelength_m": w, **summarize(psf[i, j], pixel_pitch_m)}
        for i, z in enumerate(depths_m)
        for j, w in enumerate(wavelengths_m)
    ]
    channel_metrics = (
        []
        if rgb is None
        else [
            {"depth_m": z, "channel": name, **summarize(rgb[i, c], pixel_pitch_m)}
            for i, z in enumerate(depths_m)
            for c, name in enumerate(spectra["channels"])
        ]
    )
    timing["total"] = time.perf_counter() - start
    scan = ScanResult(
        psf,
        rgb,
        list(wavelengths_m),
        list(depths_m),
        pixel_pitch_m,
        result.propagator,
        result.grid,
        timing,
        metrics,
        channel_metrics,
        spectra,
        warnings=warnings,
    )
    if check_accuracy:
        scan.accuracy = accuracy_report(design, scan, dtype, device, force)
    return scan


def accuracy_report(design: Design, scan: ScanResult, dtype, device, force: bool, rs_window: int = RS_WINDOW) -> dict:
    """Recompute the sharpest PSF of the scan (highest peak: the hard case) with doubled
    sampling over the whole window, and, for a radial design, with the direct
    Rayleigh-Sommerfeld reference on the central ``rs_window``² pixels (rs costs about a
    minute per 33² pixels on the paper's lens); relative L2 differences."""
    i, j = np.unravel_index(np.argmax(scan.psf.max(axis=(-2, -1))), scan.psf.shape[:2])
    z, w = scan.depths_m[i], scan.wavelengths_m[j]
    n = scan.psf.shape[-1]
    reference = scan.psf[i, j]
    report = {"depth_m": z, "wavelength_m": w}
    start = time.perf_counter()
    doubled = compute_psf(
        design.lens,
        [w],
        [z],
        n,
        scan.pixel_pitch_m,
        distance_m=design.focal_length_m,
        propagator=scan.propagator,
        dtype=dtype,
        device=device,
        force=force,
        oversample=2.0,
    )
    report["doubled_sampling_rel_l2"] = relative_l2(reference, doubled.psf[0, 0].detach().cpu().numpy())
    report["doubled_sampling_seconds"] = time.perf_counter() - start
    if design.lens.radial and scan.propagator != "rs":
        m = min(rs_window, n if n % 2 else n - 1)  # odd: its axis pixel m//2 lines up with n//2
        c, h = n // 2, m // 2
        start = time.perf_counter()
        exact = compute_psf(
            design.lens,
            [w],
            [z],
            m,
            scan.pixel_pitch_m,
            distance_m=design.focal_length_m,
            propagator="rs",
            dtype=torch.float64,
            device=device,
            force=force,
        )
        crop = reference[c - h : c + h + 1, c - h : c + h + 1]
        report["rs_rel_l2"] = relative_l2(crop, exact.psf[0, 0].detach().cpu().numpy())
        report["rs_window_pixels"] = m
        report["rs_seconds"] = time.perf_counter() - start
    return report
