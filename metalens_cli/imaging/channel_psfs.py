"""A design's R, G, B PSFs at a near and a far depth, each in the window its light needs: the
channel weights of its spectral sensitivity, the monochromatic PSFs mixed into channels, the
window grown while the light outgrows it (``optics.channel_psf``), and what the windows kept.

Shared by captures on axis (``imaging.pipeline``) and over the field (``imaging.field_psfs``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch

from metalens_cli.imaging.field_formation import DEFAULT_TOLERANCE
from metalens_cli.imaging.formation import canvas_margin
from metalens_cli.optics.two_scale import TwoScale, split_at, window_reach

KEPT_WARNING = 0.99  # warn when a PSF window holds less of the light than this


@dataclass
class ZeroOrder:
    """The zero-order light of a design's captures: ``scale`` ζ_c (3, 1, 1) of the focused signal
    and the unit-sum discs ``near``, ``far`` (1, N, N) (``imaging.camera``, ``optics.zero_order``)."""

    scale: torch.Tensor
    near: torch.Tensor
    far: torch.Tensor


@dataclass
class ChannelPsfs:
    """R, G, B PSFs (torch, (3, N, N), fractions of the aperture power) at the near and far
    depths, each in the window its light needs (``optics.blur``), and what the windows kept."""

    near: torch.Tensor
    far: torch.Tensor
    z_near_m: float
    z_far_m: float
    kept_near: list[float]
    kept_far: list[float]
    coverage: list[float]
    seconds: float
    held: dict = field(default_factory=dict)
    field_psfs: object = None  # imaging.field_psfs.FieldPsfs: captures vary over the field
    field_test: dict | None = None  # the isoplanatic test and the model chosen (capture_psfs)
    transforms: dict = field(default_factory=dict, repr=False)  # sensor (H, W) → (near, far), made once
    field_tolerance: float = DEFAULT_TOLERANCE  # of the field transforms (imaging.field_formation)
    formation_seconds: list = field(default_factory=list, repr=False)  # each capture's (simulate_captures)
    zero_order: ZeroOrder | None = None  # the unconverted light (attach_zero_order)
    two_scale: TwoScale | None = None  # captures use the PSFs as core and halo (optics.two_scale)

    def capture_forms(self) -> tuple:
        """The near and far PSFs as captures use them: as they are, or split into core and halo."""
        if self.two_scale is None:
            return self.near, self.far
        return tuple(split_at(p, self.two_scale) for p in (self.near, self.far))

    @property
    def margin(self) -> int:
        """Canvas margin (pixels) these PSFs need around the sensor."""
        own = max(window_reach(p.shape[-1], self.two_scale) for p in (self.near, self.far))  # no split needed
        if self.zero_order is not None:
            own = max(own, canvas_margin(self.zero_order.near.shape[-1], self.zero_order.far.shape[-1]))
        return own if self.field_psfs is None else max(own, self.field_psfs.margin)

    def report(self) -> dict:
        """JSON-ready windows and kept fractions per depth and channel (and the field model)."""
        return {
            "psf_window_px": {"near": self.near.shape[-1], "far": self.far.shape[-1]},
            "psf_energy": {"near": dict(zip("RGB", self.kept_near)), "far": dict(zip("RGB", self.kept_far))},
            **({"psf_held": self.held} if self.held else {}),
            **({} if self.two_scale is None else {"halo_blocks_px": self._blocks()}),
            **({"field": self.field_test} if self.field_test is not None else {}),
            **({} if self.field_psfs is None else self.field_psfs.report()),
        }

    def _blocks(self) -> dict:
        """Per depth, the halo's block side and the core's (pixels; 1, N: one scale)."""
        return {
            d: dict(zip(("halo", "core"), self.two_scale.at(p.shape[-1])))
            for d, p in (("near", self.near), ("far", self.far))
        }

    def warnings(self) -> list[str]:
        """One line per (depth, channel) whose window kept less than ``KEPT_WARNING`` of the light."""
        return [
            f"{depth} PSF window ({psfs.shape[-1]} px) keeps {k:.3f} of the {c} light (< {KEPT_WARNING})"
            for depth, psfs, kept in (("near", self.near, self.kept_near), ("far", self.far, self.kept_far))
            for c, k in zip("RGB", kept)
            if k < KEPT_WARNING
        ]


def design_sensitivity(design):
    """S^c of a design: its preset's (filter × camera × η), or the default camera without a filter
    and with the design's ``efficiency`` (η = 1 without one) (``imaging.camera.design_factors``)."""
    from metalens_cli.imaging.camera import design_factors
    from metalens_cli.optics.spectra import spectral_sensitivity, wavelength_grid

    grid = wavelength_grid()
    return spectral_sensitivity(grid, *design_factors(design, grid))


