"""Where a point source's light lands on the sensor plane: geometric blur and PSF windows.

Geometrical optics of the field leaving the lens (SI metres, radians): at a pupil point the local
transverse wavevector is ∇(φ_lens + φ_source), so the ray leaves with direction sines
s = ∇φ·λ/2π and lands at x + d·s/√(1 − |s|²) on the plane at distance d. The farthest landing
point from the axis is the geometric blur radius. For an ideal thin lens of focal length f
(a diffractive lens designed at λd has f_λ = f·λd/λ) and a source at depth z this is the textbook
D·|v − d|/(2v) with v = 1/(1/f_λ − 1/z); here it comes from the lens's own phase, so it holds
for learned designs too.

A window must also hold the diffraction around the geometric light. The Airy pattern of an
aperture of numerical aperture NA leaves 1 − EE(ρ) ≈ 2/(π·k·NA·ρ) of its energy beyond ρ, so
1 % lies beyond ρ ≈ 10·λ/NA: the window adds ``DIFFRACTION_MARGIN``·λ/NA around the blur.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from metalens_cli.optics.lens import Metalens

DIFFRACTION_MARGIN = 20.0  # × λ/NA: twice the Airy pattern's 99 % encircled-energy radius
BLOCK_ROWS = 256  # rows of a 2-D map traced at a time


def _landing(x, y, gx, gy, wavelength_m: float, distance_m: float) -> np.ndarray:
    """Distance from the axis (m) at which the rays leaving (x, y) with phase gradient (gx, gy)
    (rad/m) land; evanescent directions (|s| ≥ 1) give 0 (they carry no power to the sensor)."""
    sx, sy = gx * wavelength_m / (2 * math.pi), gy * wavelength_m / (2 * math.pi)
    s2 = sx**2 + sy**2
    ok = s2 < 1
    scale = distance_m / np.sqrt(np.where(ok, 1 - s2, 1.0))
    return np.where(ok, np.hypot(x + scale * sx, y + scale * sy), 0.0)


def _source_gradient(r, wavelength_m: float, depth_m: float):
    """d(source phase)/dr (rad/m) at radii r: k·r/√(r² + z²); 0 for a plane wave."""
    if math.isinf(depth_m):
        return np.zeros_like(r)
    return 2 * math.pi / wavelength_m * (r / depth_m) / np.sqrt((r / depth_m) ** 2 + 1)  # no z² to overflow


def geometric_blur_radius(lens: Metalens, wavelength_m: float, depth_m: float, distance_m: float) -> float:
    """Largest distance (m) from the axis at which a ray from the pupil lands, for a source at
    ``depth_m`` (math.inf: plane wave) of ``wavelength_m``, on the plane at ``distance_m``."""
    theta = lens.theta.detach().double().cpu().numpy()
    p, a = lens.pitch_m, lens.radius_m
    if lens.radial:
        # θ is linear between samples k·p: one gradient per interval, traced at its midpoint
        r = (np.arange(theta.shape[0] - 1) + 0.5) * p
        grad = 2 * np.diff(theta) / p + _source_gradient(r, wavelength_m, depth_m)
        inside = r <= a
        return float(_landing(r[inside], 0.0, grad[inside], 0.0, wavelength_m, distance_m).max(initial=0.0))
    m = theta.shape[0]
    c = (np.arange(m) - m // 2) * p
    worst = 0.0
    for start in range(1, m - 1, BLOCK_ROWS):
        rows = slice(start, min(start + BLOCK_ROWS, m - 1))
        block = theta[rows.start - 1 : rows.stop + 1]
        # central differences of φ = 2θ, steps wrapped to (−π, π] (a map may be given modulo π)
        gy = _wrap(2 * (block[2:, 1:-1] - block[:-2, 1:-1])) / (2 * p)
        gx = _wrap(2 * (block[1:-1, 2:] - block[1:-1, :-2])) / (2 * p)
        y, x = c[rows][:, None], c[1:-1][None, :]
        r = np.hypot(x, y)
        radial = _source_gradient(r, wavelength_m, depth_m) / np.maximum(r, p * 1e-9)
        rho = _landing(x, y, gx + radial * x, gy + radial * y, wavelength_m, distance_m)
        worst = max(worst, float(np.where(r <= a, rho, 0.0).max(initial=0.0)))
    return worst


def _wrap(step: np.ndarray) -> np.ndarray:
    return np.remainder(step + math.pi, 2 * math.pi) - math.pi


def numerical_aperture(lens: Metalens, distance_m: float) -> float:
    """sin of the half-angle the pupil subtends from the sensor's centre: a/√(a² + d²)."""
    return lens.radius_m / math.hypot(lens.radius_m, distance_m)


def window_radius_m(lens: Metalens, wavelengths_m, depths_m, distance_m: float) -> float:
    """Radius (m) that holds the light of every (λ, z) in the ranges given: geometric blur +
    diffraction margin. Only the extreme wavelengths and depths are traced: a ray's direction sine
    is λ·∇φ_lens/2π + r/√(r² + z²), linear in λ and monotone in z, and its landing point is
    monotone in that sine, so its distance from the axis is largest at an end of each range."""
    na = numerical_aperture(lens, distance_m)
    lams, zs = {min(wavelengths_m), max(wavelengths_m)}, {min(depths_m), max(depths_m)}
    return max(
        geometric_blur_radius(lens, lam, z, distance_m) + DIFFRACTION_MARGIN * lam / na for lam in lams for z in zs
    )


def window_pixels(radius_m: float, pixel_pitch_m: float) -> int:
    """Odd side N of the square window (axis at pixel N//2) whose inscribed disc has ``radius_m``."""
    return 2 * math.ceil(radius_m / pixel_pitch_m - 0.5) + 1


def psf_window(
    lens: Metalens, wavelengths_m, depths_m, distance_m: float, pixel_pitch_m: float, headroom: float = 1.0
) -> int:
    """Window side N (pixels, odd) for the PSFs of ``lens`` at every wavelength and depth given:
    ``window_radius_m`` × ``headroom`` (> 1 for a lens that will change, as in training)."""
    return window_pixels(headroom * window_radius_m(lens, wavelengths_m, depths_m, distance_m), pixel_pitch_m)


def kept_fraction(psf: torch.Tensor) -> torch.Tensor:
    """Sum of each PSF over its window (..., N, N) → (...): the fraction of the power through the
    aperture that the window holds, for PSFs in the units of ``compute_psf``."""
    return psf.detach().sum(dim=(-2, -1))
