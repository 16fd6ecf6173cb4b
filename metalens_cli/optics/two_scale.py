"""A PSF at two samplings: its core at the sensor's pixels, its halo at s × s coarser ones.

A training or evaluation PSF window is as large as its light (1000-1300 px for a learned lens at
the near depth), yet its detail sits in a small core: beyond it lies a broad halo (a defocus
disc, scattered light) that holds much of the window's power and little of its structure.
:class:`TwoScalePsf` keeps the central K × K pixels (the *core*) at the sensor's pitch p and the
whole window at pitch s·p (the *halo*: coarse pixels of s × s sensor pixels, s odd), with the
coarse pixels of the core zeroed, so that the two parts never count the same light twice.

Conventions: the axis at fine pixel K//2 of the core and coarse pixel Nc//2 of the halo; coarse
pixel U covers the fine offsets U·s − s//2 .. U·s + s//2 from the axis; K = k·s with k odd, so the
core is exactly the k × k central coarse pixels. Values are powers per pixel (fine or coarse), in
the units of the PSF they come from. s = 1 is the single-scale PSF (the halo's centre zeroed, its
light in the core). Pure torch, batched, differentiable, any device.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from metalens_cli import arguments
from metalens_cli.errors import InputError
from metalens_cli.optics.window import WINDOW_PER_BLOCK, check_scales

CORE_PIXELS = 65  # the core a halo scale goes with by default (optimize.core_pixels, --halo-scale)


@dataclass(frozen=True)
class TwoScalePsf:
    """Core (..., C, K, K) at the sensor's pitch and halo (..., C, Nc, Nc) at ``scale`` × it,
    the halo's central K/s × K/s pixels zero (module docstring)."""

    core: torch.Tensor
    halo: torch.Tensor
    scale: int

    @property
    def core_pixels(self) -> int:
        """K, the core's side (sensor pixels)."""
        return self.core.shape[-1]

    @property
    def window(self) -> int:
        """The side (sensor pixels, odd) the halo spans: s·Nc, at least K."""
        return max(self.scale * self.halo.shape[-1], self.core_pixels)

    def sum(self) -> torch.Tensor:
        """The power of each PSF (..., C): core plus halo."""
        return self.core.sum(dim=(-2, -1)) + self.halo.sum(dim=(-2, -1))

    def map(self, fn) -> TwoScalePsf:
        """``fn`` applied to core and halo alike (``detach``, ``to``, a normalisation)."""
        return TwoScalePsf(fn(self.core), fn(self.halo), self.scale)

    def fine(self, n: int | None = None) -> torch.Tensor:
        """The central n × n sensor pixels (default: the whole ``window``): each halo pixel's power
        spread evenly over its s × s sensor pixels, the core added. Sums are kept where the window
        holds whole coarse pixels; a window cutting through them keeps its share of their area."""
        n = self.window if n is None else int(n)
        s = self.scale
        spread = self.halo.repeat_interleave(s, dim=-2).repeat_interleave(s, dim=-1) / s**2
        psf = _fit(spread, n)
        lo, k = n // 2, self.core_pixels // 2
        if n >= self.core_pixels:
            core = torch.zeros_like(psf)
            core[..., lo - k : lo + k + 1, lo - k : lo + k + 1] = self.core
            return psf + core
        return psf + _fit(self.core, n)