def channel_weights(design, wavelengths_m):
    """(3, W) R, G, B quadrature weights of :func:`design_sensitivity` at ``wavelengths_m``."""
    from metalens_cli.optics.spectra import quadrature_weights

    return quadrature_weights(design_sensitivity(design), np.asarray(wavelengths_m, dtype=float))


def channel_psfs(
    design,
    z_near_m: float,
    z_far_m: float,
    wavelengths_m,
    pixel_pitch_m: float,
    *,
    dtype=torch.float32,
    device="cpu",
    window: int | None = None,
    two_scale: TwoScale | None = None,
) -> ChannelPsfs:
    """Monochromatic PSFs at both depths mixed into R, G, B, each depth in the window that holds
    99.9 % of its light on the sensor plane (``optics.channel_psf``), looked for within the
    window its rays need (``optics.blur.psf_window`` over the wavelengths that matter,
    ``spectra.significant``: the rule training uses), grown while the light outgrows it.
    ``window`` forces one N × N window for both (the kept fractions then tell what it loses).
    ``two_scale``: the captures convolve the PSFs as core and halo (``ChannelPsfs.capture_forms``)."""
    from metalens_cli.optics.blur import kept_fraction, psf_window
    from metalens_cli.optics.channel_psf import channel_psf_stack, grow_until_held
    from metalens_cli.optics.psf import compute_psf
    from metalens_cli.optics.sampling import PsfGrid
    from metalens_cli.optics.sensor import larger_window
    from metalens_cli.optics.spectra import mix_channels, significant

    start = time.perf_counter()
    weights = channel_weights(design, wavelengths_m)
    d = design.focal_length_m
    if window:
        result = compute_psf(
            design.lens,
            PsfGrid(list(wavelengths_m), [z_near_m, z_far_m], window, pixel_pitch_m, d),
            propagator="auto",
            dtype=dtype,
            device=device,
        )
        near, far = mix_channels(result.psf, weights.weights)
        kept = [kept_fraction(p).cpu().tolist() for p in (near, far)]
        return ChannelPsfs(
            near,
            far,
            z_near_m,
            z_far_m,
            kept[0],
            kept[1],
            [float(c) for c in weights.coverage],
            time.perf_counter() - start,
            two_scale=two_scale,
        )
    used = list(np.asarray(wavelengths_m)[significant(weights.weights)])
    capacity = [psf_window(design.lens, used, [z], d, pixel_pitch_m) for z in (z_near_m, z_far_m)]
    stack, _ = grow_until_held(
        lambda windows: channel_psf_stack(
            design.lens,
            list(wavelengths_m),
            [z_near_m, z_far_m],
            weights.weights,
            windows,
            pixel_pitch_m,
            d,
            dtype=dtype,
            device=device,
        ),
        capacity,
        lambda windows, outgrown: [larger_window(n) if grow else n for n, grow in zip(windows, outgrown.any(axis=1))],
    )
    near, far = stack.psfs
    held = {depth: dict(zip("RGB", stack.held[i].tolist())) for i, depth in enumerate(("near", "far"))}
    return ChannelPsfs(
        near,
        far,
        z_near_m,
        z_far_m,
        stack.kept[0].tolist(),
        stack.kept[1].tolist(),
        [float(c) for c in weights.coverage],
        time.perf_counter() - start,
        held,
        two_scale=two_scale,
    )
