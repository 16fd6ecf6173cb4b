"""PSF cubes over wavelength and depth (the core of ``metalens psf-scan``), with cost and accuracy.

A scan computes psf[i, j] for depths[i] × wavelengths[j] through :func:`compute_psf`, the
channel PSFs rgb[i, c] = Σ_j w[c, j]·psf[i, j] when a preset defines the spectra (S^c
quadrature on the scan wavelengths: filter × camera response, w summing to 1 per channel),
summaries of every PSF and of every channel PSF (its centre 5 × 5 energy is the spectrally
weighted mean of the wavelengths' own), and, on request, an accuracy report:
the sharpest PSF recomputed with doubled sampling and, for radial designs, with the direct
Rayleigh-Sommerfeld reference. The scan's cost is estimated and its cube file checked before
any work; the cube is written with the scan's metadata in its header.

With field angles (:func:`run_field_scan`) the cube gains a field axis (docs/formats.md, field
cubes): each field's PSFs from ``optics.field.field_psf``, in a window centred on its chief ray,
summarised by ``analysis.psf_metrics.field_summary`` (centroid, tangential and sagittal FWHM,
encircled energy).
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from metalens_cli import arguments
from metalens_cli.analysis.psf_metrics import summarize
from metalens_cli.errors import InputError
from metalens_cli.io.designs import Design
from metalens_cli.io.exr import MAX_DEPTHS, MAX_WAVELENGTHS
from metalens_cli.io.json_files import jsonable
from metalens_cli.io.psf_cube_files import check_cube_size, write_psf_cube
from metalens_cli.io.resources import Estimate
from metalens_cli.optics.psf import compute_psf, estimate_psf, psf_inputs
from metalens_cli.runtime import Stopwatch

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
    fields: FieldScan | None = None


@dataclass
class FieldScan:
    """The field axis of a scan: PSFs (F, D, W, N, N), channel PSFs (F, D, 3, N, N) or None, field
    angles (rad), azimuth (rad), chief rays (F × (x, y), m), window centres (F × (column, row)
    pixels from the axis pixel) and per field its PSF and channel summaries."""

    psf: np.ndarray
    rgb: np.ndarray | None
    angles_rad: list[float]
    azimuth_rad: float
    chief_ray_m: list[list[float]]
    centre_px: list[list[int]]
    metrics: list[dict]


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


def check_scan_size(
    path: str | os.PathLike[str], wavelengths_m, depths_m, pixels: int, *, field_cube: bool = False
) -> None:
    """Refuse, before any work, a scan whose cube ``path`` cannot hold: more wavelengths or depths
    than a cube file holds, a ``.mat`` variable over 2 GiB or a field cube in any format but
    ``.exr`` (``io.psf_cube_files``)."""
    for option, values, limit in (
        ("--wavelengths", wavelengths_m, MAX_WAVELENGTHS),
        ("--depths", depths_m, MAX_DEPTHS),
    ):
        if len(values) > limit:
            raise InputError(
                option, f"{len(values)} values; a PSF cube holds at most {limit}", f"at most {limit} values"
            )
    check_cube_size(path, "--output", len(depths_m), len(wavelengths_m), pixels, field_cube=field_cube)


def estimate_scan(
    design: Design,
    wavelengths_m: list[float],
    depths_m: list[float],
    pixels: int,
    pixel_pitch_m: float,
    *,
    propagator: str = "auto",
    dtype: torch.dtype = torch.float32,
    force: bool = False,
) -> Estimate:
    """Peak memory and time of :func:`run_scan` (``optics.psf.estimate_psf``, which also applies
    the sampling guard) and the bytes of its float32 cube."""
    cost = estimate_psf(
        design.lens,
        wavelengths_m,
        depths_m,
        pixels,
        pixel_pitch_m,
        distance_m=design.focal_length_m,
        propagator=propagator,
        dtype=dtype,
        force=force,
    )
    count = len(wavelengths_m) * len(depths_m)
    return Estimate(
        f"psf-scan of {count} PSFs of {pixels}² pixels",
        cost.memory_bytes,
        "--pixels",
        cost.seconds,
        disk_bytes=count * pixels**2 * 4,
    )


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
    arguments.instance(design, "design", Design, "a Design (ml.resolve_design)")
    wavelengths_m, depths_m, _ = psf_inputs(
        design.lens, wavelengths_m, depths_m, pixels, pixel_pitch_m, design.focal_length_m, propagator, dtype
    )
    device = arguments.device(device)
    watch = Stopwatch()
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
        watch.add(result.timing_s)
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
    watch.times["total"] = time.perf_counter() - start
    scan = ScanResult(
        psf,
        rgb,
        list(wavelengths_m),
        list(depths_m),
        pixel_pitch_m,
        result.propagator,
        result.grid,
        watch.times,
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


def scan_metadata(design: Design, scan: ScanResult, dtype: str, efficiency: dict) -> dict:
    """What the cube's header and the report say beyond the axes: f and D (m), NA, propagator,
    ``dtype`` (its name), grid, timings (s), accuracy, spectra and the nanofin ``efficiency`` used."""
    half = design.lens.aperture_m / 2
    return {
        "f_m": design.focal_length_m,
        "aperture_m": design.lens.aperture_m,
        "na": half / math.hypot(half, design.focal_length_m),
        "propagator": scan.propagator,
        "dtype": dtype,
        "grid": scan.grid,
        "timing_s": scan.timing_s,
        "accuracy": scan.accuracy,
        "spectra": scan.spectra,
        "efficiency": efficiency,
    }


def write_scan(path: str | os.PathLike[str], design: Design, scan: ScanResult, metadata: dict) -> None:
    """The scan's cube file, in the format of ``path``'s suffix, atomically, ``metadata`` in its header."""
    fields = scan.fields
    write_psf_cube(
        path,
        scan.psf if fields is None else fields.psf,
        scan.wavelengths_m,
        scan.depths_m,
        scan.pixel_pitch_m,
        design.describe(),
        rgb=scan.rgb if fields is None else fields.rgb,
        extra=jsonable(metadata if fields is None else {**metadata, **field_metadata(scan)}),
    )


def scan_report(design: Design, scan: ScanResult, metadata: dict, path: str | os.PathLike[str], plot_path=None) -> dict:
    """The JSON report of a scan written to ``path`` (and plotted to ``plot_path``): axes (m),
    window, ``metadata``, the summaries of every PSF and channel PSF, and the warnings."""
    return {
        "file": str(path),
        "design": design.describe(),
        "wavelengths_m": scan.wavelengths_m,
        "depths_m": scan.depths_m,
        "pixels": scan.psf.shape[-1],
        "pixel_pitch_m": scan.pixel_pitch_m,
        **metadata,
        "psfs": scan.metrics,
        "channel_psfs": scan.channel_metrics,
        **({} if scan.fields is None else {"field_azimuth_rad": scan.fields.azimuth_rad}),
        **({} if scan.fields is None else {"fields": scan.fields.metrics}),
        "warnings": scan.warnings,
        **({"plot": str(plot_path)} if plot_path else {}),
    }


def estimate_field_scan(
    design: Design,
    wavelengths_m: list[float],
    depths_m: list[float],
    pixels: int,
    pixel_pitch_m: float,
    angles_rad: list[float],
    *,
    azimuth_rad: float = 0.0,
    dtype: torch.dtype = torch.float32,
    force: bool = False,
) -> Estimate:
    """Peak memory and time of :func:`run_field_scan`: an on-axis field as :func:`estimate_scan`,
    each other field as ``optics.field.estimate_field_psf`` at ``azimuth_rad``."""
    from metalens_cli.optics.field import estimate_field_psf

    axis = estimate_psf(
        design.lens, wavelengths_m, depths_m, pixels, pixel_pitch_m, distance_m=design.focal_length_m,
        dtype=dtype, force=force,
    )  # fmt: skip
    off = [a for a in angles_rad if a > 0]
    memory, seconds = axis.memory_bytes, axis.seconds if len(off) < len(angles_rad) else 0.0
    for angle in off:
        tilted = estimate_field_psf(
            design.lens, wavelengths_m, depths_m, pixels, pixel_pitch_m, angle, azimuth_rad=azimuth_rad,
            distance_m=design.focal_length_m, dtype=dtype, force=force,
        )  # fmt: skip
        memory, seconds = max(memory, tilted.memory_bytes), seconds + tilted.seconds
    count = len(wavelengths_m) * len(depths_m) * len(angles_rad)
    return Estimate(
        f"psf-scan of {count} PSFs of {pixels}² pixels over {len(angles_rad)} fields",
        memory,
        "--pixels",
        seconds,
        disk_bytes=count * pixels**2 * 4,
    )


def run_field_scan(
    design: Design,
    wavelengths_m: list[float],
    depths_m: list[float],
    pixels: int,
    pixel_pitch_m: float,
    angles_rad: list[float],
    *,
    azimuth_rad: float = 0.0,
    dtype: torch.dtype = torch.float32,
    device: str = "cpu",
    force: bool = False,
    check_accuracy: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> ScanResult:
    """A scan over the field angles ``angles_rad`` (rad) at azimuth ``azimuth_rad``: field 0's
    PSFs are the scan's ``psf``/``rgb`` (what on-axis readers see), all of them in ``fields``.
    ``check_accuracy`` recomputes the sharpest PSF of the outermost field with doubled sampling
    (the direct Rayleigh-Sommerfeld sum over a lens of this size is out of reach off axis)."""
    from metalens_cli.analysis.psf_metrics import field_summary
    from metalens_cli.optics.field import field_psf

    start = time.perf_counter()
    warnings: list[str] = []
    arguments.instance(design, "design", Design, "a Design (ml.resolve_design)")
    wavelengths_m, depths_m, _ = psf_inputs(
        design.lens, wavelengths_m, depths_m, pixels, pixel_pitch_m, design.focal_length_m, dtype=dtype
    )
    angles_rad = arguments.numbers_of(angles_rad, "angles_rad", lo=0.0, form="field angles ≥ 0 (rad)")
    arguments.number(azimuth_rad, "azimuth_rad", form="a finite azimuth (rad)")
    device = arguments.device(device)
    weights, spectra = _channel_weights(design, wavelengths_m, warnings) if design.preset is not None else (None, None)
    watch = Stopwatch()
    psfs, results = [], []
    steps: list[tuple[int, list[float]]] = []  # (field, wavelengths): an on-axis radial field is one batch
    for k, angle in enumerate(angles_rad):
        batched = angle == 0 and design.lens.radial
        steps += [(k, list(wavelengths_m))] if batched else [(k, [w]) for w in wavelengths_m]
    parts: dict[int, list[torch.Tensor]] = {k: [] for k in range(len(angles_rad))}
    for done, (k, group) in enumerate(steps, start=1):
        result = field_psf(
            design.lens, group, depths_m, pixels, pixel_pitch_m, angles_rad[k], azimuth_rad=azimuth_rad,
            distance_m=design.focal_length_m, dtype=dtype, device=device, force=force,
        )  # fmt: skip
        parts[k].append(result.psf.detach().to("cpu", torch.float32))
        if len(parts[k]) == 1:
            results.append(result)
        watch.add({stage: seconds for stage, seconds in result.timing_s.items() if stage != "total"})
        if progress is not None:
            progress(done, len(steps))
    for k in range(len(angles_rad)):
        psfs.append(torch.cat(parts[k], dim=1).numpy())
    psf = np.stack(psfs)
    rgb = None if weights is None else np.einsum("cw,fdwij->fdcij", weights, psf).astype(np.float32)
    chief = [[float(v) for v in r.chief_ray_m] for r in results]
    centre = [[int(v) for v in r.centre_px] for r in results]
    metrics = []
    for k, angle in enumerate(angles_rad):
        offset = (centre[k][0] * pixel_pitch_m - chief[k][0], centre[k][1] * pixel_pitch_m - chief[k][1])
        entry = {
            "field": k,
            "angle_rad": angle,
            "angle_deg": math.degrees(angle),
            "chief_ray_m": chief[k],
            "window_centre_px": centre[k],
            "propagator": results[k].propagator,
            "psfs": [
                {"depth_m": z, "wavelength_m": w, **field_summary(psf[k, i, j], pixel_pitch_m, offset, azimuth_rad)}
                for i, z in enumerate(depths_m)
                for j, w in enumerate(wavelengths_m)
            ],
        }
        if rgb is not None:
            entry["channel_psfs"] = [
                {"depth_m": z, "channel": name, **field_summary(rgb[k, i, c], pixel_pitch_m, offset, azimuth_rad)}
                for i, z in enumerate(depths_m)
                for c, name in enumerate(spectra["channels"])
            ]
        metrics.append(entry)
        kept = psf[k].sum(axis=(-2, -1))
        if kept.min() < COVERAGE_WARNING:
            warnings.append(
                f"field {k} ({math.degrees(angle):.3g}°): the {pixels}-pixel window keeps as little as "
                f"{kept.min():.3f} of the light; widen --pixels"
            )
    watch.times["total"] = time.perf_counter() - start
    axis_metrics = [
        {"depth_m": z, "wavelength_m": w, **summarize(psf[0, i, j], pixel_pitch_m)}
        for i, z in enumerate(depths_m)
        for j, w in enumerate(wavelengths_m)
    ]
    scan = ScanResult(
        psf[0],
        None if rgb is None else rgb[0],
        list(wavelengths_m),
        list(depths_m),
        pixel_pitch_m,
        results[-1].propagator,
        results[-1].grid,
        watch.times,
        axis_metrics,
        [],
        spectra,
        warnings=warnings,
        fields=FieldScan(psf, rgb, list(angles_rad), azimuth_rad, chief, centre, metrics),
    )
    if check_accuracy:
        k = int(np.argmax(angles_rad))
        i, j = np.unravel_index(np.argmax(psf[k].max(axis=(-2, -1))), psf.shape[1:3])
        clock = time.perf_counter()
        doubled = field_psf(
            design.lens, [wavelengths_m[j]], [depths_m[i]], pixels, pixel_pitch_m, angles_rad[k],
            azimuth_rad=azimuth_rad, distance_m=design.focal_length_m, dtype=dtype, device=device, force=force,
            oversample=2.0,
        )  # fmt: skip
        scan.accuracy = {
            "field": k,
            "depth_m": depths_m[i],
            "wavelength_m": wavelengths_m[j],
            "doubled_sampling_rel_l2": relative_l2(psf[k, i, j], doubled.psf[0, 0].detach().cpu().numpy()),
            "doubled_sampling_seconds": time.perf_counter() - clock,
        }
    return scan


def field_metadata(scan: ScanResult) -> dict:
    """The field keys of a field cube's header (docs/formats.md), with the kept light per PSF."""
    f = scan.fields
    return {
        "field_angles_rad": f.angles_rad,
        "field_azimuth_rad": f.azimuth_rad,
        "chief_ray_m": f.chief_ray_m,
        "window_centre_px": f.centre_px,
        "field_kept": f.psf.sum(axis=(-2, -1)).astype(float).tolist(),
    }
