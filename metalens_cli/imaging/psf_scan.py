"""PSF cubes over wavelength and depth (the core of ``metalens psf-scan``), with cost and accuracy.

A scan computes psf[i, j] for depths[i] × wavelengths[j] through :func:`compute_psf`, the
channel PSFs rgb[i, c] = Σ_j w[c, j]·psf[i, j] when a preset defines the spectra (S^c
quadrature on the scan wavelengths: filter × camera response, w summing to 1 per channel),
summaries of every PSF and of every channel PSF (its centre 5 × 5 energy is the spectrally
weighted mean of the wavelengths' own), and, on request, an accuracy report:
the sharpest PSF recomputed with doubled sampling and, for radial designs, with the direct
Rayleigh-Sommerfeld reference. The scan's cost is estimated and its cube file checked before
any work; the cube is written with the scan's metadata in its header.

With field angles (:func:`run_scan`'s ``field_angles_rad``) the cube gains a field axis (docs/formats.md, field
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
from metalens_cli.optics.sampling import PsfGrid, psf_grid
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


def _scan_inputs(design, grid, field_angles_rad, azimuth_rad, propagator, dtype):
    """The checked arguments of a scan: the grid at the design's focal length (unless it names a
    distance) and the field angles (rad) or None."""
    arguments.instance(design, "design", Design, "a Design (ml.resolve_design)")
    if field_angles_rad is None:
        grid = psf_inputs(design.lens, _at_focus(design, grid), propagator, dtype)
        return grid, None
    grid = psf_inputs(design.lens, _at_focus(design, grid), dtype=dtype)
    angles = arguments.numbers_of(field_angles_rad, "field_angles_rad", lo=0.0, form="field angles ≥ 0 (rad)")
    arguments.number(azimuth_rad, "azimuth_rad", form="a finite azimuth (rad)")
    if propagator not in ("auto", "asm"):
        raise InputError(
            "propagator", f"{propagator!r} with field angles", "auto or asm (off axis: the shifted angular spectrum)"
        )
    return grid, angles


def _at_focus(design: Design, grid: PsfGrid) -> PsfGrid:
    """``grid`` at the design's lens-to-sensor distance when it names none."""
    grid = psf_grid(grid)
    return grid.replace(distance_m=design.focal_length_m) if grid.distance_m is None else grid


def estimate_scan(
    design: Design,
    grid: PsfGrid,
    *,
    field_angles_rad: list[float] | None = None,
    azimuth_rad: float = 0.0,
    propagator: str = "auto",
    dtype: torch.dtype = torch.float32,
    force: bool = False,
) -> Estimate:
    """Peak memory and time of :func:`run_scan` with these arguments, and the bytes of its
    float32 cube, before any work (the sampling guard applies).

    Args:
        design: the design scanned.
        grid: the scan's wavelengths (m), depths (m), window, pixel pitch (m) and distance (m;
            None: the design's focal length).
        field_angles_rad: None: an on-axis scan (``optics.psf.estimate_psf``); else the field
            angles (rad): an on-axis field as on axis, each other as
            ``optics.field.estimate_field_psf`` at ``azimuth_rad``.
        azimuth_rad: azimuth of the fields (rad).
        propagator: on axis "auto", "asm", "radial" or "rs"; with fields "auto" or "asm".
        dtype: real dtype of the computation, float32 or float64.
        force: proceed past the sampling guard.

    Returns:
        The scan's peak memory (bytes), seconds and cube bytes.
    """
    from metalens_cli.optics.field import estimate_field_psf

    grid, angles = _scan_inputs(design, grid, field_angles_rad, azimuth_rad, propagator, dtype)
    on_axis = propagator if angles is None else "auto"  # a field scan's on-axis field: compute_psf's choice
    axis = estimate_psf(design.lens, grid, propagator=on_axis, dtype=dtype, force=force)
    fields = [0.0] if angles is None else angles
    off = [a for a in fields if a > 0]
    memory, seconds = axis.memory_bytes, axis.seconds if len(off) < len(fields) else 0.0
    for angle in off:
        tilted = estimate_field_psf(design.lens, grid, angle, azimuth_rad=azimuth_rad, dtype=dtype, force=force)
        memory, seconds = max(memory, tilted.memory_bytes), seconds + tilted.seconds
    count = grid.count * len(fields)
    what = f"psf-scan of {count} PSFs of {grid.pixels}² pixels"
    return Estimate(
        what if angles is None else f"{what} over {len(angles)} fields",
        memory,
        "--pixels",
        seconds,
        disk_bytes=count * grid.pixels**2 * 4,
    )


