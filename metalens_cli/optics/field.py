"""Sensor PSFs of off-axis sources: the field of view of a metalens.

A field point (α, ψ) sends light that reaches the lens centre travelling at angle α from the axis,
azimuth ψ counter-clockwise from the sensor's +x axis (``optics.source``). Its PSF is returned in an
N × N window of sensor pixels centred on the pixel where the chief ray lands (``centre_px``, integer
offsets (column, row) from the axis pixel): window pixel (i, j) is the sensor pixel centred at
x = (j − N//2 + column)·p, y = (i − N//2 + row)·p. Values as in ``optics.psf``: the fraction of the
power through the pupil landing on each pixel.

The chief ray passes the lens centre; it leaves in the direction of the incoming light bent by the
lens's own phase gradient there, s = sin α·(cos ψ, sin ψ) + (λ/2π)·∇φ(0), and lands at d·s/√(1 − |s|²)
(d·tan α for a lens whose phase is flat at its centre, as every radial one).

Method: off axis even a radial lens has only a mirror symmetry, so the pupil field is built on the
whole meta-atom grid (radial lenses: one quadrant of the lens phase, mirrored), its carrier (the
linear phase of the tilt) taken out, and propagated with the shifted band-limited angular spectrum
onto the window around the chief ray (``propagate.asm_transfer_shifted``): the FFT grid holds the
light that can reach the window, the aperture plus the window and a guard measured from the chief
ray (``sampling.plan_field_asm``), so the cost does not grow with α. A radial lens's field point
on the +x axis (ψ = 0, every field PSF set's) keeps the mirror symmetry y → −y: its pupil field
is built on the rows y ≥ 0 alone and propagated by ``propagate.asm_propagate_even_y`` (the same
PSF to rounding, 1.4× faster and 40 % less memory on the paper's lens;
``benchmarks/bench_field_set.py``). α = 0 is the on-axis PSF
(``optics.psf.compute_psf``, bit for bit). ``propagator="rs"`` is the slow reference: the direct
Rayleigh-Sommerfeld sum over the same sites of the full tilted field (carrier included), sharing
none of the above but the pupil's sites.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from metalens_cli import arguments
from metalens_cli.errors import InputError, SamplingError
from metalens_cli.optics import propagate as prop
from metalens_cli.optics import sampling
from metalens_cli.optics.lens import Metalens
from metalens_cli.optics.psf import PsfCost, check_psf_memory, compute_psf, pixel_psf, psf_inputs
from metalens_cli.optics.sensor import GridPixels, grid_pixel_matrix
from metalens_cli.optics.source import (
    field_direction,
    tilted_source_amplitude,
    tilted_source_path,
    tilted_source_phase,
)
from metalens_cli.runtime import Stopwatch

FIELD_PROPAGATORS = ("asm", "rs")
MAX_FIELD_ANGLE = math.radians(60.0)
# field_psf's angle margin as on axis (its default doubles it for small lenses, whose edge-diffracted light the
# single one would cut): 3e-6 relative L2 on the paper's lens, 1.9-2.1× faster (benchmarks/bench_field.py)
ON_AXIS_MARGIN = 0.5


@dataclass
class FieldPsf:
    """PSFs (depths, wavelengths, N, N) of one field point, their window and the chief rays.

    What :func:`field_psf` returns; the window convention is the module docstring's.

    Attributes:
        psf: (D, W, N, N) the fraction of the power through the pupil landing on each pixel.
        wavelengths_m: the W wavelengths (m).
        depths_m: the D source depths (m; inf: a plane wave).
        pixel_pitch_m: sensor pixel pitch (m).
        distance_m: lens-to-sensor distance (m).
        angle_rad: field angle α (rad) from the axis.
        azimuth_rad: azimuth ψ (rad), counter-clockwise from the sensor's +x axis.
        chief_ray_m: (x, y) where the chief ray lands at the middle wavelength (m).
        chief_rays_m: one (x, y) per wavelength (m) (a 2-D lens with a phase gradient at its centre
            bends them differently).
        centre_px: (column, row) of the window's centre pixel from the axis pixel.
        propagator: the propagator used: "asm" or "rs"; on axis, :func:`compute_psf`'s.
        grid: the sampling grid used (its kind and sizes).
        timing_s: seconds per stage.
    """

    psf: torch.Tensor
    wavelengths_m: tuple[float, ...]
    depths_m: tuple[float, ...]
    pixel_pitch_m: float
    distance_m: float
    angle_rad: float
    azimuth_rad: float
    chief_ray_m: tuple[float, float]
    chief_rays_m: tuple[tuple[float, float], ...]
    centre_px: tuple[int, int]
    propagator: str
    grid: dict = field(default_factory=dict)
    timing_s: dict = field(default_factory=dict)


def field_angle(height_m: float, distance_m: float) -> float:
    """Field angle whose chief ray lands at ``height_m`` from the axis, for a lens with a flat phase
    at its centre (every radial one): atan(h/d).

    Args:
        height_m: image height h (m) from the axis, ≥ 0.
        distance_m: lens-to-sensor distance d (m), positive.

    Returns:
        The field angle α (rad), in [0, π/2).

    Examples:
        >>> round(field_angle(1e-3, 1e-3), 6)  # π/4
        0.785398
        >>> field_angle(0.0, 4e-3)
        0.0
    """
    height = arguments.number(height_m, "height_m", lo=0.0, form="a height ≥ 0 (m)")
    return math.atan2(height, arguments.positive(distance_m, "distance_m"))


def _check_field(angle_rad: float, azimuth_rad: float, limit: float = MAX_FIELD_ANGLE) -> None:
    """A field angle in [0, ``limit``] and a finite azimuth (rad)."""
    arguments.number(angle_rad, "angle_rad", lo=0.0, hi=limit, form=f"an angle from 0 to {limit:.6g} rad")
    arguments.number(azimuth_rad, "azimuth_rad", form="a finite azimuth (rad)")


def centre_gradient(lens: Metalens) -> tuple[float, float]:
    """∇φ at the lens centre (rad/m), (∂x, ∂y): 0 for a radial lens; central differences of the
    2-D map's phase 2θ (wrapped to (−π, π]) about the centre site (rows y, columns x)."""
    if lens.radial:
        return 0.0, 0.0
    theta = lens.theta.detach().double().cpu().numpy()
    c = theta.shape[0] // 2
    return (
        float(_phase_step(theta[c, c + 1] - theta[c, c - 1])) / (2 * lens.pitch_m),
        float(_phase_step(theta[c + 1, c] - theta[c - 1, c])) / (2 * lens.pitch_m),
    )