@dataclass(frozen=True)
class TwoScale:
    """How PSFs are sampled: halo blocks of at most ``scale`` × ``scale`` sensor pixels around a
    core of about ``core_pixels`` at the sensor's pitch, and, for radial lenses, the halo's radial
    samples ``radial_step`` times the core's (the core's intensity is sampled 4× above its Nyquist
    rate, ``sampling.plan_radial``). Each PSF gets the scale its window allows (:meth:`at`): a
    window of N pixels has blocks of at most N/``window_blocks`` (default 200), a guard for small
    windows, whose structure (a near defocus disc of tens of pixels) blocks of 5 would blur; on
    windows of 400-900 px the captures' error depends on s alone (about 2e-4, 6e-4 and 1.4e-3 of
    relative L2 at s = 3, 5, 9; docs/benchmarks.md). ``scale`` 1: one scale, the exact path."""

    scale: int = 1
    core_pixels: int = 1
    radial_step: int = 1
    window_blocks: int = WINDOW_PER_BLOCK

    def __post_init__(self):
        check_scales(self.scale, self.core_pixels)
        arguments.count(self.radial_step, "halo_radial_step", hi=4)

    @property
    def single(self) -> bool:
        """Whether every PSF keeps one scale."""
        return self.scale == 1

    def at(self, window: int) -> tuple[int, int]:
        """(s, K) for a PSF of ``window`` pixels: the largest odd s ≤ ``scale`` and ≤ N/``window_blocks``, and
        the smallest odd multiple of s ≥ ``core_pixels`` (s = 1: one scale)."""
        s = max(1, min(self.scale, int(window // self.window_blocks)))
        s -= 1 - s % 2
        k = -(-self.core_pixels // s)
        return s, s * (k + 1 - k % 2)


def power(psf) -> torch.Tensor:
    """The power of each PSF (..., C) of (..., C, N, N) tensors or a :class:`TwoScalePsf`."""
    return psf.sum() if isinstance(psf, TwoScalePsf) else psf.sum(dim=(-2, -1))


def window_reach(window: int, scales: TwoScale | None = None) -> int:
    """:func:`reach` of a ``window``-pixel PSF sampled as ``scales`` gives it (``TwoScale.at``)."""
    return reach(window, *(scales or TwoScale()).at(window))


def reach(window: int, scale: int = 1, core_pixels: int = 1) -> int:
    """The canvas margin (pixels) a ``window``-pixel PSF needs around the sensor: N//2 at one
    scale; as core and halo, max(K//2, s·(Nc//2 + 2) − 1), the halo's blocks reaching one block
    further for the interpolation and the sensor's last partial block (``imaging.formation``)."""
    if scale == 1:
        return window // 2
    return max(core_pixels // 2, scale * (halo_pixels(window, core_pixels, scale) // 2 + 2) - 1)


def window(psf) -> int:
    """The side (sensor pixels) of a (..., N, N) PSF or the span of a :class:`TwoScalePsf`."""
    return psf.window if isinstance(psf, TwoScalePsf) else psf.shape[-1]


def _fit(psf: torch.Tensor, n: int) -> torch.Tensor:
    """(..., N, N) PSFs cropped or zero-padded to the central n × n (axis at n//2; N, n odd)."""
    size = psf.shape[-1]
    if n <= size:
        lo = size // 2 - n // 2
        return psf[..., lo : lo + n, lo : lo + n]
    pad = n // 2 - size // 2
    return torch.nn.functional.pad(psf, (pad, pad, pad, pad))


def core_mask(halo_pixels: int, core_pixels: int, scale: int, like: torch.Tensor) -> torch.Tensor:
    """(Nc, Nc) ones with the central K/s × K/s coarse pixels zero (the core's), in ``like``'s
    dtype and device."""
    k = core_pixels // scale
    mask = torch.ones(halo_pixels, halo_pixels, dtype=like.dtype, device=like.device)
    lo = halo_pixels // 2 - k // 2
    if k:
        mask[lo : lo + k, lo : lo + k] = 0
    return mask


def halo_pixels(window: int, core_pixels: int, scale: int) -> int:
    """Nc: the fewest coarse pixels (odd) whose span s·Nc covers a ``window``-pixel PSF and the core."""
    need = max(window, core_pixels)
    n = -(-need // scale)
    return n if n % 2 else n + 1


def block_sum(psf: torch.Tensor, scale: int) -> torch.Tensor:
    """(..., N, N) fine PSFs (N odd, axis at N//2) → (..., Nc, Nc) coarse pixels of ``scale`` × ``scale``
    fine ones about the same axis (``halo_pixels``; zero-padded where the window ends)."""
    n = psf.shape[-1]
    m = halo_pixels(n, scale, scale)
    padded = torch.nn.functional.pad(psf, ((m * scale - n) // 2,) * 4)
    return torch.nn.functional.avg_pool2d(padded.reshape(-1, 1, m * scale, m * scale), scale).reshape(
        *psf.shape[:-2], m, m
    ) * (scale * scale)


def split(psf: torch.Tensor, scale: int, core_pixels: int) -> TwoScalePsf:
    """A fine (..., C, N, N) PSF as a :class:`TwoScalePsf` (its core cut out, its halo summed in
    coarse pixels): the same light, exactly, at the coarse sampling the halo is given at. Used
    where the PSF exists at the sensor's pitch anyway (2-D lenses, field points) and as the
    reference of the directly computed halo (``optics.channel_psf``)."""
    check_scales(scale, core_pixels)
    core = _fit(psf, core_pixels)
    halo = block_sum(psf, scale)
    m = max(halo.shape[-1], core_pixels // scale)
    halo = _fit(halo, m)
    return TwoScalePsf(core, halo * core_mask(m, core_pixels, scale, halo), scale)


def split_at(psf: torch.Tensor, scales: TwoScale):
    """``psf`` (..., C, N, N) split at the scale its window allows (``TwoScale.at``), or as it is
    where that is one scale."""
    s, k = scales.at(psf.shape[-1])
    return psf if s == 1 else split(psf, s, k)


def halo_sampling(scale: int, core_pixels: int = CORE_PIXELS) -> TwoScale | None:
    """The sampling of ``--halo-scale`` s: blocks of up to s × s around the odd multiple of s
    nearest above ``core_pixels``; None for s = 1 (one scale)."""
    if scale == 1:
        return None
    if not (isinstance(scale, int) and scale > 1 and scale % 2):
        raise InputError("--halo-scale", f"{scale!r}", "an odd number of pixels per halo block (1: one scale)")
    k = -(-core_pixels // scale)
    return TwoScale(scale, scale * (k + 1 - k % 2))
