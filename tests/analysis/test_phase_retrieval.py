"""Phase retrieval from measured PSFs: simulated measurements of a lens with a known defocus and
spherical aberration (the PSFs computed here by ``compute_psf`` on a perturbed θ, noise added
here) are fitted back; coefficients within 3 σ of the truth, σ shrinking with the SNR, residuals
at the noise; cubes that cannot constrain the phase are refused."""

import math

import numpy as np
import pytest
import torch

from metalens_cli.analysis.phase_retrieval import (
    check_constrained,
    check_retrievable,
    retrieve_phase,
    zernike_radial,
)
from metalens_cli.analysis.subpixel import fourier_shift
from metalens_cli.errors import InputError
from metalens_cli.optics.lens import Metalens, hyperbolic
from metalens_cli.optics.psf import compute_psf
from metalens_cli.optics.sampling import PsfGrid

# A small lens (NA 0.1: Airy core 1.22·λ/NA ≈ 6.5 µm at 532 nm, 8 pixels of 0.8 µm); a source at
# 2 mm images 53 µm behind f (about one depth of focus λ/NA², 0.5 waves of defocus), and the
# diffractive lens focuses 500 and 570 nm 19 µm after and before f: phase diversity both ways.
F, D, PITCH = 300e-6, 60e-6, 395e-9
WAVELENGTHS, DEPTHS = [500e-9, 532e-9, 570e-9], [math.inf, 2e-3]
PIXELS, PIXEL_PITCH = 40, 0.8e-6
TRUTH = np.array([1.0, -0.6, 0.0, 0.0])  # rad: defocus, primary spherical, secondary, tertiary
SHIFTS = [(0.3, -0.2), (0.0, 0.1), (-0.25, 0.0), (0.1, 0.15), (0.0, 0.0), (-0.1, -0.3)]  # px per PSF


def nominal():
    return hyperbolic(532e-9, F, D, PITCH)


def perturbed_psfs(coefficients, shifts=None, pixels=PIXELS):
    """(D, W, N, N) PSFs of the nominal lens with δ = c2·(2ρ² − 1) + c4·(6ρ⁴ − 6ρ² + 1) (the
    polynomials written out here, not taken from the module), each normalised to sum to one and
    moved by its sub-pixel shift (a Fourier shift on a window 8 pixels wider, then cropped)."""
    lens = nominal()
    rho = np.arange(lens.theta.shape[0]) * PITCH / (D / 2)
    delta = coefficients[0] * (2 * rho**2 - 1) + coefficients[1] * (6 * rho**4 - 6 * rho**2 + 1)
    aberrated = Metalens(lens.theta + torch.from_numpy(delta) / 2, PITCH, D, F)
    psf = compute_psf(aberrated, PsfGrid(WAVELENGTHS, DEPTHS, pixels + 8, PIXEL_PITCH, F), dtype=torch.float64)
    psf = psf.psf.numpy()
    if shifts is not None:
        flat = psf.reshape(-1, pixels + 8, pixels + 8)
        psf = np.stack([fourier_shift(p, *s) for p, s in zip(flat, shifts)]).reshape(psf.shape)
    psf = psf[..., 4 : 4 + pixels, 4 : 4 + pixels]
    return psf / psf.sum(axis=(-2, -1), keepdims=True)


def noisy(psf, snr, seed):
    """Gaussian noise of σ = peak/SNR per PSF (a read-noise-limited camera); returns data and σ."""
    sigma = psf.max(axis=(-2, -1), keepdims=True) / snr
    return psf + np.random.default_rng(seed).normal(size=psf.shape) * sigma, sigma[..., 0, 0]


@pytest.fixture(scope="module")
def aberrated():
    return perturbed_psfs(TRUTH, SHIFTS)


def retrieve(psf, **options):
    return retrieve_phase(psf, WAVELENGTHS, DEPTHS, PIXEL_PITCH, nominal(), **options)


def coefficients(result):
    return np.array([t["coefficient_rad"] for t in result.terms]), np.array([t["sigma_rad"] for t in result.terms])


