"""Image formation through a split-spectrum lens with a near obstruction (Suppl. Note 4).

    I = α ⊙ (P_near ∗ I_obs) + (1 − α) ⊙ (P_far ∗ I_clean),   α = m ∗ P_near,

channel-wise, where m is the obstruction's coverage (1{I_obs ≠ 0} for a hard obstruction; a
soft edge or a semi-opaque drop gives values in 0..1) and P are the 3-channel (R, G, B) PSFs.

Conventions (every function here is pure torch: batched, differentiable, on any device):

- Images are (..., 3, H, W) linear radiance; masks (..., 1, H, W) or (..., 3, H, W).
- PSFs are (..., 3, N, N) with the optical axis at pixel (N//2, N//2), as written by
  ``compute_psf`` / ``mix_channels``: fractions of the aperture power, so a uniform scene keeps
  its brightness up to the light that falls outside the N × N window (``normalize_psf`` with
  ``mode="window"`` rescales each PSF to sum 1 instead).
- Convolution is linear (zero padding, no wrap-around): the output is the H × W part of the
  full convolution aligned with the input ("same"). The FFT size per axis is the smallest
  2·3·5·7-smooth number ≥ H + ⌈N/2⌉, the least for which circular wrap-around never reaches
  the kept pixels.
- ``psf_spectrum`` precomputes a PSF's transform once for a given image size; pass the
  result wherever a PSF is accepted to reuse it (an optimiser recomputes it each step).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from metalens_cli.errors import InputError
from metalens_cli.optics.propagate import fft_size


def padded_shape(image_hw: tuple[int, int], psf_n: tuple[int, int]) -> tuple[int, int]:
    """FFT size per axis for a linear "same" convolution of an H × W image with an N × N PSF."""
    return tuple(fft_size(h + (n + 1) // 2) for h, n in zip(image_hw, psf_n))


@dataclass(frozen=True)
class PsfSpectrum:
    """rfft2 of a PSF placed for linear convolution of ``image_hw`` images.

    ``spectrum``: (..., C, L0, L1 // 2 + 1) complex; ``fft_shape`` (L0, L1); ``energy``:
    (..., C) sum of the PSF over its window (what a uniform scene keeps).
    """

    spectrum: torch.Tensor
    image_hw: tuple[int, int]
    fft_shape: tuple[int, int]
    energy: torch.Tensor


def normalize_psf(psf: torch.Tensor, mode: str = "aperture") -> torch.Tensor:
    """``aperture``: unchanged (fractions of the aperture power; light outside the window is lost).
    ``window``: each PSF divided by its sum over the window (a uniform scene keeps exactly its
    brightness). Differentiable."""
    if mode == "aperture":
        return psf
    if mode == "window":
        return psf / psf.sum(dim=(-2, -1), keepdim=True).clamp_min(torch.finfo(psf.dtype).tiny)
    raise InputError("psf normalization", f"unknown mode {mode!r}", "aperture or window")


def psf_spectrum(psf: torch.Tensor, image_hw: tuple[int, int]) -> PsfSpectrum:
    """Precompute the transform of ``psf`` (..., C, N0, N1) for images of size ``image_hw``.

    The PSF's axis pixel (N0//2, N1//2) goes to index (0, 0) of the padded array, so the
    convolution neither shifts the image nor wraps around (see the module docstring).
    """
    if psf.ndim < 3:
        raise InputError("psf", f"shape {tuple(psf.shape)}", "(..., C, N, N) PSFs")
    n0, n1 = psf.shape[-2:]
    shape = padded_shape(tuple(image_hw), (n0, n1))
    if n0 > shape[0] or n1 > shape[1]:  # cannot happen with fft_size ≥ H + ⌈N/2⌉ ≥ N, kept as a guard
        raise InputError("psf", "larger than its padded transform", "a PSF window smaller than twice the image")
    padded = psf.new_zeros(*psf.shape[:-2], *shape)
    padded[..., :n0, :n1] = psf
    padded = torch.roll(padded, shifts=(-(n0 // 2), -(n1 // 2)), dims=(-2, -1))
    return PsfSpectrum(torch.fft.rfft2(padded), tuple(image_hw), shape, psf.sum(dim=(-2, -1)))


def _spectrum(psf, image_hw) -> PsfSpectrum:
    if isinstance(psf, PsfSpectrum):
        if psf.image_hw != tuple(image_hw):
            raise InputError("psf", f"spectrum prepared for {psf.image_hw}, image is {tuple(image_hw)}", "psf_spectrum(psf, image size)")
        return psf
    return psf_spectrum(psf, image_hw)


def convolve(image: torch.Tensor, psf) -> torch.Tensor:
    """Linear ("same") convolution of ``image`` (..., C, H, W) with ``psf`` (..., C, N, N) or
    a :class:`PsfSpectrum`; C broadcasts (a 1-channel mask with a 3-channel PSF gives 3)."""
    h, w = image.shape[-2:]
    spec = _spectrum(psf, (h, w))
    return _inverse_kept(torch.fft.rfft2(image, s=spec.fft_shape) * spec.spectrum, spec.fft_shape, h, w)


def _inverse_kept(spectrum: torch.Tensor, fft_shape: tuple[int, int], h: int, w: int) -> torch.Tensor:
    """irfft2 restricted to the kept h × w corner: the row transforms run only for the h kept rows."""
    rows = torch.fft.ifft(spectrum, dim=-2)[..., :h, :]
    return torch.fft.irfft(rows, n=fft_shape[1], dim=-1)[..., :w]


def circular_convolve(image: torch.Tensor, psf: torch.Tensor) -> torch.Tensor:
    """Circular convolution on the image's own grid (wraps around): for comparison only."""
    h, w = image.shape[-2:]
    n0, n1 = psf.shape[-2:]
    padded = psf.new_zeros(*psf.shape[:-2], h, w)
    padded[..., :n0, :n1] = psf
    padded = torch.roll(padded, shifts=(-(n0 // 2), -(n1 // 2)), dims=(-2, -1))
    return torch.fft.irfft2(torch.fft.rfft2(image) * torch.fft.rfft2(padded), s=(h, w))


def alpha_map(mask: torch.Tensor, psf_near, alpha_gain: float | None = None) -> torch.Tensor:
    """α = m ∗ P_near; with ``alpha_gain`` g, the gain-and-clamp variant min(g·α, 1) of Shi et al."""
    alpha = convolve(mask, psf_near)
    if alpha_gain is not None:
        if not alpha_gain > 0:
            raise InputError("--alpha-gain", f"{alpha_gain!r}", "a positive gain")
        alpha = torch.clamp(alpha_gain * alpha, max=1.0)
    return alpha


@dataclass
class Capture:
    """The result of :func:`form_image`: the obstructed capture and its parts, (..., 3, H, W)."""

    image: torch.Tensor
    unobstructed: torch.Tensor
    obstruction: torch.Tensor
    alpha: torch.Tensor


def form_image(
    clean: torch.Tensor,
    obstruction: torch.Tensor,
    mask: torch.Tensor,
    psf_near,
    psf_far,
    alpha_gain: float | None = None,
) -> Capture:
    """I = α ⊙ (P_near ∗ I_obs) + (1 − α) ⊙ (P_far ∗ I_clean), α = m ∗ P_near.

    ``clean`` and ``obstruction`` (..., 3, H, W) linear; ``mask`` m (..., 1 or 3, H, W) in 0..1;
    PSFs (..., 3, N, N) or :class:`PsfSpectrum` (precomputed, reused). Transforms are
    batched: one rfft2 of [I_obs, m] and one of I_clean, one irfft2 of all nine planes.
    """
    h, w = clean.shape[-2:]
    near, far = _spectrum(psf_near, (h, w)), _spectrum(psf_far, (h, w))
    if near.fft_shape != far.fft_shape:
        raise InputError("psf", "near and far PSF windows differ in size", "PSFs of one window size")
    s = near.fft_shape
    channels = obstruction.shape[-3]
    stacked = torch.cat([obstruction, mask.to(obstruction.dtype)], dim=-3)
    f_near = torch.fft.rfft2(stacked, s=s)
    f_far = torch.fft.rfft2(clean, s=s)
    products = torch.cat(
        [f_near[..., :channels, :, :] * near.spectrum, f_near[..., channels:, :, :] * near.spectrum, f_far * far.spectrum], dim=-3
    )
    planes = _inverse_kept(products, s, h, w)
    near_obs, alpha, far_clean = planes.split(channels, dim=-3)
    if alpha_gain is not None:
        if not alpha_gain > 0:
            raise InputError("--alpha-gain", f"{alpha_gain!r}", "a positive gain")
        alpha = torch.clamp(alpha_gain * alpha, max=1.0)
    image = alpha * near_obs + (1 - alpha) * far_clean
    return Capture(image, far_clean, near_obs, alpha)


def add_noise(
    image: torch.Tensor,
    photons: float | None = None,
    read_noise: float = 0.0,
    generator: torch.Generator | int | None = None,
) -> torch.Tensor:
    """Poisson-Gaussian sensor noise, differentiable (Gaussian approximation of shot noise).

    A pixel of value x (1 = full scale) collects x·``photons`` electrons: its noise has
    variance x/photons (shot, x clamped at 0) + ``read_noise``² (read noise, in full-scale
    units). ``photons`` None or 0 means no shot noise. ``generator``: a seed or a
    ``torch.Generator`` on the image's device; the same seed gives the same noise.
    """
    if isinstance(generator, int):
        generator = torch.Generator(device=image.device).manual_seed(generator)
    variance = torch.zeros_like(image)
    if photons:
        if photons < 0:
            raise InputError("--photons", f"{photons!r}", "a positive full-well count")
        variance = image.clamp_min(0) / photons
    if read_noise < 0:
        raise InputError("--read-noise", f"{read_noise!r}", "a non-negative standard deviation")
    variance = variance + read_noise**2
    noise = torch.randn(image.shape, generator=generator, dtype=image.dtype, device=image.device)
    return image + torch.sqrt(variance) * noise


def kept_energy(psf: torch.Tensor) -> list[float]:
    """Per-PSF sums over the window (what a uniform scene keeps), as floats for reports."""
    return [float(v) for v in psf.detach().sum(dim=(-2, -1)).reshape(-1)]

