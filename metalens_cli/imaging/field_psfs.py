"""R, G, B PSFs over the field of a radially symmetric design: what a space-variant capture needs.

A set holds, at the near and the far depth, the channel PSFs of K image points on the sensor's +x
axis at heights h_k pixels (h_0 = 0 to the sensor's corner), each in a window centred on its
chief-ray pixel: α_k = atan(h_k·p/f) puts the chief ray of a lens whose phase is flat at its centre
(every radial one) on pixel h_k exactly. Other azimuths are rotations (``imaging.field_formation``).

- h = 0: the on-axis channel PSFs of ``imaging.channel_psfs.channel_psfs`` (radial path, every wavelength).
- h > 0: ``optics.field.field_psf`` (2-D shifted angular spectrum, seconds per PSF at the paper's
  lens) at the midpoints of ``wavelengths_per_channel`` equal-mass strata of each channel's S^c
  (``optics.spectra.sample_wavelengths``). The error of that reduction is measured on axis, where
  both are cheap (``spectral_error``: relative L2 of the on-axis channel PSFs from the strata
  against the full quadrature), and reported. The on-axis entry keeps the full quadrature, so the
  capture at the centre is the on-axis model's exactly.
- Sampling: ``field_psf`` with the on-axis angle margin (``optics.field.ON_AXIS_MARGIN``; its
  default doubles it for small lenses, whose edge-diffracted light it would otherwise cut). What
  that costs is measured on every set: the corner's far PSF at the middle wavelength against the
  doubled margin (``sampling_error``, relative L2).
- Windows: the on-axis rule's, grown to hold the geometric rays at the corner (``optics.field.
  field_window``); what each window keeps is reported.
- Cached on disk (``io.cache``, kind ``field-psfs``) by a hash of the lens, depths, wavelengths,
  sensor and heights: the same set is computed once.

``field_dependence`` is the isoplanatic test ``--field auto`` uses: geometric rays of the middle
wavelength from a plane wave at the sensor corner's field angle; the field matters when their RMS
spot radius exceeds the on-axis one by more than a pixel.
"""

from __future__ import annotations

import hashlib
import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from metalens_cli import arguments
from metalens_cli.errors import InputError
from metalens_cli.imaging.channel_psfs import channel_psfs, design_sensitivity
from metalens_cli.imaging.field_formation import FieldPsfSet, height_check
from metalens_cli.io.cache import cached, check_array, input_key
from metalens_cli.optics.field import ON_AXIS_MARGIN, field_window
from metalens_cli.optics.window import crop_window

HEIGHT_STEP_PX = 90  # default spacing of the image points from the axis to the corner (at most 5 of them)
# strata per channel: on the paper's lenses' on-axis PSFs 0.13-0.76 relative L2 from every 2.5 nm, but in captures of
# the photographs −0.14 dB PSNR (hyperbolic) and +0.00-0.01 dB (learned) against every 5 nm (docs/field.md)
DEFAULT_WAVELENGTHS_PER_CHANNEL = 8
CACHE_KIND = "field-psfs"
CACHE_VERSION = 3  # bump when the computation changes


@dataclass
class FieldPsfs:
    """The near and far :class:`FieldPsfSet` (heights in pixels, PSFs (K, 3, N, N) summing to what
    each window keeps), their depths (m), field angles (rad) and the report."""

    near: FieldPsfSet
    far: FieldPsfSet
    z_near_m: float
    z_far_m: float
    angles_rad: list[float]
    wavelengths_m: list[float]
    spectral_error: dict
    sampling_error: float
    kept: dict
    seconds: float
    cached: bool
    cache_path: str | None = None
    height_error: dict = field(default_factory=dict)

    @property
    def margin(self) -> int:
        """Canvas margin (pixels) these PSFs need around the sensor."""
        return max(self.near.psfs.shape[-1], self.far.psfs.shape[-1]) // 2

    def report(self) -> dict:
        """JSON-ready: the image heights (pixels), field angles (degrees), wavelengths (m), window
        sides (pixels), the energy the windows kept, the spectral, sampling and height errors, the
        seconds, and whether and where the PSFs were cached."""
        return {
            "field_heights_px": list(self.near.heights_px),
            "field_angles_deg": [math.degrees(a) for a in self.angles_rad],
            "field_wavelengths_m": self.wavelengths_m,
            "field_psf_window_px": {"near": self.near.psfs.shape[-1], "far": self.far.psfs.shape[-1]},
            "field_psf_energy": self.kept,
            "spectral_error": self.spectral_error,
            "sampling_error": self.sampling_error,
            "height_error": self.height_error,
            "field_psf_seconds": self.seconds,
            "field_psf_cached": self.cached,
            "field_psf_cache": self.cache_path,
        }


