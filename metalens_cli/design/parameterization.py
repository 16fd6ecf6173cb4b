"""What the optimiser learns: the rotation map θ as a radial profile or a 2-D map.

- ``RadialTheta``: θ(r_k) at r_k = k·p (p: meta-atom pitch), k = 0..K, the lens's own radial form
  (``Metalens.theta`` 1-D): one parameter per meta-atom ring, or G design samples spread evenly
  over r_0..r_K and interpolated linearly to the rings (G < K + 1: a smoother, cheaper design).
- ``SplineTheta`` (``theta_basis = "spline"``): the initial radial profile plus a smooth
  deviation, a cubic B-spline with G coefficients on uniform knots in (r/r_K)² (smooth at the
  axis; knots closest where Fresnel zones are, at the rim). Adam moves every sample of a
  ``RadialTheta`` by about its learning rate each step, independently: a ±0.1 rad step between
  samples 8 rings apart tilts rays by ~0.01 rad and moves them ~20 pixels at f = 4 mm, so the
  light spreads within a few steps (docs/training.md); the spline's steps are smooth.
- ``GridTheta``: θ on a G × G design grid spanning the M × M meta-atom grid (axis at the centre
  site of both), bilinearly upsampled to the meta-atom grid (G = M: one parameter per site).

Both are ``torch.nn.Module``s whose ``lens()`` builds a differentiable :class:`Metalens`;
θ in radians, lengths in SI metres. Initialisation: ``hyperbolic`` (the lens focusing λd at f)
or ``random`` (a seeded smooth random aspheric profile, see :func:`random_radial_theta`).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from metalens_cli.errors import InputError
from metalens_cli.optics.lens import Metalens, hyperbolic_phase

RANDOM_ORDER = 4  # polynomial order in (r/a)² of the random initial profile


class _Theta(torch.nn.Module):
    """θ design samples (rad) as one parameter, upsampled to the lens's rings or sites by ``_upsample``."""

    def __init__(self, theta: np.ndarray, size: int, pitch_m: float, aperture_m: float, focal_length_m: float):
        super().__init__()
        self.theta = torch.nn.Parameter(torch.as_tensor(np.asarray(theta), dtype=torch.float64))
        self.size = size
        self.pitch_m, self.aperture_m, self.focal_length_m = pitch_m, aperture_m, focal_length_m

    def full_theta(self) -> torch.Tensor:
        """θ on the lens's own sampling: K + 1 rings (radial) or M × M sites (2-D)."""
        if self.theta.shape[-1] == self.size:
            return self.theta
        return self._upsample()

    def lens(self) -> Metalens:
        return Metalens(self.full_theta(), self.pitch_m, self.aperture_m, self.focal_length_m)


class RadialTheta(_Theta):
    """θ at G design samples spanning the rings r_0..r_K, linear in between (G = K + 1: one per ring)."""

    def _upsample(self) -> torch.Tensor:
        return torch.nn.functional.interpolate(
            self.theta[None, None], size=self.size, mode="linear", align_corners=True
        )[0, 0]


class SplineTheta(torch.nn.Module):
    """θ(r_k) = θ0(r_k) + Σ_g c_g·B_g((r_k/r_K)²) on the rings r_k: ``theta`` holds the G spline
    coefficients c (rad, 0 at the start), ``base`` θ0 and ``basis`` B (rings × G) are fixed."""

    def __init__(self, base: np.ndarray, coefficients: int, pitch_m: float, aperture_m: float, focal_length_m: float):
        super().__init__()
        self.register_buffer("base", torch.as_tensor(np.asarray(base), dtype=torch.float64))
        self.register_buffer("basis", torch.from_numpy(spline_basis(base.size, coefficients)))
        self.theta = torch.nn.Parameter(torch.zeros(coefficients, dtype=torch.float64))
        self.pitch_m, self.aperture_m, self.focal_length_m = pitch_m, aperture_m, focal_length_m

    def full_theta(self) -> torch.Tensor:
        """θ (rad) on the K + 1 rings: θ0 + B·c, differentiable in the coefficients c."""
        return self.base + self.basis @ self.theta

    def lens(self) -> Metalens:
        """The :class:`Metalens` of :meth:`full_theta` with this pitch, aperture and focal length (m)."""
        return Metalens(self.full_theta(), self.pitch_m, self.aperture_m, self.focal_length_m)


def spline_basis(rings: int, coefficients: int) -> np.ndarray:
    """(rings × G) cubic B-splines at u = (k/K)², k = 0..K = rings − 1, on G − 3 uniform knot
    intervals of [0, 1] (clamped ends): each column is one basis function, rows sum to 1."""
    from scipy.interpolate import BSpline

    degree = 3
    inner = np.linspace(0.0, 1.0, coefficients - degree + 1)
    knots = np.concatenate([np.zeros(degree), inner, np.ones(degree)])
    u = (np.arange(rings) / (rings - 1)) ** 2
    return BSpline.design_matrix(u, knots, degree).toarray()