def test_defocus_and_spherical_recovered_within_their_uncertainty_at_two_snrs(aberrated):
    sigmas = {}
    for snr in (100, 1000):
        data, noise = noisy(aberrated, snr, seed=3)
        result = retrieve(data)
        found, sigma = coefficients(result)
        assert result.converged and result.iterations < 40
        np.testing.assert_array_less(np.abs(found - TRUTH), 3 * sigma)
        # the residual is the noise: each PSF's σ from its residual within 10 % of the noise added
        # (2·40² samples estimate it to ~2 %), and the fit explains the nominal's misfit
        fitted = np.array([p["noise_sigma"] for p in result.psfs])
        np.testing.assert_allclose(fitted, noise.ravel(), rtol=0.1)
        assert 0.9 < result.chi2_reduced < 1.1
        assert all(p["relative_l2"] < p["relative_l2_nominal"] for p in result.psfs)
        shifts = np.array([p["shift_px"] for p in result.psfs])
        np.testing.assert_allclose(shifts, SHIFTS, atol=30 / snr)  # 0.3 px at SNR 100
        sigmas[snr] = sigma
    # σ ∝ 1/SNR for white noise: ten times the SNR, a tenth of the uncertainty (within 2×)
    ratio = sigmas[100] / sigmas[1000]
    assert np.all((ratio > 5) & (ratio < 20)), ratio
    # an uncertainty worth reporting: defocus and spherical known to better than 0.02 rad at SNR 100
    assert np.all(sigmas[100][:2] < 0.02)
    assert result.condition_number < 1e3


def test_photon_noise_is_weighed_by_its_own_variance(aberrated):
    """Shot noise (10⁵ photons per PSF) and 3 e⁻ of read noise: the fitted variance model
    σ² = a + b·model finds b ≈ 1/photons (a, the read noise's 3²/photons², is lost under the shot
    noise of a window this bright), and the coefficients lie within 3 σ
    (with one σ per PSF they fell 3-5 σ off: the bright core is the noisiest)."""
    photons = 1e5
    rng = np.random.default_rng(8)
    data = (rng.poisson(aberrated * photons) + 3 * rng.normal(size=aberrated.shape)) / photons
    result = retrieve(data)
    found, sigma = coefficients(result)
    np.testing.assert_array_less(np.abs(found - TRUTH), 3 * sigma)
    slopes = np.array([p["noise_model"]["shot_slope"] for p in result.psfs])
    # a sharp PSF's slope rests on its few bright pixels (χ² scatter: 0.49-1.67 here): each within 3×,
    # their geometric mean within 30 %
    assert np.all((slopes > 1 / 3 / photons) & (slopes < 3 / photons)), slopes * photons
    assert np.exp(np.mean(np.log(slopes))) == pytest.approx(1 / photons, rel=0.3), slopes * photons


def test_retrieved_theta_is_the_nominal_plus_half_the_fitted_delta(aberrated):
    data, _ = noisy(aberrated, 1000, seed=5)
    result = retrieve(data, terms=2)
    lens = nominal()
    rho = np.arange(lens.theta.shape[0]) * PITCH / (D / 2)
    c2, c4 = coefficients(result)[0]
    delta = c2 * (2 * rho**2 - 1) + c4 * (6 * rho**4 - 6 * rho**2 + 1)
    np.testing.assert_allclose(result.theta, lens.theta.numpy() + delta / 2, atol=1e-12)
    assert result.theta.shape == lens.theta.shape


def test_zero_perturbation_recovers_zero():
    data, _ = noisy(perturbed_psfs(np.zeros(4)), 300, seed=7)
    result = retrieve(data, nuisance=("background",))
    found, sigma = coefficients(result)
    np.testing.assert_array_less(np.abs(found), 3 * sigma)
    assert np.all(sigma < 0.01)
    assert all(p["shift_px"] == [0.0, 0.0] for p in result.psfs)  # not fitted


def test_zernike_radial_polynomials_are_orthogonal_on_the_unit_disc():
    """∫₀¹ R_n R_m ρ dρ = δ_nm / (2(n + 1)) (Gauss-Legendre, exact for these polynomials)."""
    x, w = np.polynomial.legendre.leggauss(20)
    rho, w = (x + 1) / 2, w / 2
    for n in (0, 2, 4, 6, 8):
        for m in (0, 2, 4, 6, 8):
            value = np.sum(w * rho * zernike_radial(n, rho) * zernike_radial(m, rho))
            assert value == pytest.approx(1 / (2 * (n + 1)) if n == m else 0.0, abs=1e-12)
    np.testing.assert_allclose(zernike_radial(6, rho), 20 * rho**6 - 30 * rho**4 + 12 * rho**2 - 1, atol=1e-12)


def test_one_depth_and_one_wavelength_is_refused_for_the_twin_ambiguity():
    psf = np.ones((1, 1, PIXELS, PIXELS))
    with pytest.raises(InputError, match="MEASURED: one depth and one wavelength.*−δ.*twin"):
        check_retrievable(psf, [532e-9], [math.inf], PIXEL_PITCH, nominal(), F)