def corner_pixels(sensor_pixels: int) -> int:
    """Distance (pixels, rounded up) from the axis pixel to the farthest sensor corner pixel."""
    half = sensor_pixels // 2
    return math.ceil(math.hypot(half, half))


def field_heights(sensor_pixels: int, heights: int | None = None) -> tuple[int, ...]:
    """Image-point heights (pixels) from the axis (0) to the sensor's corner: ``heights`` of them,
    default one per ``HEIGHT_STEP_PX`` (2 to 5)."""
    top = corner_pixels(sensor_pixels)
    heights = heights or max(2, min(5, math.ceil(top / HEIGHT_STEP_PX) + 1))
    if heights < 2:
        raise InputError("field heights", f"{heights}", "at least 2 (the axis and the corner)")
    return tuple(sorted({round(top * k / (heights - 1)) for k in range(heights)}))


def field_dependence(design, sensor_pixels: int, pixel_pitch_m: float, wavelength_m: float = 530e-9) -> dict:
    """The isoplanatic test (module docstring): the corner's field angle, the RMS geometric spot
    radii (m) on axis and at the corner, and whether the field matters (``field_dependent``)."""
    from metalens_cli.optics.field import ray_landings, rms_spot

    d = design.focal_length_m
    corner = math.atan2(corner_pixels(sensor_pixels) * pixel_pitch_m, d)
    axis = rms_spot(ray_landings(design.lens, wavelength_m, 0.0, math.inf, d)[0])
    edge = rms_spot(ray_landings(design.lens, wavelength_m, corner, math.inf, d)[0])
    return {
        "corner_field_deg": math.degrees(corner),
        "rms_spot_axis_m": axis,
        "rms_spot_corner_m": edge,
        "field_dependent": bool(design.lens.radial and edge - axis > pixel_pitch_m),
        "rule": "RMS geometric spot at the sensor corner exceeds the on-axis one by more than a pixel (530 nm, ∞)",
    }