def _phase_step(theta_step):
    """The phase step 2·Δθ (rad) wrapped to (−π, π] (a map given modulo π in θ is fine)."""
    return np.remainder(2 * theta_step + math.pi, 2 * math.pi) - math.pi


def chief_ray(
    lens: Metalens, wavelength_m: float, angle_rad: float, azimuth_rad: float, distance_m: float
) -> tuple[float, float]:
    """Where the ray through the lens centre lands on the sensor, from the lens's phase gradient
    there (module docstring): d·s/√(1 − |s|²), s = sin α·(cos ψ, sin ψ) + (λ/2π)·∇φ(0).

    Args:
        lens: the metalens (radial: flat phase at the centre, so d·tan α).
        wavelength_m: wavelength λ (m).
        angle_rad: field angle α (rad), in [0, π/2).
        azimuth_rad: azimuth ψ (rad), counter-clockwise from the sensor's +x axis.
        distance_m: lens-to-sensor distance d (m).

    Returns:
        (x, y) of the landing point (m) from the optical axis.
    """
    _ray_inputs(lens, wavelength_m, angle_rad, azimuth_rad, distance_m)
    ux, uy = field_direction(angle_rad, azimuth_rad)
    gx, gy = centre_gradient(lens)
    sx, sy = ux + wavelength_m * gx / (2 * math.pi), uy + wavelength_m * gy / (2 * math.pi)
    cos = math.sqrt(max(1 - sx**2 - sy**2, 1e-12))
    return distance_m * sx / cos, distance_m * sy / cos


