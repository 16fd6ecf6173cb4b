"""What no phase design can do, checked by propagation on the paper's lens (docs/training.md,
"What no phase design can do"). Lengths in metres; PSF pixels are fractions of the power through
the aperture (πa² for a unit plane wave), so P₀/p² of a pixel of side p small against the spot is
the axial intensity per unit incident intensity, over πa².

1. On axis, a pupil of radius a with a λ-independent (geometric) phase, |t| = 1, at distance d
   gives U₀ = (kd/i)·∫ t(s)·e^{iks}/s ds over the path length s = √(r² + d²) ∈ [d, s_max]
   (Rayleigh-Sommerfeld, ks ≫ 1). Parseval over k with dλ = 2π·dk/k² cancels the k² in front:
   ∫ I₀ dλ = 4π²d·(1 − d/s_max) whatever the phase, i.e. ∫ P₀/p² dλ = 4πd·(1 − d/s_max)/a². Over
   wavenumber the k² stays: by stationary phase ∫ I₀ dk = 2πd²·∫ k*(s)²/s² ds, k*(s) the
   wavenumber the zone at s focuses on axis, which depends on the design.
2. The identity does not bound the 5 × 5-pixel core: a core lit at the axial intensity at every
   wavelength would hold 0.57 of the light on average over 430-650 nm; lenses hold ~0.04.
3. What does: a ray from radius r, deflected by the lens's fixed phase gradient (sin θ =
   (λ/λ*)·r/s), lands at ρ = r − d·tan θ, so dρ/dλ = r·s²/(d²·λ*) and it stays in the square core
   of half-width h (h / max(|cos ψ|, |sin ψ|) along its azimuth ψ) over Δλ = 2hλ*d²/(r·s²·max(..)).
   Weighted by its share r·dr·dψ/(πa²) of the aperture power: ∫ E dλ = 16·ln(1 + √2)·h·λ*·d·
   arctan(a/d)/(π·a²), for any lens whose rays all focus λ* (λ* varying with r: its weighted mean).
"""

import math

import numpy as np
import pytest
import torch

from metalens_cli.analysis.psf_metrics import central_energy
from metalens_cli.constants import PAPER_FOCAL_LENGTH_M, PAPER_PITCH_M
from metalens_cli.optics import sampling
from metalens_cli.optics.lens import Metalens, hyperbolic
from metalens_cli.optics.psf import compute_psf
from metalens_cli.optics.sampling import PsfGrid

D_M, APERTURE_M, PITCH_M, PIXEL_M = PAPER_FOCAL_LENGTH_M, 2.516e-3, PAPER_PITCH_M, 1.85e-6
A_M = APERTURE_M / 2
S_MAX_M = math.hypot(A_M, D_M)
SPAN_M = S_MAX_M - D_M  # the path lengths a pupil spans: 0.19 mm
POINT_M = 0.03e-6  # a pixel ~40× below the Airy radius: P₀/p² is the axial intensity to ~5e-4
BAND_M = (430e-9, 650e-9)
CORE = 5


def identity_constant() -> float:
    """∫ P₀/p² dλ (m, per unit aperture power) = 4π²d(1 − d/s_max) / (πa²)."""
    return 4 * math.pi * D_M * (1 - D_M / S_MAX_M) / A_M**2


def chirped(centre_m: float, rim_m: float) -> tuple[Metalens, float, float]:
    """A strongly aberrated lens: the zone at path length s focuses on axis the wavenumber
    k*(s) = α + β·s, from 2π/centre_m at the axis to 2π/rim_m at the rim (φ'(s) = −k*(s)).
    Returns the lens, α and β."""
    k1, k2 = 2 * math.pi / centre_m, 2 * math.pi / rim_m
    beta = (k2 - k1) / SPAN_M
    alpha = k1 - beta * D_M
    r = np.arange(hyperbolic(532e-9, D_M, APERTURE_M, PITCH_M).theta.numel()) * PITCH_M
    u = r**2 / (np.sqrt(r**2 + D_M**2) + D_M)  # s − d without cancellation
    phi = -(k1 * u + (k2 - k1) * u**2 / (2 * SPAN_M))
    return Metalens(torch.from_numpy(phi / 2), PITCH_M, APERTURE_M, D_M), alpha, beta


@pytest.fixture(scope="module")
def axial():
    """Axial intensity per unit aperture power of a sharp and an aberrated lens, on a grid uniform
    in k at π/L (L = s_max − d): I₀(k) is the Fourier transform of the autocorrelation of t(s)/s,
    which spans |τ| ≤ L, so the trapezoid rule at this step integrates it without aliasing."""
    k = np.arange(2 * math.pi / 820e-9, 2 * math.pi / 400e-9, math.pi / SPAN_M)  # 495 wavenumbers
    waves = 2 * math.pi / k
    sharp = hyperbolic(532e-9, D_M, APERTURE_M, PITCH_M)
    spread, alpha, beta = chirped(620e-9, 720e-9)  # 22 waves from the 620 nm lens at the rim
    plan = sampling.check_lens_sampling(sharp, list(waves), [math.inf], False)  # one plan for both

    def intensity(lens):
        psf = compute_psf(lens, PsfGrid(waves, [math.inf], 1, POINT_M), dtype=torch.float64, plan_frequency=plan).psf
        return psf[0, :, 0, 0].numpy() / POINT_M**2

    return {"k": k, "sharp": intensity(sharp), "spread": intensity(spread), "alpha": alpha, "beta": beta}