def estimate_field_psfs(design, sensor_pixels: int, pixel_pitch_m: float, depths_m, wavelengths_m) -> tuple[int, float]:
    """(peak bytes, seconds) of :func:`field_channel_psfs` at ``depths_m`` (near, far), when not
    cached: each off-axis height's PSFs (``optics.field.estimate_field_psf``, the set's margin, at
    the set's wavelengths, :func:`field_strata`) in a window no smaller than the set's (the rays'
    window of the on-axis rule at ``wavelengths_m``, the on-axis quadrature's, or of the corner's
    rays) and the corner's check with the doubled margin."""
    from metalens_cli.optics.blur import psf_window
    from metalens_cli.optics.field import estimate_field_psf
    from metalens_cli.optics.sampling import PsfGrid

    heights = field_heights(sensor_pixels)[1:]
    d, lens = design.focal_length_m, design.lens
    lams = [float(x) for x in field_strata(design).wavelengths_m]
    corner = math.atan2(heights[-1] * pixel_pitch_m, d)
    window = max(
        field_window(lens, lams, z, corner, d, pixel_pitch_m, psf_window(lens, wavelengths_m, [z], d, pixel_pitch_m))
        for z in depths_m
    )
    grid = PsfGrid(lams, depths_m, window, pixel_pitch_m, d)
    costs = [
        estimate_field_psf(lens, grid, math.atan2(h * pixel_pitch_m, d), oversample=ON_AXIS_MARGIN, force=True)
        for h in heights
    ]
    middle = lams[len(lams) // 2]
    costs.append(
        estimate_field_psf(lens, grid.replace(wavelengths_m=[middle], depths_m=[depths_m[-1]]), corner, force=True)
    )
    return max(c.memory_bytes for c in costs), sum(c.seconds for c in costs)


def field_strata(design, wavelengths_per_channel: int | None = None):
    """The wavelengths and weights (``optics.spectra.sample_wavelengths``) the off-axis PSFs of a
    set use: the midpoints of ``wavelengths_per_channel`` (default
    ``DEFAULT_WAVELENGTHS_PER_CHANNEL``) equal-mass strata of each channel's S^c."""
    from metalens_cli.optics.spectra import sample_wavelengths

    return sample_wavelengths(
        design_sensitivity(design), wavelengths_per_channel or DEFAULT_WAVELENGTHS_PER_CHANNEL, None
    )


def strata_channel_psfs(design, strata, depths_m, pixels: int, pixel_pitch_m: float, device="cpu") -> torch.Tensor:
    """On-axis R, G, B PSFs (Z, 3, N, N), float64, from the wavelengths of ``strata``
    (:func:`field_strata`) alone: what the off-axis PSFs' spectral reduction does on axis."""
    from metalens_cli.optics.psf import compute_psf
    from metalens_cli.optics.sampling import PsfGrid

    lams = [float(x) for x in strata.wavelengths_m]
    grid = PsfGrid(lams, list(depths_m), pixels, pixel_pitch_m, design.focal_length_m)
    mono = compute_psf(design.lens, grid, device=device).psf
    return torch.einsum("zwij,cw->zcij", mono.double(), torch.as_tensor(strata.weights, device=mono.device))


def field_channel_psfs(
    design,
    z_near_m: float,
    z_far_m: float,
    wavelengths_m,
    pixel_pitch_m: float,
    sensor_pixels: int,
    *,
    heights: int | None = None,
    wavelengths_per_channel: int | None = None,
    device="cpu",
    progress=None,
) -> FieldPsfs:
    """The near and far PSF sets of ``design`` over a ``sensor_pixels``² sensor (module docstring).

    Cached on disk by a hash of the lens, depths, wavelengths, sensor and heights.

    Args:
        design: a radially symmetric resolved design (:func:`resolve_design`).
        z_near_m: the near (obstruction) depth (m).
        z_far_m: the far (scene) depth (m).
        wavelengths_m: the on-axis quadrature's wavelengths (m) (as
            ``imaging.channel_psfs.channel_psfs``).
        pixel_pitch_m: sensor pixel pitch (m).
        sensor_pixels: the sensor's side (pixels).
        heights: image points from the axis to the corner (default one per ``HEIGHT_STEP_PX``, 2
            to 5).
        wavelengths_per_channel: strata per channel off axis (default
            ``DEFAULT_WAVELENGTHS_PER_CHANNEL``).
        device: torch device.
        progress: ``progress(done, total)`` after each off-axis height.

    Returns:
        ``FieldPsfs``: the near and far :class:`FieldPsfSet` (heights in pixels, PSFs (K, 3, N, N)
        summing to what each window keeps), their depths (m), field angles (rad), the wavelengths
        (m) and the report (spectral and sampling errors, kept fractions).
    """
    from metalens_cli.io.designs import Design
    from metalens_cli.optics.field import field_psf
    from metalens_cli.optics.sampling import PsfGrid

    arguments.instance(design, "design", Design, "a Design (ml.resolve_design)")
    arguments.positive(z_near_m, "z_near_m")
    arguments.positive(z_far_m, "z_far_m", allow_inf=True)
    arguments.lengths(wavelengths_m, "wavelengths_m")
    arguments.positive(pixel_pitch_m, "pixel_pitch_m")
    arguments.count(sensor_pixels, "sensor_pixels")
    device = arguments.device(device)
    if not design.lens.radial:
        raise InputError(
            "--field", "a field-dependent capture rotates one radius's PSFs", "a radially symmetric design"
        )
    start = time.perf_counter()
    d = design.focal_length_m
    heights_px = field_heights(sensor_pixels, heights)
    angles = [math.atan2(h * pixel_pitch_m, d) for h in heights_px]
    strata = field_strata(design, wavelengths_per_channel)
    lams = [float(x) for x in strata.wavelengths_m]
    axis = channel_psfs(design, z_near_m, z_far_m, wavelengths_m, pixel_pitch_m, device=device)
    n = max(axis.near.shape[-1], axis.far.shape[-1])
    reduced = strata_channel_psfs(design, strata, [z_near_m, z_far_m], n, pixel_pitch_m, device=device)
    error = {which: _relative_l2(reduced[i], _pad(getattr(axis, which), n)) for i, which in enumerate(("near", "far"))}
    sizes = [
        field_window(design.lens, lams, z, angles[-1], d, pixel_pitch_m, n)
        for z, n in ((z_near_m, axis.near.shape[-1]), (z_far_m, axis.far.shape[-1]))
    ]
    key = input_key(
        {
            "version": CACHE_VERSION,
            "theta": hashlib.sha256(design.lens.theta.detach().double().cpu().numpy().tobytes()).hexdigest(),
            "lens": [design.lens.pitch_m, design.lens.aperture_m, d],
            "depths": [z_near_m, z_far_m],
            "wavelengths": lams,
            "weights": strata.weights,
            "pitch": pixel_pitch_m,
            "heights": list(heights_px),
            "windows": sizes,
        }
    )

    def compute() -> dict[str, np.ndarray]:
        near, far = [], []
        grid = PsfGrid(lams, [z_near_m, z_far_m], max(sizes), pixel_pitch_m, d)
        for k, angle in enumerate(angles[1:], start=1):
            result = field_psf(design.lens, grid, angle, device=device, oversample=ON_AXIS_MARGIN)
            weights = torch.as_tensor(strata.weights, device=result.psf.device)
            rgb = torch.einsum("zwij,cw->zcij", result.psf.double(), weights).float()
            near.append(crop_window(rgb[0], sizes[0]).cpu().numpy())
            far.append(crop_window(rgb[1], sizes[1]).cpu().numpy())
            if progress is not None:
                progress(k, len(angles) - 1)
        middle = len(lams) // 2
        corner = grid.replace(wavelengths_m=[lams[middle]], depths_m=[z_far_m])
        doubled = field_psf(design.lens, corner, angles[-1], device=device)
        error = _relative_l2(result.psf[1, middle], doubled.psf[0, 0])
        return {"near": np.stack(near), "far": np.stack(far), "sampling_error": np.array([error])}

    def validate(arrays) -> str | None:
        count = len(angles) - 1
        return (
            check_array(arrays, "near", (count, 3, sizes[0], sizes[0]))
            or check_array(arrays, "far", (count, 3, sizes[1], sizes[1]))
            or check_array(arrays, "sampling_error", (1,))
        )

    entry = cached(CACHE_KIND, key, compute, validate)
    sets = []
    for which, on_axis, size in (("near", axis.near, sizes[0]), ("far", axis.far, sizes[1])):
        centre = _pad(on_axis.detach().float().cpu(), size)
        psfs = torch.cat([centre[None], torch.from_numpy(entry.arrays[which])]).to(device)
        sets.append(FieldPsfSet(heights_px, psfs))
    kept = {
        which: [[float(v) for v in s.psfs[k].sum(dim=(-2, -1))] for k in range(len(heights_px))]
        for which, s in zip(("near", "far"), sets)
    }
    return FieldPsfs(
        sets[0], sets[1], z_near_m, z_far_m, angles, lams, error, float(entry.arrays["sampling_error"][0]), kept,
        time.perf_counter() - start, entry.hit, None if entry.path is None else str(entry.path),
        {"near": height_check(sets[0]), "far": height_check(sets[1])},
    )  # fmt: skip


def _pad(psf: torch.Tensor, size: int) -> torch.Tensor:
    """(…, n, n) PSFs centred in (…, size, size) windows (zeros around; axis pixel kept at size//2)."""
    n = psf.shape[-1]
    if n >= size:
        return crop_window(psf, size)
    out = psf.new_zeros(*psf.shape[:-2], size, size)
    lo = size // 2 - n // 2
    out[..., lo : lo + n, lo : lo + n] = psf
    return out


def _relative_l2(a: torch.Tensor, b: torch.Tensor) -> float:
    a, b = a.detach().double().cpu(), b.detach().double().cpu()
    return float((a - b).norm() / b.norm())
