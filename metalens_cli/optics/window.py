"""The PSF window convention: an (..., N, N) PSF has its axis at pixel N//2, and a smaller
window of n pixels keeps that axis at pixel n//2 (``optics.sensor`` writes PSFs so). Works on
numpy arrays and torch tensors alike (slicing only), so torch-free callers use it too; and the
check of a two-scale sampling's block and core sides (``optics.two_scale``), which presets make."""

from __future__ import annotations

from metalens_cli import arguments
from metalens_cli.errors import InputError

WINDOW_PER_BLOCK = 200  # a PSF window spans at least this many halo blocks: s ≤ N/200 (optics.two_scale.TwoScale)


def crop_window(psf, n: int):
    """The central n × n pixels (n ≤ N) of (..., N, N) PSFs: axis pixel N//2 becomes n//2.

    Slicing only: a view of ``psf``, numpy array or torch tensor alike, values unchanged.

    Args:
        psf: PSFs, the axis at pixel (N//2, N//2) of the last two axes.
        n: the window's side in pixels, 1 ≤ n ≤ N.

    Returns:
        The central window, the axis at pixel (n//2, n//2).

    Shape:
        - Input: :math:`(..., N, N)`
        - Output: :math:`(..., n, n)`

    Examples:
        >>> import numpy as np
        >>> crop_window(np.arange(25).reshape(5, 5), 3).tolist()
        [[6, 7, 8], [11, 12, 13], [16, 17, 18]]
        >>> crop_window(np.zeros((2, 4, 4)), 3).shape
        (2, 3, 3)
    """
    arguments.shaped(psf, "psf", min_ndim=2, form="PSFs (..., N, N)")  # values as they are: slicing only
    arguments.count(n, "n", hi=psf.shape[-1])
    lo = psf.shape[-1] // 2 - n // 2
    return psf[..., lo : lo + n, lo : lo + n]


def check_scales(scale: int, core_pixels: int, prefix: str = "") -> None:
    """``scale`` s an odd count ≥ 1 and ``core_pixels`` K an odd multiple of it (K = k·s, k odd);
    errors name ``prefix`` + halo_scale or core_pixels."""
    if not (isinstance(scale, int) and scale >= 1 and scale % 2 == 1):
        raise InputError(
            f"{prefix}halo_scale", f"{scale!r}", "an odd number of sensor pixels per halo pixel (1: one scale)"
        )
    if not (isinstance(core_pixels, int) and core_pixels >= scale and core_pixels % (2 * scale) == scale):
        raise InputError(
            f"{prefix}core_pixels",
            f"{core_pixels!r} with a halo scale of {scale}",
            f"an odd multiple of {scale} (K = k·s, k odd)",
        )
