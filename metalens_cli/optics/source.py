"""On-axis point source at depth z in front of the lens (z > 0, SI metres).

The scalar field at lens radius r is exp(ik·R)/R with R = √(r² + z²). We drop the constant phase
k·z and scale the amplitude to 1 on the axis:

    phase(r)     = k·(R − z) = k·r²/(R + z)        (no cancellation: float32-safe from 1 mm to 1 km)
    amplitude(r) = z/R = 1/√(1 + (r/z)²)           (the 1/R fall-off; exact, costs nothing)

z = math.inf is a plane wave: phase 0, amplitude 1.
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
