"""What no phase design can do: raise the spectrally integrated on-axis intensity.

In the Fresnel approximation the on-axis field of a pupil of radius a with a λ-independent
(geometric) phase φ(r), at distance d, is U(λ) = (2πν)·G(ν) with ν = 1/(2λd) and G the Fourier
transform of g(u) = exp(iφ(√u)) over u = r² ∈ [0, a²]. Parseval gives ∫|G|² dν = a², hence
∫ I(λ) dλ = 2π²a²/d for a unit plane wave, whatever φ is: a design can move axial light between
wavelengths (flatten it) but not add to it. docs/training.md uses this to explain why a learned
broadband lens cannot double the hyperbolic lens's mean core energy over the visible.
"""

import math

import numpy as np
import pytest
import torch

from metalens_cli.optics.lens import Metalens, hyperbolic
from metalens_cli.optics.psf import compute_psf

F, D, P = 1e-3, 0.3e-3, 395e-9  # NA 0.15: the axial peak is ~±13 nm wide at 550 nm
PIXEL = 0.2e-6  # a pixel small against the Airy core (1.8 µm): energy ≈ I(0)·pixel²


def axial_integral(lens: Metalens, waves: np.ndarray) -> tuple[float, float]:
    """(∫ I(0, λ) dλ, max I) with I the axis pixel's energy / pixel area, over ``waves`` (m)."""
    energy = np.concatenate(
        [
            compute_psf(lens, list(chunk), [math.inf], 1, PIXEL, distance_m=F, dtype=torch.float64)
            .psf[0, :, 0, 0]
            .numpy()
            for chunk in np.array_split(waves, 4)
        ]
    )
    intensity = energy / PIXEL**2  # per unit pupil power (W/m² per W)
    return float(np.trapezoid(intensity, waves)), float(intensity.max())


def test_spectral_integral_of_axial_intensity_does_not_depend_on_the_phase():
    waves = np.arange(380e-9, 800e-9, 0.25e-9)
    sharp = hyperbolic(550e-9, F, D, P)
    r = np.arange(sharp.theta.numel()) * P
    # the same lens with 3 waves of spherical aberration: its axial light spreads over the band
    spread = Metalens(sharp.theta + torch.from_numpy(3 * math.pi * (r / (D / 2)) ** 4 / 2), P, D, F)
    integral_sharp, peak_sharp = axial_integral(sharp, waves)
    integral_spread, peak_spread = axial_integral(spread, waves)
    closed_form = 2 * math.pi**2 * (D / 2) ** 2 / F / (math.pi * (D / 2) ** 2)  # per unit pupil power
    assert peak_spread < 0.6 * peak_sharp  # the designs differ: one is sharp, the other spread
    # the closed form up to the sinc² tails outside the band (the peak is ~±13 nm wide: ≈ 3 % of
    # the light lies beyond 380-800 nm) and the Fresnel approximation (~NA²/4 ≈ 0.6 %)
    assert integral_sharp == pytest.approx(closed_form, rel=0.05)
    # and the same for both designs, far closer than either is to the closed form: the tails
    # beyond the band are alike, and nothing else depends on φ
    assert integral_spread == pytest.approx(integral_sharp, rel=0.01)