def test_axial_light_over_wavelength_is_the_same_for_any_phase_with_the_non_paraxial_constant(axial):
    k = axial["k"]
    over_wavelength = {name: np.trapezoid(axial[name] * 2 * math.pi / k**2, k) for name in ("sharp", "spread")}
    paraxial = 2 * math.pi**2 * A_M**2 / D_M / (math.pi * A_M**2)
    assert abs(paraxial / identity_constant() - 1) > 0.07  # at NA 0.3 the paraxial constant is 7 % off
    assert axial["sharp"].max() > 30 * axial["spread"].max()  # the designs differ: one sharp, one spread
    # the band's tails (≤ 0.1 %) and the point pixel's size (≤ 0.05 %) are all that is left out
    for value in over_wavelength.values():
        assert value == pytest.approx(identity_constant(), rel=4e-3)
    assert over_wavelength["spread"] == pytest.approx(over_wavelength["sharp"], rel=2e-3)


def test_axial_light_over_wavenumber_depends_on_where_the_design_focuses(axial):
    k, alpha, beta = axial["k"], axial["alpha"], axial["beta"]
    over_k = {name: np.trapezoid(axial[name], k) for name in ("sharp", "spread")}
    # stationary phase: ∫ I₀ dk = 2πd²∫ k*(s)²/s² ds over the aperture power πa²
    k_d = 2 * math.pi / 532e-9
    expected_sharp = k_d**2 / (2 * math.pi) * identity_constant()
    moments = alpha**2 * (1 / D_M - 1 / S_MAX_M) + 2 * alpha * beta * math.log(S_MAX_M / D_M) + beta**2 * SPAN_M
    expected_spread = 2 * math.pi * D_M**2 * moments / (math.pi * A_M**2)
    assert over_k["sharp"] == pytest.approx(expected_sharp, rel=5e-3)
    assert over_k["spread"] == pytest.approx(expected_spread, rel=5e-3)
    assert over_k["sharp"] / over_k["spread"] > 1.5  # (2π/532 nm)² against a mean (2π/~670 nm)²


@pytest.fixture(scope="module")
def cores():
    """Far 5 × 5 core energy over 430-650 nm every 0.25 nm of hyperbolic lenses designed for 532 and
    600 nm, both at d = 4 mm."""
    waves = np.linspace(*BAND_M, 881)
    out = {"waves": waves}
    for design in (532e-9, 600e-9):
        lens = hyperbolic(design, D_M, APERTURE_M, PITCH_M)
        psf = compute_psf(lens, PsfGrid(waves, [math.inf], CORE, PIXEL_M), dtype=torch.float64).psf[0].numpy()
        out[design] = central_energy(psf, CORE)
    return out


def ray_dwell_integral(design_m: float) -> float:
    """∫ E dλ (m) over the band by ray dwell, for rays that all focus ``design_m`` on the sensor."""
    h = CORE / 2 * PIXEL_M
    return 16 * math.log(1 + math.sqrt(2)) * h * design_m * D_M * math.atan(A_M / D_M) / (math.pi * A_M**2)


def test_the_identity_does_not_bound_the_5x5_core(cores):
    allowed = identity_constant() * (CORE * PIXEL_M) ** 2 / (BAND_M[1] - BAND_M[0])
    assert allowed == pytest.approx(0.57, abs=0.005)  # the core lit at the axial intensity throughout
    assert cores[532e-9][::4].mean() < allowed / 10


def test_the_band_mean_needs_1nm_sampling(cores):
    waves = cores["waves"]
    for design in (532e-9, 600e-9):
        fine = np.trapezoid(cores[design], waves)
        one_nm, five_nm = cores[design][::4], cores[design][::20]
        assert np.trapezoid(one_nm, waves[::4]) == pytest.approx(fine, rel=1e-3)  # 1 nm has converged
        assert one_nm.mean() == pytest.approx(fine / (BAND_M[1] - BAND_M[0]), rel=6e-3)  # mean of samples
        assert abs(five_nm.mean() / one_nm.mean() - 1) > 0.03  # 5 nm: off by where the peak falls
    # the numbers docs/training.md quotes: 5 nm inflates the hyperbolic lens's mean, at 600 nm it deflates
    assert round(float(cores[532e-9][::4].mean()), 4) == 0.0381
    assert round(float(cores[532e-9][::20].mean()), 4) == 0.0398
    assert cores[600e-9][::20].mean() < cores[600e-9][::4].mean()


def test_ray_dwell_predicts_the_band_integrated_core(cores):
    waves = cores["waves"]
    computed = {design: np.trapezoid(cores[design], waves) for design in (532e-9, 600e-9)}
    for design, value in computed.items():
        # wave optics and the rays whose dwell passes the band's ends: within 3 % (measured −1.1, −1.7 %)
        assert value == pytest.approx(ray_dwell_integral(design), rel=0.03)
    # the design can only move λ*: the band integral scales with it
    assert computed[600e-9] / computed[532e-9] == pytest.approx(600 / 532, rel=0.015)
