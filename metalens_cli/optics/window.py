"""The PSF window convention: an (..., N, N) PSF has its axis at pixel N//2, and a smaller
window of n pixels keeps that axis at pixel n//2 (``optics.sensor`` writes PSFs so). Works on
numpy arrays and torch tensors alike (slicing only), so torch-free callers use it too."""

from __future__ import annotations

from metalens_cli import arguments


def crop_window(psf, n: int):
    """The central n × n pixels (n ≤ N) of (..., N, N) PSFs: axis pixel N//2 becomes n//2."""
    arguments.shaped(psf, "psf", min_ndim=2, form="PSFs (..., N, N)")  # values as they are: slicing only
    arguments.count(n, "n", hi=psf.shape[-1])
    lo = psf.shape[-1] // 2 - n // 2
    return psf[..., lo : lo + n, lo : lo + n]