@pytest.mark.parametrize(
    ("change", "match"),
    [
        (lambda p: p.__setitem__((0, 1, 3, 3), np.nan), "NaN or infinite"),
        (lambda p: p.__setitem__((1, 0), 0.0), "holds no light"),
    ],
)
def test_unusable_values_are_refused(change, match):
    psf = np.ones((2, 3, PIXELS, PIXELS))
    change(psf)
    with pytest.raises(InputError, match=f"MEASURED: .*{match}"):
        check_retrievable(psf, WAVELENGTHS, DEPTHS, PIXEL_PITCH, nominal(), F)


def test_saturated_frames_and_coarse_pixels_are_refused():
    psf = np.ones((2, 3, PIXELS, PIXELS))
    frames = [{"file": "a.png", "saturated_pixels": 0}, {"file": "b.png", "saturated_pixels": 12}]
    with pytest.raises(InputError, match="MEASURED: 1 of its frames .*saturated pixels \\(b.png\\)"):
        check_retrievable(psf, WAVELENGTHS, DEPTHS, PIXEL_PITCH, nominal(), F, {"frames": frames})
    # NA 0.0995: the Airy core at 570 nm is 1.22·0.57/0.0995 = 7.0 µm across
    with pytest.raises(InputError, match="wider than the lens's Airy core"):
        check_retrievable(psf, WAVELENGTHS, DEPTHS, 8e-6, nominal(), F)
    with pytest.raises(InputError, match="window of 12 pixels"):
        check_retrievable(psf[..., :12, :12], WAVELENGTHS, DEPTHS, PIXEL_PITCH, nominal(), F)
    flat = hyperbolic(532e-9, F, D, PITCH, radial=False)
    with pytest.raises(InputError, match="--design: a 2-D rotation map"):
        check_retrievable(psf, WAVELENGTHS, DEPTHS, PIXEL_PITCH, flat, F)


def test_terms_the_cube_cannot_tell_apart_are_named():
    """Two coefficients moving the pixels alike (equal Jacobian columns) leave a direction free."""
    rng = np.random.default_rng(0)
    jc = rng.normal(size=(500, 3))
    jc[:, 2] = jc[:, 1]  # Z(4,0) and Z(6,0) move every pixel alike
    jn = np.zeros((500, 2))  # two PSFs, one scale each, on their own halves of the pixels
    jn[:250, 0], jn[250:, 1] = rng.normal(size=250), rng.normal(size=250)
    j = np.concatenate([jc, jn], axis=1)
    with pytest.raises(InputError, match=r"--terms: the cube does not constrain Z\(\d,0\).*, Z\(\d,0\)") as error:
        check_constrained(j.T @ j, 3, 1, 2)
    assert "Z(2,0)" not in str(error.value)
    j[:, 2] += 0.5 * rng.normal(size=500)
    assert check_constrained(j.T @ j, 3, 1, 2) < 100


def test_terms_and_nuisance_are_checked():
    psf = np.ones((2, 3, PIXELS, PIXELS))
    with pytest.raises(InputError, match="--terms"):
        retrieve(psf, terms=0)
    with pytest.raises(InputError, match="--nuisance: unknown tilt"):
        retrieve(psf, nuisance=("tilt",))


def test_giant_cubes_are_refused_and_the_fit_is_estimated(monkeypatch):
    from metalens_cli.analysis import phase_retrieval
    from metalens_cli.analysis.phase_retrieval import estimate_retrieval, model_grid

    monkeypatch.setattr(phase_retrieval, "MAX_SAMPLES", 1000)
    with pytest.raises(InputError, match="6 PSFs of 40² pixels: 9.6e\\+03 samples, over the 1e\\+03"):
        check_retrievable(np.ones((2, 3, PIXELS, PIXELS)), WAVELENGTHS, DEPTHS, PIXEL_PITCH, nominal(), F)
    small = estimate_retrieval(nominal(), model_grid(WAVELENGTHS, DEPTHS, PIXELS, PIXEL_PITCH, F), 4, 50)
    large = estimate_retrieval(nominal(), model_grid(WAVELENGTHS * 4, DEPTHS, 4 * PIXELS, PIXEL_PITCH, F), 4, 50)
    assert "6 PSFs of 48² pixels with 4 terms" in small.describe()
    assert small.memory_bytes < large.memory_bytes and 0 < small.seconds <= small.seconds_max <= large.seconds_max
