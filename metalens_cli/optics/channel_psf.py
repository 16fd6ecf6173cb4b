"""R, G, B sensor PSFs, each depth in a window sized by its own light (training and evaluation).

For every depth the monochromatic PSFs are mixed into the channels with the spectral weights
(3, W) *before* the pixel operator: both are linear, so this equals mixing the pixel PSFs
(tests/optics/test_channel_psf.py) at a third of the pixel work for three samples per channel.

Window rule: channel c at depth z gets the smallest odd window N_c whose inscribed disc holds
``energy`` (default 0.999) of the channel's power that reaches the sensor plane; the depth's PSF
is computed in N = max_c N_c. Fractions are of the power through the aperture (``compute_psf``).

- Radial lenses: the encircled energy of I(ρ) before the pixel operator, against the power on
  the sensor plane from Parseval's theorem for the Fourier-Bessel series, Σ_m c_m·|F_m·H_m|²
  (``optics.propagate.HankelKernel``), so light beyond the radii computed counts as missing. The
  sampling plan is made for ``plan_pixels`` (the Hankel kernel cached: built once while calls
  keep the plan), the field is evaluated out to the ``capacity`` window only (cached output
  rows, extended when a capacity grows), and only the chosen window goes through the pixel
  operator (cut from a cached larger one, ``optics.sensor.radial_sensor``).
- Other propagators (2-D lenses) and field points off axis (:func:`field_channel_stack`, the
  window centred on the chief ray): PSFs in the capacity window, the energy in concentric squares
  against the capacity's total (light outside the capacity is not seen).

A channel whose light is not held by the capacity is ``outgrown``: its window is the capacity,
and a caller that can afford it asks again with a larger one.

With ``core_window`` k, the stack also holds each monochromatic PSF's energy in its central
k × k pixels (``cores``), before the mixing: what a loss that asks every wavelength to be sharp
needs (``design.losses``), at the cost of a k × k pixel operator.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from metalens_cli import arguments
from metalens_cli.errors import InputError
from metalens_cli.optics import propagate as prop
from metalens_cli.optics import sampling
from metalens_cli.optics import two_scale as ts
from metalens_cli.optics.blur import window_pixels
from metalens_cli.optics.field import ON_AXIS_MARGIN, field_psf
from metalens_cli.optics.lens import Metalens
from metalens_cli.optics.psf import check_psf_memory, compute_psf, psf_inputs, pupil_field
from metalens_cli.optics.sensor import radial_sensor, radial_sensor_radii
from metalens_cli.optics.two_scale import TwoScale, TwoScalePsf, core_mask, halo_pixels, split_at
from metalens_cli.optics.window import crop_window
from metalens_cli.runtime import Stopwatch

ENCIRCLED_ENERGY = 0.999  # of the power reaching the sensor plane, per depth and channel


@dataclass
class ChannelPsfStack:
    """Per depth: ``psfs[i]`` (3, N_i, N_i) R, G, B in fractions of the aperture power, the
    rule's window per channel ``windows[i]`` (N_i = their max), what the window holds ``kept``
    (depths, 3) and what reaches the sensor plane ``on_sensor`` (depths, 3), both fractions of
    the aperture power; ``outgrown`` (depths, 3): the channel's light passes the capacity;
    ``cores`` (with ``core_window``): per depth, the (W,) energy of each wavelength's PSF in its
    central k × k pixels, fractions of the aperture power, differentiable."""

    psfs: tuple[torch.Tensor, ...]
    windows: tuple[tuple[int, int, int], ...]
    kept: np.ndarray
    on_sensor: np.ndarray
    outgrown: np.ndarray
    capacity: tuple[int, ...]
    grid: dict = field(default_factory=dict)
    timing_s: dict = field(default_factory=dict)
    cores: tuple[torch.Tensor, ...] | None = None

    @property
    def held(self) -> np.ndarray:
        """kept / on_sensor (depths, 3): the fraction of the light on the sensor plane that the
        window holds (≥ the rule's energy unless outgrown)."""
        return self.kept / np.maximum(self.on_sensor, 1e-30)


MAX_WINDOW = 4097  # windows (pixels) stop growing here; the stack's kept fractions then tell what they lose


def grow_until_held(stack_at, capacity, grow):
    """``stack_at(capacity)`` (a :class:`ChannelPsfStack`), computed again in ``grow(capacity,
    outgrown)`` while its light outgrows its windows and they are below ``MAX_WINDOW``; returns
    the last stack and the capacity it was computed in. ``capacity`` is whatever ``stack_at`` and
    ``grow`` take (windows per depth; a training run's ``Windows`` with their plan)."""
    while True:
        stack = stack_at(capacity)
        if not stack.outgrown.any() or max(stack.capacity) >= MAX_WINDOW:
            return stack, capacity
        capacity = grow(capacity, stack.outgrown)


def channel_psf_stack(
    lens: Metalens,
    wavelengths_m,
    depths_m,
    weights,
    capacity,
    pixel_pitch_m: float,
    distance_m: float | None = None,
    *,
    energy: float = ENCIRCLED_ENERGY,
    plan_pixels: int | None = None,
    dtype: torch.dtype = torch.float32,
    device: str | torch.device = "cpu",
    plan_wavelengths_m=None,
    plan_depths_m=None,
    plan_frequency: float | None = None,
    core_window: int | None = None,
    two_scale: TwoScale | None = None,
    radial_margin: float = sampling.RADIAL_MARGIN,
) -> ChannelPsfStack:
    """Channel PSFs at every depth, each in the window its light needs (module docstring).

    Differentiable with respect to ``lens.theta`` and, given as a tensor, ``weights`` (the windows
    themselves are not).

    Args:
        lens: the metalens.
        wavelengths_m: the W wavelengths (m).
        depths_m: source depths (m; ``math.inf``: a plane wave).
        weights: (3, W) spectral weights mixing the W wavelengths into R, G, B (``optics.spectra``).
        capacity: the largest window (odd pixels) to look for light in, one for all depths or one
            per depth.
        pixel_pitch_m: sensor pixel pitch (m).
        distance_m: lens-to-sensor distance (m); None: ``lens.focal_length_m``.
        energy: the fraction of each channel's power on the sensor plane its window must hold, in
            (0, 1).
        plan_pixels: fixes the radial sampling plan (≥ every capacity; default the largest) so that
            calls with changing capacities share its kernels.
        dtype: real dtype of the computation.
        device: torch device.
        plan_wavelengths_m: as in ``compute_psf``.
        plan_depths_m: as in ``compute_psf``.
        plan_frequency: as in ``compute_psf``.
        core_window: odd pixels ≤ every capacity: also each wavelength's energy in that central
            window (``cores``).
        two_scale: the PSFs as ``optics.two_scale.TwoScalePsf`` (core and halo; radial lenses
            compute the halo at its own sampling, others sum it from the sensor's pixels); None:
            (3, N, N) tensors.
        radial_margin: a radial lens's angle margin (sin-angle kept beyond the field's steepest
            ray, ``sampling.plan_radial``): a smaller one shrinks the Hankel products.

    Returns:
        A :class:`ChannelPsfStack`: per depth ``psfs[i]`` (3, N_i, N_i) R, G, B in fractions of the
        aperture power (axis at pixel N_i//2), the rule's windows, ``kept`` and ``on_sensor``
        (depths, 3) fractions of the aperture power, ``outgrown`` (depths, 3) and ``cores``.
    """
    start = time.perf_counter()
    arguments.instance(lens, "lens", Metalens, "a Metalens (ml.hyperbolic, ml.resolve_design(...).lens)")
    grid = psf_inputs(lens, sampling.PsfGrid(wavelengths_m, depths_m, 1, pixel_pitch_m, distance_m), dtype=dtype)
    lams, zs, d = list(grid.wavelengths_m), list(grid.depths_m), grid.distance_m
    device = arguments.device(device)
    caps, mix = _capacities_and_mix(capacity, len(zs), weights, len(lams))
    plan_px = int(plan_pixels or max(caps))
    if not 0 < energy < 1:
        raise InputError("energy", f"{energy!r}", "a fraction between 0 and 1")
    if min(caps) < 1 or plan_px < max(caps):
        raise InputError("capacity", f"windows {caps} with a plan for {plan_px} pixels", "odd windows ≤ the plan's")
    if core_window is not None and not (core_window % 2 == 1 and 1 <= core_window <= min(caps)):
        raise InputError(
            "core_window", f"{core_window!r} for capacities {caps}", "an odd window no larger than every capacity"
        )
    arguments.count(plan_px, "plan_pixels")
    check_psf_memory(len(lams) * len(zs), plan_px, device)
    if lens.radial:
        stack = _radial_stack(
            lens,
            lams,
            zs,
            mix,
            caps,
            plan_px,
            pixel_pitch_m,
            d,
            energy,
            dtype,
            torch.device(device),
            plan_wavelengths_m,
            plan_depths_m,
            plan_frequency,
            core_window,
            two_scale or TwoScale(),
            radial_margin,
        )
    else:
        stack = _grid_stack(
            lens,
            lams,
            zs,
            mix,
            caps,
            pixel_pitch_m,
            d,
            energy,
            dtype,
            device,
            plan_wavelengths_m,
            plan_depths_m,
            plan_frequency,
            core_window,
            two_scale,
        )
    stack.timing_s["total"] = time.perf_counter() - start
    return stack


def _capacities_and_mix(capacity, depths: int, weights, wavelengths: int) -> tuple[list[int], torch.Tensor]:
    """One capacity per depth, and the (3, W) channel weights as float64 (a tensor stays
    differentiable), checked against the number of wavelengths."""
    caps = [int(c) for c in np.broadcast_to(np.asarray(capacity), (depths,))]
    mix = weights.double() if torch.is_tensor(weights) else torch.as_tensor(np.asarray(weights), dtype=torch.float64)
    if mix.shape != (3, wavelengths):
        raise InputError("weights", f"shape {tuple(mix.shape)} for {wavelengths} wavelengths", "(3, W) channel weights")
    return caps, mix


def _radial_stack(
    lens, lams, zs, mix, caps, plan_px, pitch, d, energy, dtype, device, plan_l, plan_z, plan_f, core_window, scales,
    margin,
):  # fmt: skip
    watch = Stopwatch()
    plan_lams = lams + [float(x) for x in np.ravel(plan_l if plan_l is not None else [])]
    plan_zs = zs + [float(x) for x in np.ravel(plan_z if plan_z is not None else [])]
    f_max = max(sampling.check_lens_sampling(lens, plan_lams, plan_zs, False), plan_f or 0.0)
    plan = sampling.plan_radial(lens, sampling.PsfGrid(plan_lams, zs, plan_px, pitch, d), f_max, margin=margin)
    kernel = prop.hankel_kernel(plan.n_freq, plan.radius_m, lens.radius_m, plan.n_nodes, dtype, device)
    # the rule's and the halos' radial samples (one scale: the core's)
    coarse = not scales.single
    step_h = plan.step_m * (scales.radial_step if coarse else 1)
    reach_px = [max(cap, scales.core_pixels) + 2 * scales.scale if coarse else cap for cap in caps]
    n_rows = [radial_sensor_radii(step_h, n, pitch) for n in reach_px]
    rows_h = prop.hankel_output_rows(kernel, step_h, max(n_rows))  # only the rows the capacities reach
    watch.lap("kernels")
    r = kernel.r.double()
    phase_lens = lens.phase_at_radius(r.to(lens.theta.device)).to(device)
    fields = torch.stack([pupil_field(phase_lens, r, lam, z, dtype) for z in zs for lam in lams], 1)
    power = (kernel.weight[:, None] * fields.abs() ** 2).sum(0)
    sins = [sampling.sin_limit(f_max, [lam], 1.0, margin) for lam in lams]
    # frequencies past every wavelength's band limit carry nothing: drop them from both products
    n_freq = int(torch.searchsorted(kernel.nu.double().cpu(), max(s / lam for s, lam in zip(sins, lams)), right=True))
    transfer = prop.radial_transfer(kernel, torch.tensor(lams, dtype=torch.float64), d, torch.tensor(sins))[:n_freq]
    spec = prop.real_matmul(kernel.forward[:n_freq], fields * kernel.weight[:, None]) * transfer.repeat(1, len(zs))
    # Parseval for the Fourier-Bessel series: the power on the sensor plane (within R)
    on_plane = (kernel.coef_out[:n_freq, None] * spec.detach().abs() ** 2).sum(0) / power.detach()
    watch.lap("source")

    def intensity(rows: torch.Tensor, start: int, stop: int) -> torch.Tensor:
        return prop.real_matmul(rows[start:stop, :n_freq], spec).abs() ** 2 / power  # W/m² per W

    w = len(lams)
    mix_d = mix.to(device, dtype)
    mix_n = mix_d.detach()  # the window rule's sums
    # The rule needs I(ρ) out to each capacity's inscribed disc (a window ≤ cap holds its light
    # there or nowhere); each PSF then needs it out to its own window's corner, often further.
    # Every depth's columns go through one product per range of rows (one pass over the matrix).
    inner = [min(rows, math.floor((cap // 2 + 0.5) * pitch / step_h) + 1) for cap, rows in zip(caps, n_rows)]
    mono = intensity(rows_h, 0, max(inner))
    windows, on_sensor, outgrown = [], [], []
    for i, cap in enumerate(caps):
        cols = slice(i * w, (i + 1) * w)
        target = (mix_n.double() @ on_plane[cols].double()).cpu().numpy()  # (3,) on the sensor plane
        rho = np.arange(inner[i]) * step_h
        ring = 2 * math.pi * rho * step_h
        ring[0] = math.pi * (step_h / 2) ** 2
        enclosed = np.cumsum((mono[: inner[i], cols].detach() @ mix_n.T).double().cpu().numpy() * ring[:, None], axis=0)
        chosen, lost = [], []
        for c in range(3):
            reach = np.nonzero(enclosed[:, c] >= energy * target[c])[0]
            wanted = window_pixels(rho[reach[0]], pitch) if reach.size else cap + 2
            lost.append(wanted > cap)
            chosen.append(min(cap, wanted))
        windows.append(tuple(chosen))
        on_sensor.append(target)
        outgrown.append(lost)
    core_op = None if core_window is None else radial_sensor(plan.step_m, core_window, pitch)
    ops, centres = [], []  # per depth: the window's operator (the halo's, at s·p), and (s, the core's)
    for chosen in windows:
        s, k = scales.at(max(chosen))
        if s == 1:
            ops.append(radial_sensor(plan.step_m, max(chosen), pitch))
            centres.append(None)
        else:
            ops.append(radial_sensor(step_h, halo_pixels(max(chosen), k, s), pitch * s))
            centres.append((s, radial_sensor(plan.step_m, k, pitch)))
    halo_ops = [op for op, c in zip(ops, centres) if c is not None]
    fine_ops = [op for op, c in zip(ops, centres) if c is None] + [c[1] for c in centres if c is not None]
    fine_ops += [core_op] if core_op is not None else []
    if step_h == plan.step_m:  # one set of samples serves both
        halo_ops, fine_ops = [], halo_ops + fine_ops
    need = max([op.n_radii for op in halo_ops], default=0)
    if need > mono.shape[0]:
        mono = torch.cat([mono, intensity(rows_h, mono.shape[0], need)])
    fine = mono
    if step_h != plan.step_m:
        need = max([op.n_radii for op in fine_ops], default=0)
        fine = intensity(prop.hankel_output_rows(kernel, plan.step_m, need), 0, None) if need else None
    elif max([op.n_radii for op in fine_ops], default=0) > mono.shape[0]:
        mono = fine = torch.cat([mono, intensity(rows_h, mono.shape[0], max(op.n_radii for op in fine_ops))])
    psfs, kept, cores = [], [], []
    for i, op in enumerate(ops):
        cols = slice(i * w, (i + 1) * w)
        if core_op is not None:
            cores.append(core_op.apply(fine[: core_op.n_radii, cols]).sum(dim=(-2, -1)))
        if centres[i] is None:
            psf = op.apply(fine[: op.n_radii, cols] @ mix_d.T)  # channels mixed first
        else:
            s, centre = centres[i]
            halo = op.apply(mono[: op.n_radii, cols] @ mix_d.T)
            core = centre.apply(fine[: centre.n_radii, cols] @ mix_d.T)
            psf = TwoScalePsf(core, halo * core_mask(op.n_pixels, centre.n_pixels, s, halo), s)
        psfs.append(psf)
        kept.append(ts.power(psf).detach().double().cpu().numpy())
    watch.lap("propagate")
    grid = {
        "kind": "radial",
        "support_radius_m": plan.radius_m,
        "hankel_samples": plan.n_freq,
        "hankel_samples_used": n_freq,
        "pupil_nodes": plan.n_nodes,
        "output_step_m": plan.step_m,
        "plan_pixels": plan_px,
        **({} if scales.single else {"halo_scale": [p.scale if isinstance(p, TwoScalePsf) else 1 for p in psfs]}),
        **({} if scales.single else {"halo_output_step_m": step_h}),
    }
    return ChannelPsfStack(
        tuple(psfs),
        tuple(windows),
        np.array(kept),
        np.array(on_sensor),
        np.array(outgrown, bool),
        tuple(caps),
        grid,
        watch.times,
        tuple(cores) if core_op is not None else None,
    )


def _grid_stack(
    lens, lams, zs, mix, caps, pitch, d, energy, dtype, device, plan_l, plan_z, plan_f, core_window, two_scale
):
    """Any propagator: the PSFs in the largest capacity, mixed, each depth cropped by its light."""
    result = compute_psf(
        lens,
        sampling.PsfGrid(lams, zs, max(caps), pitch, d),
        propagator="auto",
        dtype=dtype,
        device=device,
        plan_wavelengths_m=plan_l,
        plan_depths_m=plan_z,
        plan_frequency=plan_f,
    )
    return _square_stack(result.psf, mix, caps, energy, core_window, result.grid, dict(result.timing_s), two_scale)


def field_channel_stack(
    lens: Metalens,
    wavelengths_m,
    depths_m,
    weights,
    capacity,
    pixel_pitch_m: float,
    angle_rad: float,
    *,
    azimuth_rad: float = 0.0,
    distance_m: float | None = None,
    energy: float = ENCIRCLED_ENERGY,
    dtype: torch.dtype = torch.float32,
    device: str | torch.device = "cpu",
    core_window: int | None = None,
    two_scale: TwoScale | None = None,
) -> ChannelPsfStack:
    """:func:`channel_psf_stack` of the field point (α = ``angle_rad``, ψ = ``azimuth_rad``): the
    monochromatic PSFs of ``optics.field.field_psf`` (on-axis angle margin) in the largest
    capacity, centred on the chief ray, mixed, and each depth cropped to the concentric square
    that holds ``energy`` of what the capacity holds (light outside it is not seen: size the
    capacity with ``optics.field.field_window``). Differentiable in θ and the weights."""
    start = time.perf_counter()
    lams = [float(x) for x in np.ravel(wavelengths_m)]
    zs = [float(x) for x in np.ravel(depths_m)]
    caps, mix = _capacities_and_mix(capacity, len(zs), weights, len(lams))  # checked before the PSFs' cost
    grid = sampling.PsfGrid(lams, zs, max(caps), pixel_pitch_m, distance_m)
    result = field_psf(
        lens, grid, angle_rad, azimuth_rad=azimuth_rad, dtype=dtype, device=device, oversample=ON_AXIS_MARGIN
    )
    stack = _square_stack(result.psf, mix, caps, energy, core_window, result.grid, dict(result.timing_s), two_scale)
    stack.timing_s["total"] = time.perf_counter() - start
    return stack


def _square_stack(mono, mix, caps, energy, core_window, grid, timing, two_scale=None) -> ChannelPsfStack:
    """Monochromatic PSFs (depths, W, N, N) with N ≥ every capacity mixed into R, G, B by ``mix``
    (3, W), each depth cut to its capacity and then to the concentric square holding ``energy``
    of what the capacity holds per channel (never outgrown: light beyond it is not seen); with
    ``two_scale`` beyond one scale, each split into core and halo (``optics.two_scale.split``)."""
    rgb = torch.einsum("zwij,cw->zcij", mono, mix.to(mono.device, mono.dtype))
    psfs, windows, kept, on_sensor, outgrown = [], [], [], [], []
    for i, cap in enumerate(caps):
        psf = crop_window(rgb[i], cap)
        squares = _square_energy(psf.detach().double().cpu().numpy())  # (3, cap//2 + 1)
        total = squares[:, -1]
        chosen = [2 * int(np.argmax(squares[c] >= energy * total[c])) + 1 for c in range(3)]
        psf = crop_window(psf, max(chosen))
        if two_scale is not None:
            psf = split_at(psf, two_scale)
        psfs.append(psf)
        windows.append(tuple(chosen))
        kept.append(
            (psf.sum() if isinstance(psf, TwoScalePsf) else psf.sum(dim=(-2, -1))).detach().double().cpu().numpy()
        )
        on_sensor.append(total)
        outgrown.append([False] * 3)
    cores = (
        None
        if core_window is None
        else tuple(crop_window(mono[i], core_window).sum(dim=(-2, -1)) for i in range(len(caps)))
    )
    return ChannelPsfStack(
        tuple(psfs),
        tuple(windows),
        np.array(kept),
        np.array(on_sensor),
        np.array(outgrown, bool),
        tuple(caps),
        grid,
        timing,
        cores,
    )


def _square_energy(psf: np.ndarray) -> np.ndarray:
    """(C, N, N) odd N → (C, N//2 + 1): the sum over the central (2k + 1)² pixels for k = 0..N//2."""
    n = psf.shape[-1]
    off = np.abs(np.arange(n) - n // 2)
    ring = np.maximum(off[:, None], off[None, :])
    return np.stack([np.cumsum(np.bincount(ring.ravel(), weights=p.ravel(), minlength=n // 2 + 1)) for p in psf])
