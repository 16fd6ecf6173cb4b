"""Sensor PSFs of a metalens for on-axis point sources: the entry point of the optics core.

psf[i, j] (shape: depths × wavelengths × N × N) is the fraction of the power passing the pupil
that lands on each pixel, for a source at depths_m[i] (math.inf: plane wave) and wavelength
wavelengths_m[j] (m). Differentiable with respect to ``lens.theta``; runs on the given device.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
import torch
import torch.utils.checkpoint

from metalens_cli import arguments
from metalens_cli.errors import InputError
from metalens_cli.optics import propagate as prop
from metalens_cli.optics import sampling
from metalens_cli.optics.lens import Metalens
from metalens_cli.optics.sensor import GridPixels, grid_pixel_matrix, radial_sensor
from metalens_cli.optics.source import source_amplitude, source_phase
from metalens_cli.runtime import Stopwatch

PROPAGATORS = ("auto", "asm", "radial", "rs")


@dataclass
class PsfResult:
    """PSF stack (depths, wavelengths, N, N), its axes, the grid used and the cost per stage.

    What :func:`compute_psf` and :func:`estimate_psf` return.

    Attributes:
        psf: (D, W, N, N) the fraction of the power passing the pupil that lands on each pixel, for
            a source at ``depths_m[i]`` and wavelength ``wavelengths_m[j]``; the axis at pixel
            (N//2, N//2). Differentiable with respect to ``lens.theta``.
        wavelengths_m: the W wavelengths (m).
        depths_m: the D source depths (m; ``math.inf``: a plane wave).
        pixel_pitch_m: sensor pixel pitch (m).
        distance_m: lens-to-sensor distance (m).
        propagator: the propagator used ("asm", "radial" or "rs").
        grid: the sampling plan used (its kind and sizes).
        timing_s: seconds per stage.
    """

    psf: torch.Tensor
    wavelengths_m: tuple[float, ...]
    depths_m: tuple[float, ...]
    pixel_pitch_m: float
    distance_m: float
    propagator: str
    grid: dict = field(default_factory=dict)
    timing_s: dict = field(default_factory=dict)


def compute_psf(
    lens: Metalens,
    grid: sampling.PsfGrid,
    *,
    propagator: str = "auto",
    dtype: torch.dtype = torch.float32,
    device: str | torch.device = "cpu",
    force: bool = False,
    oversample: float = 1.0,
    plan_wavelengths_m=None,
    plan_depths_m=None,
    plan_frequency: float | None = None,
) -> PsfResult:
    """Sensor PSFs of on-axis point sources for every (depth, wavelength) of ``grid``.

    Args:
        lens: the metalens (differentiable in ``lens.theta``).
        grid: wavelengths (m), depths (m, inf: plane wave), window, pixel pitch (m) and
            lens-to-sensor distance (m; None: ``lens.focal_length_m``).
        propagator: "auto" (radial for a radial lens, else asm), "asm", "radial" or "rs".
        dtype: real dtype of the computation, float32 or float64.
        device: torch device to compute on.
        force: proceed past the sampling guard (``SamplingError``).
        oversample: scales every sample density and margin (2 for an accuracy check).
        plan_wavelengths_m: wavelengths (m) the sampling plan (and the guard) also covers, so that
            calls whose wavelengths vary inside them (an optimiser's draws) share one plan and its
            cached kernels; PSFs are computed at ``grid``'s alone.
        plan_depths_m: depths (m) the plan also covers, likewise.
        plan_frequency: plan for a field frequency (cycles/m) of at least this much, so that a lens
            that changes a little between calls keeps the plan.

    Returns:
        The PSFs (the fraction of the pupil's power on each pixel), their axes, the propagator
        and grid used, and the seconds per stage.

    Shape:
        - ``psf``: (D, W, N, N) for D depths, W wavelengths and N = ``grid.pixels``.
    """
    clock = Stopwatch()
    grid = psf_inputs(lens, grid, propagator, dtype, oversample)
    lams, zs, d, pixels = list(grid.wavelengths_m), list(grid.depths_m), grid.distance_m, grid.pixels
    device = arguments.device(device)
    check_psf_memory(grid.count, pixels, device)
    if propagator == "auto":
        propagator = "radial" if lens.radial else "asm"
    if propagator == "radial" and not lens.radial:
        raise InputError(
            "propagator", "the radial propagator needs a radially symmetric design", "asm or rs for a 2-D rotation map"
        )
    plan_lams = lams + [float(x) for x in np.ravel(plan_wavelengths_m if plan_wavelengths_m is not None else [])]
    plan_zs = zs + [float(x) for x in np.ravel(plan_depths_m if plan_depths_m is not None else [])]
    f_max = max(sampling.check_lens_sampling(lens, plan_lams, plan_zs, force), plan_frequency or 0.0)
    run = {"radial": _radial_psf, "asm": _asm_psf, "rs": _rs_psf}[propagator]
    psf, info = run(lens, grid, f_max, dtype, device, oversample, clock, plan_lams)
    clock.lap("sensor")
    return PsfResult(psf, tuple(lams), tuple(zs), grid.pixel_pitch_m, d, propagator, info, clock.times)


@dataclass(frozen=True)
class PsfCost:
    """Planned peak memory (bytes) and run time (s) of :func:`compute_psf`, from its sampling plan.

    Counted: the PSF stack and its copies (×3), the propagator's largest arrays (Hankel kernel
    and output matrix, the radial sensor operator's build arrays; the padded ASM grid ×2 and the
    meta-atom grid; the summation chunks for rs) and, for time, the dominant work at rates
    measured on 2 cores (``*_RATE``). Measured against peak RSS (tests/optics/test_psf_cost.py):
    within a factor of 2, above rather than below; for refusing jobs that cannot fit, not for
    scheduling."""

    memory_bytes: int
    seconds: float
    setup_seconds: float = 0.0  # of ``seconds``: kernels and sensor operators, cached across calls


MATMUL_RATE = 2e10  # real multiply-adds per second (float32 matrix products, 2 cores)
FFT_RATE = 2e8  # complex points per second through one 2-D FFT pass (×log2 size)
RS_RATE = 1e7  # Rayleigh-Sommerfeld kernel evaluations per second (float64)
SENSOR_RATE = (
    1e6  # (pixel, radial interval) overlap areas per second, radial sensor build (1.7e6-3.7e6 measured, 2 cores)
)
RS_PAIR_BYTES = 800  # working set per (node, output point) pair of one Rayleigh-Sommerfeld chunk
RADIAL_SLACK = 1.3  # the radial path's measured peak varies ±20 % from run to run (threaded builds, allocator)


def estimate_psf(
    lens: Metalens,
    grid: sampling.PsfGrid,
    *,
    propagator: str = "auto",
    dtype: torch.dtype = torch.float32,
    force: bool = False,
    oversample: float = 1.0,
) -> PsfCost:
    """What :func:`compute_psf` with these arguments will cost, from the same plan, before any
    large array exists (a :class:`SamplingError` here is the one it would raise).

    Args:
        lens: the metalens.
        grid: the PSFs' axes and window, as :func:`compute_psf` takes them.
        propagator: "auto", "asm", "radial" or "rs".
        dtype: real dtype of the computation, float32 or float64.
        force: proceed past the sampling guard.
        oversample: scales every sample density and margin.

    Returns:
        Planned peak memory (bytes) and run time (s).
    """
    grid = psf_inputs(lens, grid, propagator, dtype, oversample)
    lams, zs, pixels, pixel_pitch_m = list(grid.wavelengths_m), list(grid.depths_m), grid.pixels, grid.pixel_pitch_m
    propagator = ("radial" if lens.radial else "asm") if propagator == "auto" else propagator
    f_max = sampling.check_lens_sampling(lens, lams, zs, force)
    count, real = len(lams) * len(zs), 4 if dtype == torch.float32 else 8
    out_bytes = psf_stack_bytes(count, pixels)
    octant = (pixels // 2 + 1) * (pixels // 2 + 2) // 2
    if propagator == "radial":
        plan = sampling.plan_radial(lens, grid, f_max, oversample)
        intervals = math.ceil(math.sqrt(2) * pixel_pitch_m / plan.step_m) + 7
        sensor_bytes = 8 * octant * intervals * 4 * 8
        # kept in dtype, built from float64 J0 values one block at a time (arguments, values, scaled)
        matrices = (plan.n_freq * plan.n_nodes + plan.n_radii * plan.n_freq) * real + 3 * 8 * prop.BESSEL_BLOCK
        fields = 4 * plan.n_nodes * count * 2 * real
        memory = RADIAL_SLACK * (out_bytes + sensor_bytes + matrices + fields)
        products = (plan.n_freq * plan.n_nodes + plan.n_radii * plan.n_freq) * count * 2
        setup = octant * intervals / SENSOR_RATE
        return PsfCost(int(memory), products / MATMUL_RATE + setup, setup)
    if propagator == "asm":
        asm = sampling.plan_asm(lens, grid.replace(wavelengths_m=[max(lams)]), f_max, oversample)
        window = 2 * asm.window_half + 1
        memory = out_bytes + 2 * asm.size**2 * 2 * real + lens.grid_size**2 * (real + 8 + 1) + 2 * window**2 * 2 * real
        passes = count * 2 * asm.size**2 * max(math.log2(asm.size), 1)
        return PsfCost(int(memory), passes / FFT_RATE + count * pixels * window**2 * 2 / MATMUL_RATE)
    # rs: sums over the pupil for every output sample, chunked; memory is the PSFs and the nodes
    nu = sampling.frequency_limit(f_max, lams, 2 * oversample)
    if lens.radial:
        step = 1 / (16 * nu * oversample)
        outputs = math.ceil(math.hypot(pixels // 2 + 0.5, pixels // 2 + 0.5) * pixel_pitch_m / step) + 3
        n_r, n_phi = sampling.plan_rs(lens, grid, outputs * step, f_max, oversample)
        nodes = n_r * (n_phi + 1)
    else:
        nodes = math.ceil(math.pi * lens.radius_m**2 / lens.pitch_m**2)
        outputs = (2 * math.ceil((pixels // 2 + 0.5) * pixel_pitch_m * 4 * nu * oversample) + 7) ** 2
    return PsfCost(
        int(out_bytes + RS_PAIR_BYTES * max(nodes, 1 << 22) + 100 * nodes), count * nodes * outputs / RS_RATE
    )


def psf_inputs(
    lens, grid, propagator="auto", dtype=torch.float32, oversample=1.0, propagators=PROPAGATORS
) -> sampling.PsfGrid:
    """The checked arguments of a PSF computation (``metalens_cli.arguments``; the grid checked
    its own fields), and the grid with its lens-to-sensor distance resolved (the lens's focal
    length when ``grid.distance_m`` is None). Errors name the parameter (unit suffix dropped, as
    the CLI's options are named)."""
    arguments.instance(lens, "lens", Metalens, "a Metalens (ml.hyperbolic, ml.resolve_design(...).lens)")
    grid = sampling.psf_grid(grid).resolved(lens)
    if propagator not in propagators:
        raise InputError("propagator", f"unknown propagator {propagator!r}", "|".join(propagators))
    if dtype not in (torch.float32, torch.float64):
        raise InputError("dtype", f"unsupported {dtype}", "float32 or float64")
    arguments.number(oversample, "oversample", lo=0.0, open_lo=True, form="a positive factor")
    return grid


def psf_stack_bytes(count: int, pixels: int) -> int:
    """The PSF stack of ``count`` (depth, wavelength) pairs on ``pixels``² and its copies (×3), float32."""
    return 3 * count * pixels**2 * 4


def check_psf_memory(count: int, pixels: int, device) -> None:
    """Refuse PSF stacks larger than ``device``'s free memory before any array exists."""
    arguments.fits_in_memory(psf_stack_bytes(count, pixels), "pixels", f"{count} PSFs of {pixels}² pixels", device)


def _complex(dtype: torch.dtype) -> torch.dtype:
    return torch.complex64 if dtype == torch.float32 else torch.complex128


def pupil_field(phase_lens: torch.Tensor, r: torch.Tensor, lam: float, z: float, dtype: torch.dtype) -> torch.Tensor:
    """amplitude·exp(i(φ_lens + φ_source)), phases summed and reduced mod 2π in the dtype of
    ``phase_lens`` and ``r``, then cast to ``dtype``."""
    if math.isinf(z):
        phase = torch.remainder(phase_lens, 2 * math.pi).to(dtype)
        return torch.polar(torch.ones_like(phase), phase)
    phase = torch.remainder(phase_lens + source_phase(r, lam, z), 2 * math.pi)
    return torch.polar(source_amplitude(r, z).to(dtype), phase.to(dtype))


def _axes(grid):
    """A resolved grid's wavelengths and depths (lists), distance, pixels and pixel pitch."""
    return list(grid.wavelengths_m), list(grid.depths_m), grid.distance_m, grid.pixels, grid.pixel_pitch_m


def _radial_psf(lens, grid, f_max, dtype, device, oversample, clock, plan_lams):
    lams, zs, d, pixels, pitch = _axes(grid)
    plan = sampling.plan_radial(lens, grid.replace(wavelengths_m=plan_lams), f_max, oversample)
    kernel = prop.hankel_kernel(plan.n_freq, plan.radius_m, lens.radius_m, plan.n_nodes, dtype, device)
    out_matrix = prop.hankel_output_rows(kernel, plan.step_m, plan.n_radii)
    sensor = radial_sensor(plan.step_m, pixels, pitch)
    clock.lap("kernels")
    r = kernel.r.double()
    phase_lens = lens.phase_at_radius(r.to(lens.theta.device)).to(device)
    fields = torch.stack([pupil_field(phase_lens, r, lam, z, dtype) for z in zs for lam in lams], 1)
    power = (kernel.weight[:, None] * fields.abs() ** 2).sum(0)
    sins = torch.tensor([sampling.sin_limit(f_max, [lam], oversample, sampling.RADIAL_MARGIN) for lam in lams])
    transfer = prop.radial_transfer(kernel, torch.tensor(lams, dtype=torch.float64), d, sins).repeat(1, len(zs))
    clock.lap("source")
    out = prop.radial_propagate(fields, kernel, transfer, out_matrix)
    clock.lap("propagate")
    psf = sensor.apply(out.abs() ** 2) / power[:, None, None]
    info = {
        "kind": "radial",
        "support_radius_m": plan.radius_m,
        "hankel_samples": plan.n_freq,
        "pupil_nodes": plan.n_nodes,
        "sin_limit": plan.sin_limit,
        "output_step_m": plan.step_m,
        "output_radii": plan.n_radii,
    }
    return psf.reshape(len(zs), len(lams), pixels, pixels), info


def _asm_psf(lens, psf_grid, f_max, dtype, device, oversample, clock, _):
    """One PSF at a time, wavelength by wavelength so that each transfer function is built once
    and shared by the depths. Each wavelength gets its own padded grid: the wrap-free side grows
    with the steepest ray, λ·f_max, so blue light needs about half the area of red.

    When θ needs a gradient, the propagation's gradient is the adjoint propagation, which needs
    nothing saved (the transfer function is fetched again); the element-wise steps before and
    after it are checkpointed, so between the passes each PSF holds only its window field
    (w² complex: 185 MB at the paper's size)."""
    lams, zs, d, pixels, pitch = _axes(psf_grid)
    grids = {lam: sampling.plan_asm(lens, psf_grid.replace(wavelengths_m=[lam]), f_max, oversample) for lam in lams}
    cache = prop.TransferCache()
    # float32 phase: ≤ 3e-4 rad error at 2300 rad; radial lens: one quadrant, then mirrored
    phase_lens, r = lens.grid_phase(dtype, quadrant=lens.radial)
    phase_lens, r = phase_lens.to(device), r.to(device)
    mask = r <= lens.radius_m
    grid = grids[lams[0]]  # the output window (pitch/upsample, half-width) is the same for every λ
    to_pixels = GridPixels.build(grid.window_coords().numpy(), pixels, pitch, device, dtype)
    clock.lap("kernels")
    checkpointed = torch.is_grad_enabled() and phase_lens.requires_grad
    out = {}
    for j, lam in enumerate(lams):
        transfer = functools.partial(cache.get, grids[lam], lam, d, _complex(dtype), device)
        for i, z in enumerate(zs):
            field, power = _call(
                checkpointed, _masked_field, phase_lens, r, mask, lam, z, dtype, lens.radial, lens.pitch_m
            )
            window = prop.asm_propagate(field, grids[lam], transfer)
            out[i, j] = _call(checkpointed, pixel_psf, window, to_pixels, power)
            clock.lap("propagate")
    info = {
        "kind": "asm",
        "fft_size": max(g.size for g in grids.values()),
        "pitch_m": grid.pitch_m,
        "input_size": grid.input_size,
        "window_samples": grid.window_samples,
        "window_step_m": grid.pitch_m / grid.upsample,
        "checkpointed": checkpointed,
    }
    psf = torch.stack([out[i, j] for i in range(len(zs)) for j in range(len(lams))])
    return psf.reshape(len(zs), len(lams), pixels, pixels), info


def _call(checkpointed: bool, fn, *args):
    """fn(*args), activation-checkpointed when asked (recomputed in the backward pass)."""
    return torch.utils.checkpoint.checkpoint(fn, *args, use_reentrant=False) if checkpointed else fn(*args)


def _masked_field(phase_lens, r, mask, lam, z, dtype, radial, site_pitch_m):
    """The pupil field at (λ, z) on the whole meta-atom grid, and Σ|field|²·p² (the power it carries)."""
    field = pupil_field(phase_lens, r, lam, z, dtype) * mask
    field = prop.mirror_quadrant(field) if radial else field
    return field, field.abs().pow(2).sum() * site_pitch_m**2


def pixel_psf(window: torch.Tensor, to_pixels, power: torch.Tensor) -> torch.Tensor:
    """The window field's intensity |U|² (as re² + im²: no square root, 1.7× faster than |U|
    squared on a 6611² window) integrated over the sensor pixels by ``to_pixels``, over the pupil
    power."""
    return to_pixels(window.real.square() + window.imag.square()) / power


def _rs_psf(lens, grid, f_max, dtype, device, oversample, clock, _):
    """Direct Rayleigh-Sommerfeld reference in float64 (slow; small windows)."""
    if lens.radial:
        return _rs_radial(lens, grid, f_max, device, oversample, clock)
    return _rs_grid(lens, grid, f_max, device, oversample, clock)


def _rs_radial(lens, psf_grid, f_max, device, oversample, clock):
    lams, zs, d, pixels, pitch = _axes(psf_grid)
    # twice as fine as the radial path, so that the reference does not share its interpolation error
    step = 1 / (16 * sampling.frequency_limit(f_max, lams, 2 * oversample) * oversample)
    sensor = radial_sensor(step, pixels, pitch)
    radii = torch.arange(sensor.n_radii, dtype=torch.float64, device=device) * step
    n_r, n_phi = sampling.plan_rs(lens, psf_grid, float(radii[-1]), f_max, oversample)
    r, dr = prop.gauss_legendre_panels(lens.radius_m, n_r)
    phi = np.linspace(0.0, math.pi, n_phi + 1)
    w_phi = np.full(n_phi + 1, 2 * math.pi / n_phi)  # both half-planes (mirror symmetry)
    w_phi[[0, -1]] /= 2
    rr = torch.from_numpy(np.repeat(r, n_phi + 1)).to(device)
    pp = torch.from_numpy(np.tile(phi, n_r)).to(device)
    ww = torch.from_numpy(np.repeat(r * dr, n_phi + 1) * np.tile(w_phi, n_r)).to(device)
    nodes = torch.stack([rr * torch.cos(pp), rr * torch.sin(pp)], 1)
    out_xy = torch.stack([radii, torch.zeros_like(radii)], 1)
    r_t = torch.from_numpy(r).to(device)
    phase_lens = lens.phase_at_radius(r_t.to(lens.theta.device)).to(device).double()
    clock.lap("kernels")
    intensities, powers = [], []
    for z in zs:
        for lam in lams:
            f_r = pupil_field(phase_lens, r_t, lam, z, torch.float64)
            powers.append((2 * math.pi * torch.from_numpy(r * dr).to(device) * f_r.abs() ** 2).sum())
            values = f_r.repeat_interleave(n_phi + 1) * ww
            intensities.append(prop.rayleigh_sommerfeld(nodes, values, lam, d, out_xy).abs() ** 2)
            clock.lap("propagate")
    psf = sensor.apply(torch.stack(intensities, 1)) / torch.stack(powers)[:, None, None]
    grid = {
        "kind": "rs-polar",
        "radial_nodes": n_r,
        "azimuth_nodes": n_phi + 1,
        "output_step_m": step,
        "output_radii": sensor.n_radii,
    }
    return psf.reshape(len(zs), len(lams), pixels, pixels), grid


def _rs_grid(lens, psf_grid, f_max, device, oversample, clock):
    """2-D lens: midpoint rule over the meta-atom sites (the field is piecewise constant per
    site), output on a grid of step 1/(4·ν_max·oversample), pixel-integrated."""
    lams, zs, d, pixels, pitch = _axes(psf_grid)
    phase_lens, r = lens.grid_phase()
    mask = r <= lens.radius_m
    m = phase_lens.shape[0]
    c = (torch.arange(m, dtype=torch.float64) - m // 2) * lens.pitch_m
    yy, xx = torch.meshgrid(c, c, indexing="ij")
    nodes = torch.stack([xx[mask], yy[mask]], 1).to(device)
    r, phase_lens = r[mask].to(device), phase_lens[mask].to(device)
    h = 1 / (4 * sampling.frequency_limit(f_max, lams, 2 * oversample) * oversample)
    half = math.ceil((pixels // 2 + 0.5) * pitch / h) + 3
    g = torch.arange(-half, half + 1, dtype=torch.float64) * h
    gy, gx = torch.meshgrid(g, g, indexing="ij")
    out_xy = torch.stack([gx.reshape(-1), gy.reshape(-1)], 1).to(device)
    mat = torch.from_numpy(grid_pixel_matrix(g.numpy(), pixels, pitch)).to(device)
    clock.lap("kernels")
    out = []
    for z in zs:
        for lam in lams:
            f = pupil_field(phase_lens, r, lam, z, torch.float64)
            values = f * lens.pitch_m**2
            power = (f.abs() ** 2).sum() * lens.pitch_m**2
            field_out = prop.rayleigh_sommerfeld(nodes, values, lam, d, out_xy)
            out.append(mat @ field_out.abs().pow(2).reshape(g.numel(), g.numel()) @ mat.T / power)
            clock.lap("propagate")
    grid = {"kind": "rs-grid", "sites": nodes.shape[0], "output_step_m": h, "window_samples": g.numel()}
    return torch.stack(out).reshape(len(zs), len(lams), pixels, pixels), grid