def run_scan(
    design: Design,
    grid: PsfGrid,
    *,
    field_angles_rad: list[float] | None = None,
    azimuth_rad: float = 0.0,
    propagator: str = "auto",
    dtype: torch.dtype = torch.float32,
    device: str = "cpu",
    force: bool = False,
    check_accuracy: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> ScanResult:
    """The PSF cube of ``design`` over ``grid``, on axis or over field angles (module docstring).

    An on-axis field of a radial design runs as one batch; every other field goes one wavelength
    at a time so that ``progress(done, total)`` can report. The channel weights (which refuse a
    wavelength list that cannot integrate S^c) are settled before any PSF is computed.

    Args:
        design: the design scanned (its preset, if any, gives the R, G, B spectra).
        grid: the scan's wavelengths (m), depths (m, inf: plane wave), window, pixel pitch (m) and
            lens-to-sensor distance (m; None: the design's focal length).
        field_angles_rad: None: the on-axis scan (``optics.psf.compute_psf``, no field axis);
            else the field angles (rad) of a field scan (``optics.field.field_psf``, each window
            centred on its chief ray), field 0's PSFs being the result's ``psf``/``rgb``.
        azimuth_rad: azimuth of the fields (rad), counter-clockwise from the sensor's +x axis.
        propagator: on axis "auto", "asm", "radial" or "rs"; with fields "auto" or "asm".
        dtype: real dtype of the computation, float32 or float64.
        device: torch device to compute on.
        force: proceed past the sampling guard.
        check_accuracy: on axis, recompute the sharpest PSF with doubled sampling and, for a radial
            design, with the direct Rayleigh-Sommerfeld reference (:func:`accuracy_report`); with
            fields, the sharpest PSF of the outermost field with doubled sampling.
        progress: called as ``progress(done, total)`` after each batch.

    Returns:
        The PSFs, channel PSFs, their summaries, timings (s), warnings and, with fields, the field
        axis (``fields``).

    Shape:
        - ``psf``: (D, W, N, N) float32, D depths, W wavelengths, N = ``grid.pixels``.
        - ``rgb``: (D, 3, N, N) float32, or None without spectra.
        - ``fields.psf``: (F, D, W, N, N) and ``fields.rgb``: (F, D, 3, N, N) for F field angles.
    """
    from metalens_cli.optics.field import field_psf

    start = time.perf_counter()
    grid, angles = _scan_inputs(design, grid, field_angles_rad, azimuth_rad, propagator, dtype)
    device = arguments.device(device)
    lams, zs, pitch = list(grid.wavelengths_m), list(grid.depths_m), grid.pixel_pitch_m
    warnings: list[str] = []
    weights, spectra = _channel_weights(design, lams, warnings) if design.preset is not None else (None, None)
    watch = Stopwatch()
    fields = [0.0] if angles is None else angles
    steps: list[tuple[int, list[float]]] = []  # (field, wavelengths): an on-axis radial field is one batch
    radial = design.lens.radial if angles is not None or propagator == "auto" else propagator == "radial"
    for k, angle in enumerate(fields):
        batched = angle == 0 and radial
        steps += [(k, lams)] if batched else [(k, [w]) for w in lams]
    parts: dict[int, list[torch.Tensor]] = {k: [] for k in range(len(fields))}
    results = []
    options = dict(dtype=dtype, device=device, force=force)
    for done, (k, group) in enumerate(steps, start=1):
        if angles is None:
            result = compute_psf(design.lens, grid.replace(wavelengths_m=group), propagator=propagator, **options)
        else:
            result = field_psf(design.lens, grid.replace(wavelengths_m=group), fields[k], azimuth_rad=azimuth_rad,
                               **options)  # fmt: skip
        parts[k].append(result.psf.detach().to("cpu", torch.float32))
        if len(parts[k]) == 1:
            results.append(result)
        watch.add({stage: seconds for stage, seconds in result.timing_s.items() if stage != "total"})
        if progress is not None:
            progress(done, len(steps))
    psf = np.stack([torch.cat(parts[k], dim=1).numpy() for k in range(len(fields))])
    rgb = None if weights is None else np.einsum("cw,fdwij->fdcij", weights, psf).astype(np.float32)
    metrics = [
        {"depth_m": z, "wavelength_m": w, **summarize(psf[0, i, j], pitch)}
        for i, z in enumerate(zs)
        for j, w in enumerate(lams)
    ]
    channel_metrics = (
        [
            {"depth_m": z, "channel": name, **summarize(rgb[0, i, c], pitch)}
            for i, z in enumerate(zs)
            for c, name in enumerate(spectra["channels"])
        ]
        if rgb is not None and angles is None
        else []
    )
    # the grid reported: on axis the last batch's (its wavelength's plan), with fields the last field's first batch
    shown = result if angles is None else results[-1]
    field_scan = (
        None if angles is None else _field_scan(psf, rgb, angles, azimuth_rad, results, grid, spectra, warnings)
    )
    watch.times["total"] = time.perf_counter() - start
    scan = ScanResult(
        psf[0],
        None if rgb is None else rgb[0],
        lams,
        zs,
        pitch,
        shown.propagator,
        shown.grid,
        watch.times,
        metrics,
        channel_metrics,
        spectra,
        warnings=warnings,
        fields=field_scan,
    )
    if check_accuracy:
        accuracy = accuracy_report if angles is None else _field_accuracy
        scan.accuracy = accuracy(design, scan, dtype, device, force)
    return scan


def _field_scan(psf, rgb, angles, azimuth, results, grid: PsfGrid, spectra, warnings: list[str]) -> FieldScan:
    """The field axis of a scan: per field its summaries (``analysis.psf_metrics.field_summary``)
    and a warning where its window keeps too little light."""
    from metalens_cli.analysis.psf_metrics import field_summary

    lams, zs, pitch, pixels = grid.wavelengths_m, grid.depths_m, grid.pixel_pitch_m, grid.pixels
    chief = [[float(v) for v in r.chief_ray_m] for r in results]
    centre = [[int(v) for v in r.centre_px] for r in results]
    metrics = []
    for k, angle in enumerate(angles):
        offset = (centre[k][0] * pitch - chief[k][0], centre[k][1] * pitch - chief[k][1])
        entry = {
            "field": k,
            "angle_rad": angle,
            "angle_deg": math.degrees(angle),
            "chief_ray_m": chief[k],
            "window_centre_px": centre[k],
            "propagator": results[k].propagator,
            "psfs": [
                {"depth_m": z, "wavelength_m": w, **field_summary(psf[k, i, j], pitch, offset, azimuth)}
                for i, z in enumerate(zs)
                for j, w in enumerate(lams)
            ],
        }
        if rgb is not None:
            entry["channel_psfs"] = [
                {"depth_m": z, "channel": name, **field_summary(rgb[k, i, c], pitch, offset, azimuth)}
                for i, z in enumerate(zs)
                for c, name in enumerate(spectra["channels"])
            ]
        metrics.append(entry)
        kept = psf[k].sum(axis=(-2, -1))
        if kept.min() < COVERAGE_WARNING:
            warnings.append(
                f"field {k} ({math.degrees(angle):.3g}°): the {pixels}-pixel window keeps as little as "
                f"{kept.min():.3f} of the light; widen --pixels"
            )
    return FieldScan(psf, rgb, list(angles), azimuth, chief, centre, metrics)


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
    grid = PsfGrid([w], [z], n, scan.pixel_pitch_m, design.focal_length_m)
    options = dict(device=device, force=force)
    doubled = compute_psf(design.lens, grid, propagator=scan.propagator, dtype=dtype, oversample=2.0, **options)
    report["doubled_sampling_rel_l2"] = relative_l2(reference, doubled.psf[0, 0].detach().cpu().numpy())
    report["doubled_sampling_seconds"] = time.perf_counter() - start
    if design.lens.radial and scan.propagator != "rs":
        m = min(rs_window, n if n % 2 else n - 1)  # odd: its axis pixel m//2 lines up with n//2
        c, h = n // 2, m // 2
        start = time.perf_counter()
        exact = compute_psf(design.lens, grid.replace(pixels=m), propagator="rs", dtype=torch.float64, **options)
        crop = reference[c - h : c + h + 1, c - h : c + h + 1]
        report["rs_rel_l2"] = relative_l2(crop, exact.psf[0, 0].detach().cpu().numpy())
        report["rs_window_pixels"] = m
        report["rs_seconds"] = time.perf_counter() - start
    return report


def _field_accuracy(design: Design, scan: ScanResult, dtype, device, force: bool) -> dict:
    """Recompute the sharpest PSF of the outermost field with doubled sampling (the direct
    Rayleigh-Sommerfeld sum over a lens of this size is out of reach off axis); relative L2."""
    from metalens_cli.optics.field import field_psf

    fields = scan.fields
    k = int(np.argmax(fields.angles_rad))
    i, j = np.unravel_index(np.argmax(fields.psf[k].max(axis=(-2, -1))), fields.psf.shape[1:3])
    clock = time.perf_counter()
    grid = PsfGrid([scan.wavelengths_m[j]], [scan.depths_m[i]], scan.psf.shape[-1], scan.pixel_pitch_m,
                   design.focal_length_m)  # fmt: skip
    doubled = field_psf(design.lens, grid, fields.angles_rad[k], azimuth_rad=fields.azimuth_rad, dtype=dtype,
                        device=device, force=force, oversample=2.0)  # fmt: skip
    return {
        "field": k,
        "depth_m": scan.depths_m[i],
        "wavelength_m": scan.wavelengths_m[j],
        "doubled_sampling_rel_l2": relative_l2(fields.psf[k, i, j], doubled.psf[0, 0].detach().cpu().numpy()),
        "doubled_sampling_seconds": time.perf_counter() - clock,
    }


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