class GridTheta(_Theta):
    """θ on a G × G design grid, bilinearly upsampled (corners aligned) to the M × M meta-atom grid."""

    def _upsample(self) -> torch.Tensor:
        up = torch.nn.functional.interpolate(
            self.theta[None, None], size=(self.size,) * 2, mode="bilinear", align_corners=True
        )
        return up[0, 0]


def radial_radii(pitch_m: float, aperture_m: float) -> np.ndarray:
    """r_k = k·p for k = 0..K, K the first index with K·p ≥ D/2 (as ``optics.lens.hyperbolic``)."""
    return np.arange(math.ceil(aperture_m / 2 / pitch_m - 1e-9) + 2) * pitch_m


def random_radial_theta(r: np.ndarray, aperture_m: float, peak_frequency: float, seed: int) -> np.ndarray:
    """A seeded smooth random profile: θ = Σ_{n=1..4} c_n·(r/a)^{2n} with c ~ N(0, 1), scaled so
    that its largest local phase frequency |dφ/dr|/2π over the pupil equals ``peak_frequency``
    (cycles/m; the hyperbolic lens's NA/λd gives a random lens as steep as the baseline)."""
    rng = np.random.default_rng([seed, 99])
    a = aperture_m / 2
    c = rng.standard_normal(RANDOM_ORDER)
    u = np.minimum(r / a, 1.0)
    theta = sum(cn * u ** (2 * (n + 1)) for n, cn in enumerate(c))
    fine = np.linspace(0, 1, 4097)
    slope = np.abs(sum(cn * 2 * (n + 1) * fine ** (2 * n + 1) for n, cn in enumerate(c))).max() / a  # dθ/dr
    return theta * (math.pi * peak_frequency / slope)  # |dφ/dr| = 2|dθ/dr| = 2π·peak


def initial_parameterization(
    parameterization: str,
    init: str,
    lambda_d_m: float,
    focal_length_m: float,
    aperture_m: float,
    pitch_m: float,
    *,
    design_grid: int = 0,
    seed: int = 0,
    basis: str = "samples",
    start: np.ndarray | None = None,
):
    """The module to optimise: ``radial`` or ``2d``, initialised ``hyperbolic`` (λd, f) or ``random``.
    ``design_grid``: radial, the number of design samples (``basis = "samples"``) or spline
    coefficients (``"spline"``) along the radius; 2-D, the side of the design grid; 0 = one
    parameter per meta-atom ring or site (samples only). ``start``: a radial θ (rad) on the lens's
    K + 1 rings r_k = k·pitch to start from instead of ``init`` (a learned lens to fine-tune): the
    spline's base, or interpolated linearly in r to the design samples or sites."""
    if init not in ("hyperbolic", "random"):
        raise InputError("optimize.init", f"unknown initialisation {init!r}", "hyperbolic or random")
    rings = radial_radii(pitch_m, aperture_m)
    if start is not None and np.asarray(start).shape != rings.shape:
        raise InputError(
            "optimize.init_from",
            f"a θ of {np.asarray(start).size} rings for a lens of {rings.size}",
            f"a radial θ on the {rings.size} rings r = k·pitch of this lens (its pitch and aperture)",
        )

    def initial(r: np.ndarray) -> np.ndarray:
        if start is not None:
            return np.interp(r, rings, start)
        if init == "hyperbolic":
            return hyperbolic_phase(r, lambda_d_m, focal_length_m) / 2
        return random_radial_theta(r, aperture_m, na / lambda_d_m, seed)

    if basis not in ("samples", "spline") or (basis == "spline" and parameterization != "radial"):
        raise InputError(
            "optimize.theta_basis", f"{basis!r} for a {parameterization} θ", "samples, or spline for a radial θ"
        )
    na = math.sin(math.atan(aperture_m / 2 / focal_length_m))
    if parameterization == "radial":
        if basis == "spline":
            if not 4 <= design_grid <= rings.size:
                raise InputError(
                    "optimize.design_grid",
                    f"{design_grid} spline coefficients for {rings.size} rings",
                    f"4..{rings.size}",
                )
            return SplineTheta(initial(rings), design_grid, pitch_m, aperture_m, focal_length_m)
        g = rings.size if design_grid in (0, rings.size) else design_grid
        if g < 2 or g > rings.size:
            raise InputError(
                "optimize.design_grid", f"{design_grid} radial samples for {rings.size} rings", f"0 or 2..{rings.size}"
            )
        return RadialTheta(initial(np.linspace(0.0, rings[-1], g)), rings.size, pitch_m, aperture_m, focal_length_m)
    if parameterization != "2d":
        raise InputError("lens.parameterization", f"unknown {parameterization!r}", "radial or 2d")
    half = math.floor(aperture_m / 2 / pitch_m + 1e-9)
    m = 2 * half + 1
    g = m if design_grid in (0, m) else design_grid
    if g < 3 or g > m or g % 2 == 0:
        raise InputError(
            "optimize.design_grid", f"{design_grid} for a {m} × {m} meta-atom grid", f"0 or an odd size 3..{m}"
        )
    c = np.linspace(-half, half, g) * pitch_m
    return GridTheta(initial(np.hypot(c[:, None], c[None, :])), m, pitch_m, aperture_m, focal_length_m)
