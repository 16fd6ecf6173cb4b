"""Geometric-phase (Pancharatnam-Berry) metalens: a map of nanofin rotations θ and its phase.

Conventions, used everywhere in the package:

- Fields are complex amplitudes with time dependence exp(+i(kz − ωt)): a wave travelling towards
  +z gains phase +k·z, a spherical wave diverging from a point gains +k·R.
- θ is the in-plane rotation of a nanofin, measured counter-clockwise from the +x axis to the
  nanofin's width side, in radians. The cross-polarised light leaving the lens carries phase
  φ = 2θ (the sign of circular handedness is fixed so that this holds), the same at every wavelength.
- A converging lens has φ decreasing away from the axis: the hyperbolic lens focusing a plane wave
  of wavelength λd at distance f has φ(r) = −(2π/λd)·(√(r² + f²) − f) ≤ 0.
- The lens lies in the plane z = 0, light travels towards +z, the sensor is at z = distance > 0.
- The meta-atoms sit on a square grid of pitch p with one site on the optical axis. The pupil is a
  circle of diameter D: sites (or points) with r ≤ D/2 transmit, all others are opaque.

Two forms: a radial profile θ(r) sampled at r_k = k·p (k = 0..K), unwrapped and interpolated
linearly in between; or a 2-D map θ[i, j] on the grid, row i along y, column j along x, the axis at
site (M//2, M//2) of an M × M array. All lengths are SI metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from metalens_cli.arguments import instance, positive
from metalens_cli.errors import InputError


@dataclass(frozen=True)
class Metalens:
    """Rotation map θ (rad, 1-D radial or 2-D square), meta-atom pitch and pupil diameter (m).

    Checked when built: θ finite, the lengths positive. The phase imparted is φ = 2θ.

    Attributes:
        theta: fin rotation angles θ (rad): a radial profile θ(r) sampled at r = k·pitch (1-D), or a
            square M × M map whose centre site (M//2, M//2) is the axis (2-D). Differentiable.
        pitch_m: meta-atom pitch (m).
        aperture_m: pupil diameter D (m).
        focal_length_m: the design distance to the sensor (m) when known (hyperbolic builder), else
            None.

    Shape:
        - ``theta``: :math:`(K,)` radial, or :math:`(M, M)`.
    """

    theta: torch.Tensor
    pitch_m: float
    aperture_m: float
    focal_length_m: float | None = None

    def __post_init__(self) -> None:
        """θ a finite 1-D or 2-D tensor; pitch, aperture and focal length positive lengths."""
        instance(self.theta, "theta", torch.Tensor, "a 1-D or 2-D tensor of rotation angles (rad)")
        if self.theta.ndim not in (1, 2):
            raise InputError("theta", f"is {self.theta.ndim}-D", "a radial profile (1-D) or a square map (2-D)")
        with torch.no_grad():
            if not bool(torch.isfinite(self.theta).all()):
                raise InputError("theta", "holds NaN or infinite angles", "finite angles (rad)")
        positive(self.pitch_m, "pitch_m")
        positive(self.aperture_m, "aperture_m")
        if self.focal_length_m is not None:
            positive(self.focal_length_m, "focal_length_m")

    @property
    def radial(self) -> bool:
        """True when θ is a radial profile θ(r)."""
        return self.theta.ndim == 1

    @property
    def radius_m(self) -> float:
        """Pupil radius D/2 (m)."""
        return self.aperture_m / 2

    @property
    def grid_size(self) -> int:
        """M of the M × M meta-atom grid (for a radial lens: the smallest odd M holding the pupil)."""
        if self.radial:
            return 2 * math.floor(self.radius_m / self.pitch_m + 1e-9) + 1
        return self.theta.shape[0]

    def phase_at_radius(self, r: torch.Tensor) -> torch.Tensor:
        """φ = 2θ at radii ``r`` (m) from the radial profile, linear between samples (rad).

        Radii beyond the last sample take the last value (they lie outside the pupil).
        Differentiable with respect to θ.
        """
        if not self.radial:
            raise InputError("design", "a 2-D rotation map has no radial profile", "a radial lens")
        theta = self.theta.to(r.dtype)
        pos = (r / self.pitch_m).clamp(0, theta.shape[0] - 1)
        k0 = pos.floor().long().clamp(max=theta.shape[0] - 2)
        t = pos - k0
        return 2 * (theta[k0] * (1 - t) + theta[k0 + 1] * t)

    def grid_phase(
        self, dtype: torch.dtype = torch.float64, quadrant: bool = False
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """φ (rad) and the radius r (m) of every site of the M × M meta-atom grid, axis at site
        (M//2, M//2); the pupil is r ≤ D/2. A radial lens is sampled at each site's radius;
        ``quadrant`` (radial lens only) returns the sites at offsets i, j ≥ 0 only."""
        m = self.grid_size
        first = m // 2 if quadrant else 0
        coords = (torch.arange(first, m, dtype=dtype) - m // 2) * self.pitch_m
        r = torch.hypot(coords[:, None], coords[None, :])
        if self.radial:
            return self.phase_at_radius(r), r
        if quadrant:
            raise InputError("design", "a 2-D rotation map has no symmetric quadrant", "a radial lens")
        return 2 * self.theta.to(dtype), r


def hyperbolic_phase(r: np.ndarray | torch.Tensor, lambda_d_m: float, focal_length_m: float):
    """φ(r) = −(2π/λd)(√(r² + f²) − f) written as −(2π/λd)·r²/(√(r² + f²) + f) (no cancellation)."""
    sqrt = torch.sqrt if isinstance(r, torch.Tensor) else np.sqrt
    return -(2 * math.pi / lambda_d_m) * r**2 / (sqrt(r**2 + focal_length_m**2) + focal_length_m)


MAX_RADIAL_SITES = 2e7  # meta-atoms across a radial lens (a 7.9 m lens at the paper's 395 nm pitch)
MAX_GRID_SIDE = 32768  # sites per side of a 2-D map (8.6 GB of float64 θ)


def hyperbolic(
    lambda_d_m: float, focal_length_m: float, aperture_m: float, pitch_m: float, *, radial: bool = True
) -> Metalens:
    """Hyperbolic lens focusing a plane wave of wavelength λd at distance f (all in m).

    θ = φ/2 with φ(r) = −(2π/λd)(√(r² + f²) − f): the radial profile sampled at k·pitch up to
    the pupil edge (and a sample or two past it), or the 2-D map on the smallest odd grid holding
    the pupil.

    Args:
        lambda_d_m: design wavelength λd (m).
        focal_length_m: focal length f (m); the lens's ``focal_length_m``.
        aperture_m: pupil diameter D (m).
        pitch_m: meta-atom pitch (m).
        radial: build the 1-D radial profile (True) or the 2-D map (False).

    Returns:
        The :class:`Metalens`, θ in float64.

    Raises:
        InputError: a length not positive, or more meta-atoms across than the limit (2e7 radial,
            32768 per side in 2-D).

    Examples:
        >>> lens = hyperbolic(532e-9, 1e-3, 20e-6, 1e-6)
        >>> lens.radial, tuple(lens.theta.shape), lens.grid_size, lens.focal_length_m
        (True, (12,), 21, 0.001)
        >>> tuple(hyperbolic(532e-9, 1e-3, 20e-6, 1e-6, radial=False).theta.shape)
        (21, 21)
    """
    sizes = {"lambda_d_m": lambda_d_m, "focal_length_m": focal_length_m, "aperture_m": aperture_m, "pitch_m": pitch_m}
    for name, value in sizes.items():
        positive(value, name)
    sites = aperture_m / pitch_m
    if sites > (MAX_RADIAL_SITES if radial else MAX_GRID_SIDE):
        limit = MAX_RADIAL_SITES if radial else MAX_GRID_SIDE
        raise InputError(
            "aperture",
            f"{aperture_m:g} m holds {sites:.3g} meta-atoms of pitch {pitch_m:g} m across",
            f"at most {limit:g} across ({'radial' if radial else '2-D'} lens)",
        )
    if radial:
        k = math.ceil(aperture_m / 2 / pitch_m - 1e-9) + 1
        r = np.arange(k + 1) * pitch_m
    else:
        half = math.floor(aperture_m / 2 / pitch_m + 1e-9)
        c = np.arange(-half, half + 1) * pitch_m
        r = np.hypot(c[:, None], c[None, :])
    theta = hyperbolic_phase(r, lambda_d_m, focal_length_m) / 2
    return Metalens(torch.from_numpy(theta), pitch_m, aperture_m, focal_length_m)


def from_array(theta: np.ndarray, pitch_m: float, aperture_m: float, focal_length_m: float | None = None) -> Metalens:
    """Lens from a θ array (rad): 1-D radial samples at k·pitch, or a square 2-D map.

    The 1-D profile must reach the pupil edge (K·pitch ≥ D/2); the 2-D map must hold every site
    within D/2 of its centre site (M//2, M//2). θ must be finite.
    """
    positive(pitch_m, "pitch_m")
    positive(aperture_m, "aperture_m")
    theta = np.asarray(theta, dtype=np.float64)
    if not np.all(np.isfinite(theta)):
        raise InputError("design", "θ contains NaN or infinite values", "finite angles in radians")
    half = math.floor(aperture_m / 2 / pitch_m + 1e-9)
    if theta.ndim == 1:
        need = math.ceil(aperture_m / 2 / pitch_m - 1e-9) + 1
        if theta.shape[0] < max(need, 2):
            raise InputError(
                "design",
                f"radial θ has {theta.shape[0]} samples but pitch "
                f"{pitch_m:g} m and aperture {aperture_m:g} m need {max(need, 2)}",
                "samples at r = k·pitch, k = 0..K with K·pitch ≥ D/2",
            )
    elif theta.ndim == 2:
        m = theta.shape[0]
        if theta.shape[1] != m:
            raise InputError("design", f"2-D θ must be square, got shape {theta.shape}", "M × M")
        if m - 1 - m // 2 < half:
            raise InputError(
                "design",
                f"2-D θ of size {m} cannot hold the pupil: pitch {pitch_m:g} m "
                f"and aperture {aperture_m:g} m need at least {2 * half + 1} sites",
                "an M × M map with the axis at site (M//2, M//2)",
            )
    else:
        raise InputError("design", f"θ must be 1-D or 2-D, got {theta.ndim}-D", "a radial or 2-D map")
    return Metalens(torch.from_numpy(theta), float(pitch_m), float(aperture_m), focal_length_m)
