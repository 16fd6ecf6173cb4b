"""Measured against simulated PSF cubes (``metalens psf compare``).

Pairs. Each measured (depth, wavelength) PSF is paired with the simulated one at the same
depth (relative difference ≤ 1e-6; ``inf`` with ``inf``) and wavelength: the same wavelength
(within 1e-3 nm), or, when ``interpolate``, the simulated PSFs at the two nearest wavelengths
around it mixed linearly; a wavelength outside the simulated range (or not matched without
``interpolate``) and a depth without partner are refused, and reported as such.

Common grid. Both are taken at the measured pixel pitch: a simulated cube of another pitch is
re-binned onto the measured pixels (power between their edges, axis on axis). Both are cropped
to the largest window both cover, centred on pixel (N//2, N//2), and normalised to sum to one
over it. Pitches that cannot be a PSF's are refused: a cube whose window spans less than half
its shortest wavelength (no lens focuses light to a spot that small), and a pair in which
either window spans under 3 pixels of the other. A common window under ``MIN_COMMON_PIXELS`` ×
``MIN_COMMON_PIXELS`` is refused, naming the cube whose window limits it: a FWHM, an MTF, a
registration need more than a few samples (3 × 3 gave peak ratios of 1.0 and encircled energies
of 1.000 whatever the PSFs). A measured PSF of which the common window holds under
``LIGHT_REQUIRED`` of the light (its power in its own window: a blur disc wider than a cropped
simulation) is refused, and reported as such; under ``LIGHT_KEPT`` of either cube's light is
warned about: the figures describe the window's part of the PSFs. A simulation coarser than the measurement by over
``COARSE_SIMULATION``× is interpolated, not resolved, on the measured grid: warned about.

Registration. The measured PSF is moved onto the simulated one by the sub-pixel shift at the
maximum of their cross-correlation (a parabola through the peak and its neighbours on each
axis) and a Fourier shift, repeated on the residual (up to 4 rounds: the parabola is biased
away from a sample, not near one); the total shift is reported.

Metrics per pair: ``peak_ratio`` = peak(measured)/peak(simulated), a Strehl-like ratio with the
simulated lens as the reference (1 for identical PSFs); FWHM (metres, the mean of the row's and
the column's through its maximum) of each; encircled energy (fraction of the window) inside
discs of the given radii around each PSF's own centroid (so each PSF's figures do not depend on
the other), None (warned about) for a radius over half the common window's width, where the disc
leaves the window; ``relative_l2`` = ‖measured − simulated‖₂/‖simulated‖₂ after registration; MTF50
(lp/mm, ``analysis.mtf``) of each.

Fields (field cubes, ``io.exr``). Two field cubes are compared field by field: each measured
field with the simulated field at the same angle (within 1e-6 rad; a measured field without one
is refused, and reported as such), their fields at the same azimuth (else refused). Each
field's window is centred where its ``window_centre_px`` says, so the PSFs are compared window
on window as above, and each pair also reports ``sensor_shift_px``: the registration's shift
less the offset between the two windows' centres on the sensor (the simulated centre minus the
measured, in measured pixels), i.e. how far the measured PSF lies from the simulated one on the
sensor. A field cube against an on-axis cube: its field 0 is compared, with a warning.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from metalens_cli.analysis.mtf import mtf50, psf_mtf, radial_grid
from metalens_cli.analysis.psf_metrics import fwhm_pixels
from metalens_cli.analysis.subpixel import fourier_shift, parabola_vertex
from metalens_cli.errors import InputError
from metalens_cli.io.units import format_length
from metalens_cli.optics.window import crop_window

WAVELENGTH_TOLERANCE_M = 1e-12
DEPTH_TOLERANCE = 1e-6
FIELD_ANGLE_TOLERANCE_RAD = 1e-6
REGISTRATION_ROUNDS = 4
COARSE_SIMULATION = 2.0  # simulated pixels this many times the measured ones are warned about
MIN_COMMON_PIXELS = 8  # a common window narrower than this has no FWHM, MTF or registration worth reporting
LIGHT_KEPT = 0.9  # a common window holding less of a cube's light than this is warned about
LIGHT_REQUIRED = 0.5  # a measured PSF of which the common window holds less than this is not compared


@dataclass
class CubeComparison:
    """``pairs``: one record per compared (depth, wavelength); ``refused``: the measured PSFs
    left out and why; ``scans``: per compared depth, (W_c, N) central rows of the measured and
    simulated PSFs (for the x-λ figure); ``pixels`` N and ``pixel_pitch_m`` of the common grid;
    ``warnings``: one line each. Comparing two field cubes, ``fields`` holds one record per
    measured field (its simulated partner, angle, window centres and their offset), and pairs,
    refusals and scans carry ``field`` and ``field_angle_deg`` (pairs also ``sensor_shift_px``)."""

    pairs: list[dict]
    refused: list[dict]
    pixels: int
    pixel_pitch_m: float
    resampled: bool
    radii_m: list[float]
    scans: list[dict] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    fields: list[dict] = field(default_factory=list)


def compare_cubes(measured, simulated, radii_m: list[float] | None = None, interpolate: bool = True) -> CubeComparison:
    """Compare two ``io.exr.PsfCube``\\ s (see the module docstring); ``radii_m`` default: 2, 5
    and 10 measured pixels. InputError when no pair is left."""
    pitch = measured.pixel_pitch_m
    radii = list(radii_m) if radii_m else [2 * pitch, 5 * pitch, 10 * pitch]
    fields, warnings = _field_pairs(measured, simulated)
    warnings += _check_pitches(measured, simulated)
    partners = [f for f in fields if f["simulated_field"] is not None]
    if fields:  # field by field: (F_c, D, W, N, N) stacks of the paired fields
        own_m = measured.field_psf[[f["field"] for f in partners]]
        own_s = simulated.field_psf[[f["simulated_field"] for f in partners]]
    else:  # on axis, or field 0 of a field cube against an on-axis cube
        own_m, own_s = measured.psf[None], simulated.psf[None]
    sim_psf, resampled = _on_pitch(own_s, simulated.pixel_pitch_m, pitch, measured.psf.shape[-1])
    n = min(measured.psf.shape[-1], sim_psf.shape[-1])
    if n < MIN_COMMON_PIXELS:
        raise InputError(*_small_window(measured, simulated, n, sim_psf.shape[-1]))
    meas_psf = crop_window(own_m, n)
    sim_psf = crop_window(sim_psf, n)
    kept = _light_kept(own_m, meas_psf)
    kept_s = _light_kept(own_s, sim_psf)
    angles = [f["angle_deg"] for f in partners] if fields else None
    if not fields:
        kept_m, kept_s = np.where(kept < LIGHT_REQUIRED, 1.0, kept)[0], kept_s[0]
    else:
        kept_m = np.where(kept < LIGHT_REQUIRED, 1.0, kept)
    warnings += _light_warning("measured", measured, kept_m, n, angles)
    warnings += _light_warning("simulated", simulated, kept_s, n, angles)
    radii_outside = [r for r in radii if r > n * pitch / 2]
    if radii_outside:
        warnings.append(
            f"encircled energy at {_lengths(radii_outside)} is not reported: "
            f"{'the disc is' if len(radii_outside) == 1 else 'the discs are'} wider than the compared window "
            f"({n} × {n} pixels of {format_length(pitch)}, {format_length(n * pitch)} across: radii up to "
            f"{format_length(n * pitch / 2)})"
        )
    grid = radial_grid(n, pitch)
    pairs, refused, scans = [], [], []
    for f in fields:
        if f["simulated_field"] is None:
            refused += [
                {**_field_keys(f), "depth_m": _json_depth(depth), "wavelength_m": float(w), "reason": f["reason"]}
                for depth in measured.depths_m
                for w in measured.wavelengths_m
            ]
    for c, f in enumerate(partners or [None]):
        keys = {} if f is None else _field_keys(f)
        for i, depth in enumerate(measured.depths_m):
            k = _depth_index(simulated.depths_m, depth)
            if k is None:
                refused += [
                    {
                        **keys,
                        "depth_m": _json_depth(depth),
                        "wavelength_m": float(w),
                        "reason": "no simulated PSF at this depth",
                    }
                    for w in measured.wavelengths_m
                ]
                continue
            rows_m, rows_s, waves = [], [], []
            for j, wavelength in enumerate(measured.wavelengths_m):
                if kept[c, i, j] < LIGHT_REQUIRED:
                    refused.append(
                        {
                            **keys,
                            "depth_m": _json_depth(depth),
                            "wavelength_m": float(wavelength),
                            "reason": f"the compared window ({n} × {n} pixels of {format_length(pitch)}) holds "
                            f"{_percent(kept[c, i, j])} of its light (a simulated window as wide as the measured "
                            "PSF's light is needed)",
                        }
                    )
                    continue
                mix, how = _wavelength_mix(simulated.wavelengths_m, float(wavelength), interpolate)
                if mix is None:
                    refused.append(
                        {**keys, "depth_m": _json_depth(depth), "wavelength_m": float(wavelength), "reason": how}
                    )
                    continue
                reference = sum(weight * sim_psf[c, k, index].astype(np.float64) for index, weight in mix)
                record, aligned, reference = _compare_pair(
                    meas_psf[c, i, j].astype(np.float64), reference, pitch, radii, grid, n * pitch / 2
                )
                if f is not None:
                    record["sensor_shift_px"] = [s - o for s, o in zip(record["shift_px"], f["window_offset_px"])]
                pairs.append(
                    {
                        **keys,
                        "depth_m": _json_depth(depth),
                        "wavelength_m": float(wavelength),
                        "simulated": how,
                        **record,
                    }
                )
                rows_m.append(aligned[n // 2])
                rows_s.append(reference[n // 2])
                waves.append(float(wavelength))
            if waves:
                scans.append(
                    {
                        **keys,
                        "depth_m": float(depth),
                        "wavelengths_m": waves,
                        "measured": np.array(rows_m),
                        "simulated": np.array(rows_s),
                    }
                )
    if not pairs:
        reason = refused[0]["reason"] if refused else "no PSFs"
        raise InputError(
            "MEASURED",
            f"no (depth, wavelength) of the measured cube can be compared: {reason}",
            "cubes sharing depths and overlapping in wavelength",
        )
    return CubeComparison(pairs, refused, n, pitch, resampled, radii, scans, warnings, fields)


def _field_pairs(measured, simulated) -> tuple[list[dict], list[str]]:
    """The field records of two field cubes (each measured field, its simulated partner at the
    same angle within FIELD_ANGLE_TOLERANCE_RAD or None and why, the window offset), or [] and a
    warning when one cube is on axis (field 0 of the other is compared), or [] and none."""
    if not measured.is_field_cube and not simulated.is_field_cube:
        return [], []
    if not (measured.is_field_cube and simulated.is_field_cube):
        which, cube = ("measured", measured) if measured.is_field_cube else ("simulated", simulated)
        other = "simulated" if which == "measured" else "measured"
        return [], [
            f"the {which} cube holds {cube.field_count} fields and the {other} cube is on axis: only the {which} "
            f"cube's field 0 (at {math.degrees(float(cube.field_angles_rad[0])):.3g}°) is compared"
        ]
    azimuths = (measured.field_azimuth_rad, simulated.field_azimuth_rad)
    if abs(math.remainder(azimuths[0] - azimuths[1], 2 * math.pi)) > FIELD_ANGLE_TOLERANCE_RAD:
        raise InputError(
            "SIMULATED",
            f"its fields lie at azimuth {math.degrees(azimuths[1]):.4g}°, the measured cube's at "
            f"{math.degrees(azimuths[0]):.4g}°: they are other points of the sensor",
            "field cubes whose fields share field_azimuth_rad",
        )
    pitch_m, pitch_s = measured.pixel_pitch_m, simulated.pixel_pitch_m
    records = []
    for k, angle in enumerate(measured.field_angles_rad):
        near = np.flatnonzero(np.abs(simulated.field_angles_rad - angle) <= FIELD_ANGLE_TOLERANCE_RAD)
        record = {"field": k, "angle_rad": float(angle), "angle_deg": math.degrees(float(angle))}
        if not near.size:
            records.append({**record, "simulated_field": None, "reason": "no simulated field at this field angle"})
            continue
        partner = int(near[0])
        centre_m, centre_s = measured.window_centre_px[k], simulated.window_centre_px[partner]
        offset = centre_s * (pitch_s / pitch_m) - centre_m  # [column, row], measured pixels
        records.append(
            {
                **record,
                "simulated_field": partner,
                "window_centre_px": {"measured": centre_m.tolist(), "simulated": centre_s.tolist()},
                "window_offset_px": [float(offset[1]), float(offset[0])],  # (y, x) as shift_px
                "chief_ray_m": {
                    "measured": measured.chief_ray_m[k].tolist(),
                    "simulated": simulated.chief_ray_m[partner].tolist(),
                },
            }
        )
    if all(r["simulated_field"] is None for r in records):
        raise InputError(
            "SIMULATED",
            f"none of its field angles ({_degrees(simulated.field_angles_rad)}) is one of the measured cube's "
            f"({_degrees(measured.field_angles_rad)})",
            f"field cubes sharing field angles (within {FIELD_ANGLE_TOLERANCE_RAD:g} rad)",
        )
    return records, []


def _field_keys(record: dict) -> dict:
    """The keys that tie a pair, refusal or scan to its measured field."""
    return {"field": record["field"], "field_angle_deg": record["angle_deg"]}


def _degrees(angles_rad: np.ndarray) -> str:
    """ "0°, 5° and 10°" (at most six, then a count)."""
    texts = [f"{math.degrees(float(a)):.4g}°" for a in angles_rad[:6]]
    more = f" and {angles_rad.size - 6} more" if angles_rad.size > 6 else ""
    return ", ".join(texts) + more


def _check_pitches(measured, simulated) -> list[str]:
    """Refuse pixel pitches no PSF can have (see the module docstring); warn of a simulation
    much coarser than the measurement."""
    for which, cube in (("MEASURED", measured), ("SIMULATED", simulated)):
        n, pitch, shortest = cube.psf.shape[-1], cube.pixel_pitch_m, float(np.min(cube.wavelengths_m))
        if n * pitch < shortest / 2:
            raise InputError(
                which,
                f"its {n} pixels of {format_length(pitch)} span {format_length(n * pitch)}, less than half its "
                f"shortest wavelength ({shortest * 1e9:g} nm): no PSF is that small",
                "a cube whose pixel_pitch_m is the pixel pitch in metres",
            )
    measured_pitch, simulated_pitch = format_length(measured.pixel_pitch_m), format_length(simulated.pixel_pitch_m)
    ratio = simulated.pixel_pitch_m / measured.pixel_pitch_m
    if measured.psf.shape[-1] < 3 * ratio:
        raise InputError(
            "MEASURED",
            f"its window ({measured.psf.shape[-1]} pixels of {measured_pitch}) spans under 3 simulated "
            f"pixels of {simulated_pitch}",
            "a measured window at least 3 simulated pixels wide (check both cubes' pixel_pitch_m)",
        )
    if ratio > COARSE_SIMULATION:
        return [
            f"the simulated pixels ({simulated_pitch}) are {ratio:.3g}× the measured ({measured_pitch}): the "
            "simulation is interpolated onto the measured grid, not resolved on it (psf-scan --pixel-pitch "
            f"{measured.pixel_pitch_m * 1e6:.3g}um simulates at the measured pitch)"
        ]
    return []


def _small_window(measured, simulated, n: int, resampled_n: int) -> tuple[str, str, str]:
    """(field, message, expected) refusing a common window of n < MIN_COMMON_PIXELS pixels,
    naming the cube whose window limits it."""
    pitch = format_length(measured.pixel_pitch_m)
    if measured.psf.shape[-1] <= resampled_n:
        return (
            "MEASURED",
            f"the common window is {n} × {n} pixels of {pitch}, its own window: too small to compare PSFs",
            f"a measured window of at least {MIN_COMMON_PIXELS} × {MIN_COMMON_PIXELS} pixels",
        )
    own = simulated.psf.shape[-1]
    return (
        "SIMULATED",
        f"its window ({own} × {own} pixels of {format_length(simulated.pixel_pitch_m)}, "
        f"{format_length(own * simulated.pixel_pitch_m)} across) covers {n} × {n} measured pixels of {pitch}: too "
        "small to compare PSFs",
        f"a simulated window at least {MIN_COMMON_PIXELS} measured pixels "
        f"({format_length(MIN_COMMON_PIXELS * measured.pixel_pitch_m)}) wide (check both cubes' pixel_pitch_m)",
    )


def _light_kept(own: np.ndarray, cropped: np.ndarray) -> np.ndarray:
    """(D, W): the fraction of each PSF's power in its own window (``own``) that the common
    window (``cropped``, on the measured grid) holds; 1 for a PSF without light."""
    total = own.astype(np.float64).sum(axis=(-2, -1))
    kept = cropped.astype(np.float64).sum(axis=(-2, -1))
    return np.where(total > 0, kept / np.where(total > 0, total, 1.0), 1.0)


def _light_warning(which: str, cube, kept: np.ndarray, n: int, angles_deg: list[float] | None = None) -> list[str]:
    """A warning when the common window holds under LIGHT_KEPT of the light of some of
    ``cube``'s PSFs (the least said): ``kept`` (D, W), or (F_c, D, W) for the compared fields
    at ``angles_deg``."""
    index = np.unravel_index(int(np.argmin(kept)), kept.shape)
    k, j = index[-2:]
    if kept[index] >= LIGHT_KEPT:
        return []
    at_field = "" if angles_deg is None else f", field {angles_deg[index[0]]:.3g}°"
    return [
        f"the compared window ({n} × {n} pixels) holds only {_percent(kept[index])} of the {which} PSF's light at "
        f"{cube.wavelengths_m[j] * 1e9:g} nm, {format_length(float(cube.depths_m[k]))}{at_field} "
        f"({int(np.sum(kept < LIGHT_KEPT))} of {kept.size} PSFs under {LIGHT_KEPT:.0%}): the figures describe the "
        "window's part of the PSFs"
    ]


def _percent(fraction: float) -> str:
    """0.9 → "90%", 0.0031 → "0.31%"."""
    return f"{100 * float(fraction):.2g}%"


def _lengths(values: list[float]) -> str:
    """ "9.25 µm", "9.25 µm and 18.5 µm", "1 µm, 2 µm and 3 µm"."""
    texts = [format_length(v) for v in values]
    return texts[0] if len(texts) == 1 else f"{', '.join(texts[:-1])} and {texts[-1]}"


def _json_depth(depth: float) -> float | None:
    return None if math.isinf(depth) else float(depth)


def _depth_index(depths: np.ndarray, depth: float) -> int | None:
    for k, other in enumerate(depths):
        if (math.isinf(depth) and math.isinf(other)) or (
            math.isfinite(depth) and math.isfinite(other) and abs(other - depth) <= DEPTH_TOLERANCE * depth
        ):
            return k
    return None


def _wavelength_mix(
    wavelengths: np.ndarray, wavelength: float, interpolate: bool
) -> tuple[list[tuple[int, float]] | None, str]:
    """[(simulated index, weight)] and how the simulated PSF is made ("exact", "interpolated
    from 530 and 535 nm"), or (None, why it is refused)."""
    exact = np.flatnonzero(np.abs(wavelengths - wavelength) <= WAVELENGTH_TOLERANCE_M)
    if exact.size:
        return [(int(exact[0]), 1.0)], "exact"
    order = np.argsort(wavelengths)
    ordered = wavelengths[order]
    if not interpolate:
        return None, "no simulated PSF at this wavelength (interpolation off)"
    if not ordered[0] < wavelength < ordered[-1]:
        return None, f"outside the simulated {ordered[0] * 1e9:g}-{ordered[-1] * 1e9:g} nm"
    upper = int(np.searchsorted(ordered, wavelength))
    lo, hi = ordered[upper - 1], ordered[upper]
    t = (wavelength - lo) / (hi - lo)
    return [
        (int(order[upper - 1]), 1 - t),
        (int(order[upper]), t),
    ], f"interpolated from {lo * 1e9:g} and {hi * 1e9:g} nm"


def _on_pitch(psf: np.ndarray, pitch_m: float, target_m: float, target_n: int) -> tuple[np.ndarray, bool]:
    """PSFs (..., N, N) of pitch ``pitch_m`` re-binned onto pixels of ``target_m`` (axis kept at
    N//2), over the target pixels the source covers (at most ``target_n``): each target pixel
    gets the power between its edges, read off a cubic interpolation of the integral image
    (exact at source pixel edges, smooth between them; 2× re-binning of a Gaussian of σ = 3
    source pixels is within 2 % at the peak)."""
    if abs(pitch_m - target_m) <= 1e-6 * target_m:
        return psf, False
    from scipy.ndimage import map_coordinates

    n = psf.shape[-1]
    ratio = target_m / pitch_m
    extent = (n - 1) - n // 2 + 0.5  # source pixels from the axis to its nearer window edge
    half = min(target_n // 2, math.floor(extent / ratio - 0.5))
    if half < 1:
        raise InputError(
            "SIMULATED",
            f"its window ({n} pixels of {pitch_m * 1e6:g} µm) covers under 3 measured pixels",
            "a simulated window at least 3 measured pixels wide",
        )
    edges = (np.arange(-half, half + 2) - 0.5) * ratio + n // 2 + 0.5  # target pixel edges, in integral-image indices
    yy, xx = np.meshgrid(edges, edges, indexing="ij")
    flat = psf.reshape(-1, n, n).astype(np.float64)
    out = []
    for plane in flat:
        integral = np.zeros((n + 1, n + 1))
        integral[1:, 1:] = plane.cumsum(0).cumsum(1)
        c = map_coordinates(integral, [yy, xx], order=3, mode="nearest")
        out.append(c[1:, 1:] - c[:-1, 1:] - c[1:, :-1] + c[:-1, :-1])
    return np.stack(out).reshape(*psf.shape[:-2], 2 * half + 1, 2 * half + 1), True


def _compare_pair(
    measured: np.ndarray, simulated: np.ndarray, pitch: float, radii: list[float], grid, max_radius: float
) -> tuple[dict, np.ndarray, np.ndarray]:
    """Metrics of one pair (encircled energy None at radii over ``max_radius``); also the
    registered measured PSF and the simulated one, both normalised to sum to one."""
    total_m, total_s = measured.sum(), simulated.sum()
    if total_m <= 0 or total_s <= 0:
        raise InputError(
            "MEASURED" if total_m <= 0 else "SIMULATED",
            "a PSF holds no light in the common window",
            "PSFs with positive sums",
        )
    measured, simulated = measured / total_m, simulated / total_s
    dy = dx = 0.0
    aligned = measured
    for _ in range(REGISTRATION_ROUNDS):  # the parabola's bias shrinks with the residual shift
        ry, rx = _correlation_shift(aligned, simulated)
        if abs(ry) < 1e-4 and abs(rx) < 1e-4:
            break
        dy, dx = dy + ry, dx + rx
        aligned = fourier_shift(measured, -dy, -dx)
    mtf = psf_mtf(np.stack([aligned, simulated]).astype(np.float32), grid)
    m50 = mtf50(grid.frequencies_lpmm, mtf)
    record = {
        "shift_px": [float(dy), float(dx)],
        "peak_ratio": float(aligned.max() / simulated.max()),
        "fwhm_m": {"measured": _fwhm(measured, pitch), "simulated": _fwhm(simulated, pitch)},
        "encircled_energy": {
            "measured": _encircled(measured, pitch, radii, max_radius),
            "simulated": _encircled(simulated, pitch, radii, max_radius),
        },
        "relative_l2": float(np.linalg.norm(aligned - simulated) / np.linalg.norm(simulated)),
        "mtf50_lpmm": {
            "measured": None if np.isnan(m50[0]) else float(m50[0]),
            "simulated": None if np.isnan(m50[1]) else float(m50[1]),
        },
    }
    return record, aligned, simulated


def _fwhm(psf: np.ndarray, pitch: float) -> float | None:
    """Mean FWHM (metres) of the row and the column through the PSF's maximum; None if either
    does not fall to half inside the window."""
    iy, ix = np.unravel_index(int(np.argmax(psf)), psf.shape)
    c = psf.shape[-1] // 2
    centred = np.roll(psf, (c - iy, c - ix), axis=(0, 1))
    widths = [fwhm_pixels(centred[c]), fwhm_pixels(centred[:, c])]
    return None if None in widths else float(np.mean(widths)) * pitch


def _encircled(psf: np.ndarray, pitch: float, radii: list[float], max_radius: float) -> list[float | None]:
    """Fraction of the window's power inside discs of ``radii`` (metres) around the PSF's own
    centroid (pixels whose centres lie inside); None for a radius over ``max_radius`` (a disc
    wider than the window would read 1 for any PSF)."""
    yy, xx = np.indices(psf.shape, dtype=np.float64)
    total = psf.sum()
    cy, cx = (psf * yy).sum() / total, (psf * xx).sum() / total
    r = np.hypot(yy - cy, xx - cx) * pitch
    return [None if radius > max_radius else float(psf[r <= radius].sum() / total) for radius in radii]


def _correlation_shift(moving: np.ndarray, fixed: np.ndarray) -> tuple[float, float]:
    """(dy, dx) such that ``moving`` ≈ ``fixed`` moved by (dy, dx): the cross-correlation's
    maximum, refined by a parabola through it and its neighbours on each axis (circular)."""
    correlation = np.real(np.fft.ifft2(np.fft.fft2(moving) * np.conj(np.fft.fft2(fixed))))
    n0, n1 = correlation.shape
    iy, ix = np.unravel_index(int(np.argmax(correlation)), correlation.shape)

    dy = parabola_vertex(correlation[(iy - 1) % n0, ix], correlation[iy, ix], correlation[(iy + 1) % n0, ix])
    dx = parabola_vertex(correlation[iy, (ix - 1) % n1], correlation[iy, ix], correlation[iy, (ix + 1) % n1])
    return (iy - n0 if iy > n0 // 2 else iy) + dy, (ix - n1 if ix > n1 // 2 else ix) + dx