def _chief_rays(lens: Metalens, lams, angle: float, azimuth: float, d: float, pitch: float):
    """The chief ray's landing per wavelength (m), the middle wavelength's, and the window's centre
    pixel (column, row) from the axis pixel: where that one lands."""
    rays = tuple(chief_ray(lens, lam, angle, azimuth, d) for lam in lams)
    middle = rays[len(rays) // 2]
    return rays, middle, (round(middle[0] / pitch), round(middle[1] / pitch))


def field_psf(
    lens: Metalens,
    grid: sampling.PsfGrid,
    angle_rad: float,
    *,
    azimuth_rad: float = 0.0,
    propagator: str = "asm",
    dtype: torch.dtype = torch.float32,
    device: str | torch.device = "cpu",
    force: bool = False,
    oversample: float = 1.0,
) -> FieldPsf:
    """PSFs of the field point (α = ``angle_rad``, ψ = ``azimuth_rad``) for every (depth,
    wavelength) of ``grid``, in its window centred on the chief ray (module docstring).

    Args:
        lens: the metalens (differentiable in ``lens.theta``).
        grid: wavelengths (m), depths (m, inf: plane wave), window, pixel pitch (m) and
            lens-to-sensor distance (m; None: ``lens.focal_length_m``).
        angle_rad: field angle α from the axis (rad), 0 to 60°.
        azimuth_rad: field azimuth ψ (rad), counter-clockwise from the sensor's +x axis.
        propagator: "asm" (shifted angular spectrum) or "rs" (direct Rayleigh-Sommerfeld, float64,
            small lenses and windows only). α = 0 with asm returns :func:`compute_psf`'s PSFs.
        dtype: real dtype of the computation, float32 or float64.
        device: torch device to compute on.
        force: proceed past the sampling guard.
        oversample: scales every sample density and margin (2 for an accuracy check).

    Returns:
        The PSFs, their axes, the chief rays (m) and the window's centre pixel, the propagator and
        grid used, and the seconds per stage.

    Shape:
        - ``psf``: (D, W, N, N) for D depths, W wavelengths and N = ``grid.pixels``.
    """
    start = time.perf_counter()
    grid = psf_inputs(lens, grid, propagator, dtype, oversample, FIELD_PROPAGATORS)
    lams, zs, d, pixel_pitch_m = list(grid.wavelengths_m), list(grid.depths_m), grid.distance_m, grid.pixel_pitch_m
    _check_field(angle_rad, azimuth_rad)
    device = arguments.device(device)
    check_psf_memory(grid.count, grid.pixels, device)
    rays, middle, centre = _chief_rays(lens, lams, angle_rad, azimuth_rad, d, pixel_pitch_m)
    common = (tuple(lams), tuple(zs), pixel_pitch_m, d, angle_rad, azimuth_rad, middle, rays, centre)
    if angle_rad == 0 and centre == (0, 0) and propagator == "asm":
        axis = compute_psf(lens, grid, dtype=dtype, device=device, force=force, oversample=oversample)
        return FieldPsf(axis.psf, *common, axis.propagator, axis.grid, dict(axis.timing_s))
    f_g = _carrier_free_frequency(lens, lams, zs, angle_rad, azimuth_rad, force)
    run = _field_asm if propagator == "asm" else _field_rs
    psf, info, timing = run(lens, grid, angle_rad, azimuth_rad, centre, f_g, dtype, torch.device(device), oversample)
    timing["total"] = time.perf_counter() - start
    return FieldPsf(psf, *common, propagator, info, timing)


# Rates of the shifted angular spectrum on 2 CPU cores (benchmarks/bench_field.py and bench_field_set.py,
# the paper's lens: one PSF in a 255-px window, and a set's height of 24 wavelengths × 2 depths at 705 px; refitted to
# the grids sized by the light that reaches the window: 0.86-1.0× of one PSF, 0.98-1.02× of a height, 0.95× of a set)
SITE_SECONDS = 2.3e-8  # per meta-atom site: the lens phase on the whole grid, the pupil, the sources
PHASE_SECONDS = 3.2e-8  # per site held, (wavelength, finite depth): the source's phase joined, the field formed
TRANSFER_SECONDS = 2.8e-8  # per element of the kept band: one shifted transfer function (float64 build)
FFT_LENGTH_RATE = 2.6e9  # rows × length × log2(length) per second through the 1-D FFT passes, and what scales so
MEMORY_SLACK = 1.5  # peak RSS over the arrays counted: 1.35-1.55 measured (FFT work buffers, the allocator)


def estimate_field_psf(
    lens: Metalens,
    grid: sampling.PsfGrid,
    angle_rad: float,
    *,
    azimuth_rad: float = 0.0,
    dtype: torch.dtype = torch.float32,
    force: bool = False,
    oversample: float = 1.0,
    backward: bool = False,
) -> PsfCost:
    """What :func:`field_psf` (asm) will cost, from the same plans (a :class:`SamplingError` here
    is the one it would raise).

    Counted: the site grid once, per wavelength one shifted transfer function, per (wavelength,
    depth) the band FFT passes over the pupil and the window's inverse passes (and for a finite
    depth the pupil field formed with its source's phase); ``setup_seconds`` is the site grid's.
    Peak memory: the site arrays (float64 phase, per finite depth its path, the pupil field) and
    the propagation's arrays at the largest band; with ``backward``, twice that and what autograd
    keeps per (wavelength, depth): the pupil field and its float64 phase over the sites, the
    window's field and intensity (the seconds stay the forward pass's). On the +x axis of a radial
    lens half the pupil's rows serve (``_mirror_even``): half the sites held, half the transfer
    function, and half the rows of the first pass each way.

    Args:
        lens: the metalens.
        grid: the PSFs' axes and window, as :func:`field_psf` takes them.
        angle_rad: field angle α (rad), 0 to 60°.
        azimuth_rad: field azimuth ψ (rad).
        dtype: real dtype of the computation, float32 or float64.
        force: proceed past the sampling guard.
        oversample: scales every sample density and margin.
        backward: the PSFs are differentiated in θ.

    Returns:
        Planned peak memory (bytes) and run time (s).
    """
    grid = psf_inputs(lens, grid, dtype=dtype, oversample=oversample)
    lams, zs, d = list(grid.wavelengths_m), list(grid.depths_m), grid.distance_m
    pixels, pixel_pitch_m = grid.pixels, grid.pixel_pitch_m
    _check_field(angle_rad, azimuth_rad)
    f_g = _carrier_free_frequency(lens, lams, zs, angle_rad, azimuth_rad, force)
    m = lens.grid_size
    centre = _chief_rays(lens, lams, angle_rad, azimuth_rad, d, pixel_pitch_m)[2]
    share = 0.5 if _mirror_even(lens, angle_rad, azimuth_rad, centre[1]) else 1.0
    site_count = m * math.ceil(share * m)  # held; the time is the lens phase's over its quadrant and the mirroring
    finite = sum(1 for z in zs if math.isfinite(z))
    seconds, band_max, window = SITE_SECONDS * m**2 + PHASE_SECONDS * site_count * finite * len(lams), 0, 0
    carriers, centre_m = _carriers(lams, angle_rad, azimuth_rad), (centre[0] * pixel_pitch_m, centre[1] * pixel_pitch_m)
    for lam in lams:  # every one given, as field_psf computes them
        asm, k_max = sampling.plan_field_asm(lens, grid, lam, f_g, carriers[lam], centre_m, oversample)
        band, n, up = 2 * k_max + 1, asm.size, asm.upsampled_size
        passes = (share * m + band) * n * math.log2(n) + (share * band + asm.window_samples) * up * math.log2(up)
        seconds += TRANSFER_SECONDS * share * band**2 + len(zs) * passes / FFT_LENGTH_RATE
        band_max, window = max(band_max, band), asm.window_samples
    real = 4 if dtype == torch.float32 else 8
    sites = site_count * (8 + 1 + 2 * real + (real + 8) * finite)  # lens phase, pupil, fields, per finite depth
    # the transfer function and the band's spectrum, the first pass's band × sites, the window's
    # band × samples, three blocks of FFT rows, and the PSFs
    work = 2 * real * (2 * share * band_max**2 + band_max * (m + window)) + 3 * prop.BLOCK_BYTES
    memory = MEMORY_SLACK * (sites + work) + 3 * len(lams) * len(zs) * pixels**2 * real
    if backward:
        memory = 2 * memory + len(lams) * len(zs) * (site_count * (2 * real + 8) + window**2 * 3 * real)
    return PsfCost(int(memory), seconds, SITE_SECONDS * m**2)


def _carriers(lams, angle: float, azimuth: float) -> dict[float, tuple[float, float]]:
    """Per wavelength the tilt's carrier (u0, v0) = (sin α·cos ψ, sin α·sin ψ)/λ (cycles/m)."""
    return {lam: tuple(c / lam for c in field_direction(angle, azimuth)) for lam in lams}


def _carrier_free_frequency(lens, lams, zs, angle, azimuth, force) -> float:
    """Largest local frequency (cycles/m) of the pupil field without its carrier: the lens phase's
    (``sampling.lens_frequency``) plus the source residual's, whose gradient is largest at the rim
    (evaluated there on 720 points); refused past the meta-atom grid's Nyquist like on axis."""
    f_lens, _ = sampling.lens_frequency(lens)
    phi = torch.linspace(0, 2 * math.pi, 721, dtype=torch.float64)[:-1]
    x, y = lens.radius_m * torch.cos(phi), lens.radius_m * torch.sin(phi)
    f_source = 0.0
    for z in zs:
        if math.isinf(z):
            continue
        t, r0 = z * math.tan(angle), z / math.cos(angle)
        bx, by = t * math.cos(azimuth), t * math.sin(azimuth)
        r = torch.sqrt((x + bx) ** 2 + (y + by) ** 2 + z**2)
        gx, gy = (x + bx) / r - bx / r0, (y + by) / r - by / r0
        f_source = max(f_source, float(torch.hypot(gx, gy).max()) / min(lams))
    f_max = f_lens + f_source
    nyquist = 1 / (2 * lens.pitch_m)
    if f_max > nyquist and not force:
        raise SamplingError(
            "pitch",
            f"off axis the field leaving the lens reaches {f_max * 1e-3:.4g} cycles/mm without its tilt, but the "
            f"meta-atom pitch {lens.pitch_m:g} m resolves only {nyquist * 1e-3:.4g} cycles/mm",
            "a finer pitch, a shallower lens phase or a more distant source",
            forceable=True,
        )
    return 2.0 ** (math.ceil(16 * math.log2(max(f_max, 1.0))) / 16)


def _site_grid(lens: Metalens, device, half: bool = False) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Lens phase (float64, rad) on the whole M × M site grid and the sites' x (columns), y (rows)
    (m); ``half`` (radial lens): the rows y ≥ 0 alone, (M//2 + 1, M)."""
    if lens.radial:
        quadrant, _ = lens.grid_phase(torch.float64, quadrant=True)
        phase = torch.cat([quadrant.flip(-1)[..., :-1], quadrant], dim=-1) if half else prop.mirror_quadrant(quadrant)
    else:
        phase, _ = lens.grid_phase(torch.float64)
    m = phase.shape[-1]
    c = (torch.arange(m, dtype=torch.float64) - m // 2) * lens.pitch_m
    return phase.to(device), c[None, :].to(device), c[-phase.shape[-2] :, None].to(device)


def _mirror_even(lens: Metalens, angle: float, azimuth: float, centre_row: int) -> bool:
    """Whether the pupil field and the transfer function are even in y, so that half the rows
    serve (``propagate.asm_propagate_even_y``): a radial lens, a field point on the +x axis."""
    return lens.radial and angle > 0 and math.sin(azimuth) == 0.0 and centre_row == 0


def _field_asm(lens, psf_grid, angle, azimuth, centre, f_g, dtype, device, oversample):
    lams, zs, pixels, pitch = (
        list(psf_grid.wavelengths_m),
        list(psf_grid.depths_m),
        psf_grid.pixels,
        psf_grid.pixel_pitch_m,
    )
    watch = Stopwatch()
    even = _mirror_even(lens, angle, azimuth, centre[1])
    phase_lens, x, y = _site_grid(lens, device, half=even)
    pupil = torch.hypot(x, y) <= lens.radius_m
    rows = torch.where(y > 0, 2.0, 1.0) if even else torch.ones_like(y)  # each row y > 0 stands for ±y
    centre_m = (centre[0] * pitch, centre[1] * pitch)
    complex_dtype = torch.complex64 if dtype == torch.float32 else torch.complex128
    carriers = _carriers(lams, angle, azimuth)
    grids = {
        lam: sampling.plan_field_asm(lens, psf_grid, lam, f_g, carriers[lam], centre_m, oversample) for lam in lams
    }
    d = psf_grid.distance_m
    grid = grids[lams[0]][0]
    to_pixels = GridPixels.build(grid.window_coords().numpy(), pixels, pitch, device, dtype)
    watch.lap("kernels")
    # per depth, what no wavelength changes: the amplitude, the light through the pupil, and the source's
    # residual path (m; its phase is 2π/λ times it); a plane wave has none, so its field serves every λ
    sources = []
    for z in zs:
        amplitude = (tilted_source_amplitude(x, y, z, angle, azimuth) * pupil).to(dtype)
        power = (amplitude.double().pow(2) * rows).sum() * lens.pitch_m**2
        if math.isinf(z):
            sources.append((torch.polar(amplitude, torch.remainder(phase_lens, 2 * math.pi).to(dtype)), power, None))
        else:
            path = tilted_source_path(x, y, z, angle, azimuth)
            sources.append((amplitude, power, path))
    watch.lap("source")
    out = torch.empty(len(zs), len(lams), pixels, pixels, dtype=dtype, device=device)
    for j, lam in enumerate(lams):
        watch.restart()
        g, k_max = grids[lam]
        transfer = prop.asm_transfer_shifted(g, lam, d, k_max, carriers[lam], centre_m, complex_dtype, device, even)
        watch.lap("kernels")
        for i, (source, power, path) in enumerate(sources):
            if path is None:
                field_g = source
            else:
                phase = torch.add(phase_lens, path, alpha=2 * math.pi / lam).remainder_(2 * math.pi)
                field_g = torch.polar(source, phase.to(dtype))
            propagate = prop.asm_propagate_even_y if even else prop.asm_propagate
            window = propagate(field_g, g, lambda t=transfer: t)
            out[i, j] = pixel_psf(window, to_pixels, power.to(dtype))
        watch.lap("propagate")
    info = {
        "kind": "asm-shifted",
        "mirror_y": even,
        "fft_size": max(g.size for g, _ in grids.values()),
        "band_halfwidth": max(k for _, k in grids.values()),
        "pitch_m": grid.pitch_m,
        "window_samples": grid.window_samples,
        "window_step_m": grid.pitch_m / grid.upsample,
        "carrier_free_frequency_per_m": f_g,
    }
    return out, info, watch.times


def _field_rs(lens, psf_grid, angle, azimuth, centre, f_g, dtype, device, oversample):
    """Midpoint rule over the sites in the pupil (the field is one value per site), output on a grid
    of step 1/(8·ν) around the window centre, ν the full field's highest frequency (tilt included),
    pixel-integrated."""
    lams, zs, d = list(psf_grid.wavelengths_m), list(psf_grid.depths_m), psf_grid.distance_m
    pixels, pitch = psf_grid.pixels, psf_grid.pixel_pitch_m
    watch = Stopwatch()
    phase_lens, x, y = _site_grid(lens, device)
    xx, yy = torch.broadcast_tensors(x, y)
    inside = torch.hypot(xx, yy) <= lens.radius_m
    xs, ys, phase_lens = xx[inside], yy[inside], phase_lens[inside]
    nodes = torch.stack([xs, ys], 1)
    nu = max(sampling.sin_limit(f_g, [lam], 2 * oversample) / lam + math.sin(angle) / lam for lam in lams)
    h = 1 / (8 * nu * oversample)  # finer than the asm window: the reference shares not its interpolation error
    half = math.ceil((pixels // 2 + 0.5) * pitch / h) + 3
    g = torch.arange(-half, half + 1, dtype=torch.float64) * h
    gy, gx = torch.meshgrid(g, g, indexing="ij")
    out_xy = torch.stack([gx.reshape(-1) + centre[0] * pitch, gy.reshape(-1) + centre[1] * pitch], 1).to(device)
    mat = torch.from_numpy(grid_pixel_matrix(g.numpy(), pixels, pitch)).to(device)
    watch.lap("kernels")
    out = []
    for z in zs:
        for lam in lams:
            phase = phase_lens + tilted_source_phase(xs, ys, lam, z, angle, azimuth)
            u = torch.polar(tilted_source_amplitude(xs, ys, z, angle, azimuth), torch.remainder(phase, 2 * math.pi))
            power = (u.abs() ** 2).sum() * lens.pitch_m**2
            field_out = prop.rayleigh_sommerfeld(nodes, u * lens.pitch_m**2, lam, d, out_xy)
            out.append(mat @ field_out.abs().pow(2).reshape(g.numel(), g.numel()) @ mat.T / power)
    watch.lap("propagate")
    grid = {"kind": "rs-grid", "sites": int(nodes.shape[0]), "output_step_m": h, "window_samples": g.numel()}
    return torch.stack(out).reshape(len(zs), len(lams), pixels, pixels).to(dtype), grid, watch.times


def ray_landings(
    lens: Metalens,
    wavelength_m: float,
    angle_rad: float,
    depth_m: float,
    distance_m: float,
    *,
    azimuth_rad: float = 0.0,
    samples: int = 48,
) -> tuple[np.ndarray, np.ndarray]:
    """Geometric rays through a grid of pupil points and where they land on the sensor.

    Each ray leaves the lens in the direction the incoming light (from the field point (α, ψ) at
    ``depth_m``) is bent to by the lens's phase gradient, s = s_in + (λ/2π)·∇φ (local grating
    equation), and travels d·s/√(1 − |s|²) sideways; rays whose |s| ≥ 1 are evanescent and
    dropped. For sizing windows and the isoplanatic test.

    Args:
        lens: the metalens.
        wavelength_m: wavelength λ (m).
        angle_rad: field angle α (rad), in [0, π/2).
        depth_m: source depth (m), positive; inf: a plane wave.
        distance_m: lens-to-sensor distance d (m).
        azimuth_rad: azimuth ψ (rad), counter-clockwise from the sensor's +x axis.
        samples: the pupil is sampled on a ``samples`` × ``samples`` grid (≥ 2) over its square;
            the points inside the pupil are traced.

    Returns:
        The landings (m) of the R rays kept, and where the chief ray lands (m, :func:`chief_ray`).

    Shape:
        - Output: :math:`(R, 2)` landings (x, y), R ≤ ``samples``²; :math:`(2,)` the chief ray's.
    """
    _ray_inputs(lens, wavelength_m, angle_rad, azimuth_rad, distance_m)
    arguments.positive(depth_m, "depth_m", allow_inf=True)
    arguments.count(samples, "samples", lo=2)
    arguments.fits_in_memory(LANDING_BYTES * samples**2, "samples", f"{samples}² rays")
    a = lens.radius_m
    u = (np.arange(samples) + 0.5) / samples * 2 - 1
    x, y = np.meshgrid(u * a, u * a)
    inside = np.hypot(x, y) <= a
    x, y = x[inside], y[inside]
    gx, gy = _phase_gradient(lens, x, y)
    if math.isinf(depth_m):
        sx0, sy0 = field_direction(angle_rad, azimuth_rad)
        sx, sy = np.full_like(x, sx0), np.full_like(y, sy0)
    else:
        t = depth_m * math.tan(angle_rad)
        bx, by = x + t * math.cos(azimuth_rad), y + t * math.sin(azimuth_rad)
        r = np.sqrt(bx**2 + by**2 + depth_m**2)
        sx, sy = bx / r, by / r
    sx, sy = sx + wavelength_m * gx / (2 * math.pi), sy + wavelength_m * gy / (2 * math.pi)
    keep = sx**2 + sy**2 < 1
    cos = np.sqrt(1 - sx[keep] ** 2 - sy[keep] ** 2)
    landings = np.stack([x[keep] + distance_m * sx[keep] / cos, y[keep] + distance_m * sy[keep] / cos], 1)
    return landings, np.array(chief_ray(lens, wavelength_m, angle_rad, azimuth_rad, distance_m))


LANDING_BYTES = 160  # per pupil sample: its coordinates, directions, phase radii and landings (float64)


def _ray_inputs(lens, wavelength_m, angle_rad, azimuth_rad, distance_m) -> None:
    """A lens, a wavelength and a distance (m), a field angle below 90° and an azimuth (rad)."""
    arguments.instance(lens, "lens", Metalens, "a Metalens")
    arguments.positive(wavelength_m, "wavelength_m")
    arguments.positive(distance_m, "distance_m")
    _check_field(angle_rad, azimuth_rad, limit=math.nextafter(math.pi / 2, 0))


def _phase_gradient(lens: Metalens, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """∇φ (rad/m) at points (x, y): the radial profile's slope (central differences over one pitch,
    the profile being linear between samples) along r̂, or the 2-D map's wrapped differences at
    the nearest site."""
    p = lens.pitch_m
    if lens.radial:
        r = np.hypot(x, y)
        radii = torch.from_numpy(np.concatenate([r + p / 2, np.maximum(r - p / 2, 0.0)]))
        phase = lens.phase_at_radius(radii).detach().double().numpy()
        slope = (phase[: r.size] - phase[r.size :]) / (r + p / 2 - np.maximum(r - p / 2, 0.0))
        safe = np.where(r > 0, r, 1.0)
        return slope * x / safe, slope * y / safe
    theta = lens.theta.detach().double().cpu().numpy()
    m = theta.shape[0]
    col = np.clip(np.rint(x / p).astype(int) + m // 2, 1, m - 2)
    row = np.clip(np.rint(y / p).astype(int) + m // 2, 1, m - 2)
    return (
        _phase_step(theta[row, col + 1] - theta[row, col - 1]) / (2 * p),
        _phase_step(theta[row + 1, col] - theta[row - 1, col]) / (2 * p),
    )


def field_window(lens: Metalens, wavelengths_m, depth_m: float, angle_rad: float, distance_m: float,
                 pixel_pitch_m: float, at_least: int = 1) -> int:  # fmt: skip
    """Odd window (pixels) centred on the chief ray that holds the geometric rays of the field point
    at ``angle_rad`` and ``depth_m`` over the wavelengths (:func:`ray_landings`), with 10 % and 4
    pixels of margin, and no smaller than ``at_least`` (the on-axis rule's window)."""
    reach = max(
        float(np.hypot(*(landing - chief).T).max())
        for landing, chief in (ray_landings(lens, lam, angle_rad, depth_m, distance_m) for lam in wavelengths_m)
    )
    return max(at_least, 2 * math.ceil(1.1 * reach / pixel_pitch_m) + 9)


def rms_spot(landings: np.ndarray) -> float:
    """RMS radius of ray landings about their centroid.

    Args:
        landings: ray landings (x, y) in m (:func:`ray_landings`), R ≥ 1.

    Returns:
        The RMS distance (m) of the landings from their centroid.

    Shape:
        - Input: :math:`(R, 2)`

    Examples:
        >>> rms_spot([[0.0, 0.0], [2e-6, 0.0]])
        1e-06
    """
    landings = np.asarray(arguments.array(landings, "landings", ndim=2, form="ray landings (R, 2) in m"))
    if landings.shape[1] != 2 or landings.shape[0] < 1:
        raise InputError("landings", f"has shape {landings.shape}", "ray landings (R, 2) in m, R ≥ 1")
    return float(np.sqrt(((landings - landings.mean(axis=0)) ** 2).sum(axis=1).mean()))
