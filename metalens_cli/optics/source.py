"""Point sources in front of the lens (z > 0, SI metres): on axis, and at a field point (α, ψ).

The scalar field at lens radius r is exp(ik·R)/R with R = √(r² + z²). We drop the constant phase
k·z and scale the amplitude to 1 on the axis:

    phase(r)     = k·(R − z) = k·r²/(R + z)        (no cancellation: float32-safe from 1 mm to 1 km)
    amplitude(r) = z/R = 1/√(1 + (r/z)²)           (the 1/R fall-off; exact, costs nothing)

z = math.inf is a plane wave: phase 0, amplitude 1.

Off axis, the light from field point (α, ψ) reaches the lens centre travelling in the direction
(sin α·cos ψ, sin α·sin ψ, cos α), ψ counter-clockwise from the sensor's +x axis: a tilted plane
wave for z = ∞, a point at (−z·tan α·cos ψ, −z·tan α·sin ψ, −z) for finite z (its depth measured
along the axis). Phases are relative to the lens centre; the amplitude is R0/R (R0 = z/cos α).
"""

from __future__ import annotations

import math

import torch


def source_phase(r: torch.Tensor, wavelength_m: torch.Tensor | float, depth_m: float) -> torch.Tensor:
    """k·(√(r² + z²) − z) in rad at radii ``r`` (m), computed as k·r²/(z·(√(1 + (r/z)²) + 1)):
    no cancellation for large z, no overflow of z² for any finite z."""
    if math.isinf(depth_m):
        return torch.zeros_like(r)
    k = 2 * math.pi / wavelength_m
    return k * r**2 / (depth_m * (torch.sqrt(1 + (r / depth_m) ** 2) + 1))


def source_amplitude(r: torch.Tensor, depth_m: float) -> torch.Tensor:
    """Relative amplitude z/√(r² + z²) of the spherical wave (1 on axis, 1 for a plane wave)."""
    if math.isinf(depth_m):
        return torch.ones_like(r)
    return torch.rsqrt(1 + (r / depth_m) ** 2)


def source_frequency(r: float, wavelength_m: float, depth_m: float) -> float:
    """Local radial spatial frequency (cycles/m) of the source phase at radius r: sin(angle)/λ."""
    if math.isinf(depth_m):
        return 0.0
    return r / math.hypot(r, depth_m) / wavelength_m


def field_direction(angle_rad: float, azimuth_rad: float) -> tuple[float, float]:
    """Transverse direction cosines (sin α·cos ψ, sin α·sin ψ) of the light from field point (α, ψ)
    as it reaches the lens centre (ψ counter-clockwise from the sensor's +x axis)."""
    s = math.sin(angle_rad)
    return s * math.cos(azimuth_rad), s * math.sin(azimuth_rad)


def _offsets(x: torch.Tensor, y: torch.Tensor, angle_rad: float, azimuth_rad: float, depth_m: float):
    """For the source at (−X, −Y, −z), X, Y = z·tan α·(cos ψ, sin ψ): q = x·X + y·Y, R0 = z/cos α and
    R − R0 = (x² + y² + 2q)/(R + R0), R = √((x + X)² + (y + Y)² + z²): no cancellation."""
    t = math.tan(angle_rad) * depth_m
    q = x * (t * math.cos(azimuth_rad)) + y * (t * math.sin(azimuth_rad))
    r0 = depth_m / math.cos(angle_rad)
    s = x**2 + y**2 + 2 * q
    ratio = torch.sqrt(1 + s / r0**2)  # R/R0
    return q, r0, s / (r0 * (ratio + 1)), ratio


def tilted_source_phase(x, y, wavelength_m: float, depth_m: float, angle_rad: float, azimuth_rad: float):
    """Phase (rad) at lens points (x, y) (m) of the source at field point (α, ψ), relative to the lens
    centre: k·(sin α·cos ψ·x + sin α·sin ψ·y) for a plane wave (z = ∞), k·(R − R0) for a point at
    depth z (module docstring for R, R0). At α = 0 it equals :func:`source_phase`."""
    k = 2 * math.pi / wavelength_m
    if math.isinf(depth_m):
        ux, uy = field_direction(angle_rad, azimuth_rad)
        return k * (ux * x + uy * y)
    return k * _offsets(x, y, angle_rad, azimuth_rad, depth_m)[2]


def tilted_source_path(x, y, depth_m: float, angle_rad: float, azimuth_rad: float):
    """The source's path at lens points (x, y) (m) beyond its carrier: R − R0 − q/R0 =
    ρ²/(R + R0) − q·(R − R0)/((R + R0)·R0) with ρ² = x² + y², free of cancellation; 0 for a plane
    wave (z = ∞). 2π/λ times it is :func:`tilted_source_phase` without its carrier, the linear part
    k·(sin α·cos ψ·x + sin α·sin ψ·y), at every wavelength."""
    if math.isinf(depth_m):
        return torch.zeros_like(x + y)
    q, r0, dr, ratio = _offsets(x, y, angle_rad, azimuth_rad, depth_m)
    # R − R0 − q/R0 = (ρ² + 2q)/(R + R0) − q/R0 = ρ²/(R + R0) − q·(R − R0)/((R + R0)·R0)
    total = r0 * (ratio + 1)  # R + R0
    return (x**2 + y**2) / total - q * dr / (total * r0)


def tilted_source_amplitude(x, y, depth_m: float, angle_rad: float, azimuth_rad: float):
    """Relative amplitude R0/R of the point source at (α, ψ) (1 at the lens centre; 1 for a plane wave)."""
    if math.isinf(depth_m):
        return torch.ones_like(x + y)
    return 1 / _offsets(x, y, angle_rad, azimuth_rad, depth_m)[3]
