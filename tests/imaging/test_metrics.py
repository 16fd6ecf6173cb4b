"""Metrics: PSNR of known noise, SSIM against an independent implementation and against the
reference packages (scikit-image directly; torchmetrics through a stored fixture), gain/bias
match (luminance and least squares) against known affine changes and numpy closed forms."""

import json
from pathlib import Path

import numpy as np
import pytest
import scipy.signal
import skimage.metrics
import torch
from metric_references import ssim_pairs

from metalens_cli.errors import InputError
from metalens_cli.imaging.metrics import MATCH_METHODS, photometric_match, psnr, ssim


def test_psnr_of_known_noise():
    rng = np.random.default_rng(0)
    ref = torch.full((3, 128, 128), 0.5, dtype=torch.float64)
    noisy = ref + 0.01 * torch.as_tensor(rng.standard_normal((3, 128, 128)))
    # MSE ≈ σ² = 1e-4 → 40 dB; 49152 samples → MSE relative error ≈ 0.6 % → 0.03 dB
    assert float(psnr(noisy, ref)) == pytest.approx(40.0, abs=0.1)
    assert float(psnr(ref + 0.1, ref)) == pytest.approx(20.0, abs=1e-9)  # exact: MSE = 0.01


def _ssim_reference(x, y, k1=0.01, k2=0.03, sigma=1.5, size=11):
    """Independent SSIM (Wang et al. 2004) in numpy/scipy: 2-D Gaussian window, 'valid' FFT filtering."""
    g = np.exp(-((np.arange(size) - size // 2) ** 2) / (2 * sigma**2))
    w = np.outer(g, g)
    w /= w.sum()
    out = []
    for a, b in zip(x, y):
        f = lambda z: scipy.signal.fftconvolve(z, w, mode="valid")  # noqa: E731
        ma, mb = f(a), f(b)
        va, vb, cab = f(a * a) - ma**2, f(b * b) - mb**2, f(a * b) - ma * mb
        c1, c2 = k1**2, k2**2
        out.append(((2 * ma * mb + c1) * (2 * cab + c2)) / ((ma**2 + mb**2 + c1) * (va + vb + c2)))
    return float(np.mean(out))


def test_ssim_matches_independent_implementation():
    rng = np.random.default_rng(1)
    x = rng.random((3, 48, 40))
    y = np.clip(x + 0.1 * rng.standard_normal(x.shape), 0, 1)
    ours = float(ssim(torch.as_tensor(x), torch.as_tensor(y)))
    np.testing.assert_allclose(ours, _ssim_reference(x, y), atol=1e-9)  # float64, different filtering order
    assert float(ssim(torch.as_tensor(x), torch.as_tensor(x))) == pytest.approx(1.0, abs=1e-12)


@pytest.fixture(scope="module")
def pairs():
    return ssim_pairs()


# scikit-image's arguments for this package's SSIM: 11 × 11 Gaussian window (σ 1.5, truncate 3.5),
# population covariances, K1 0.01, K2 0.03, the range given; skimage filters with mirrored
# borders and then drops the 5-pixel border strip, which leaves the same 'valid' window positions
SKIMAGE_SSIM = dict(gaussian_weights=True, sigma=1.5, use_sample_covariance=False, K1=0.01, K2=0.03, data_range=1.0)
PAIR_NAMES = ("photo-noise", "photo-blur", "photo-shift", "photo-colour", "noise-vs-noise", "texture-blur")


@pytest.mark.parametrize("name", PAIR_NAMES)
def test_ssim_and_psnr_match_scikit_image(pairs, name):
    """Channels are averaged (each has the same number of window positions, so the mean over
    channels and positions is skimage's mean of per-channel means)."""
    x, y = pairs[name]
    reference = skimage.metrics.structural_similarity(x, y, channel_axis=0, **SKIMAGE_SSIM)
    ours = float(ssim(torch.as_tensor(y), torch.as_tensor(x)))
    assert ours == pytest.approx(reference, abs=1e-12)  # float64: round-off (measured ≤ 1.3e-15)
    ours32 = float(ssim(torch.as_tensor(y, dtype=torch.float32), torch.as_tensor(x, dtype=torch.float32)))
    assert ours32 == pytest.approx(reference, abs=1e-4)  # float32 (measured ≤ 1.9e-6)
    psnr_reference = skimage.metrics.peak_signal_noise_ratio(x, y, data_range=1.0)
    assert float(psnr(torch.as_tensor(y), torch.as_tensor(x))) == pytest.approx(psnr_reference, abs=1e-10)


def test_ssim_matches_scikit_image_grey_and_non_square():
    rng = np.random.default_rng(21)
    x = rng.random((1, 40, 57))
    y = np.clip(0.7 * x + 0.2 + 0.05 * rng.standard_normal(x.shape), 0, 1)
    reference = skimage.metrics.structural_similarity(x[0], y[0], **SKIMAGE_SSIM)
    assert float(ssim(torch.as_tensor(x), torch.as_tensor(y))) == pytest.approx(reference, abs=1e-12)
    reference = skimage.metrics.structural_similarity(x[0], y[0], **{**SKIMAGE_SSIM, "data_range": 2.0})
    assert float(ssim(torch.as_tensor(x), torch.as_tensor(y), data_range=2.0)) == pytest.approx(reference, abs=1e-12)


def test_scikit_image_defaults_are_another_ssim(pairs):
    """Without those arguments skimage computes another SSIM: its defaults are a uniform 7 × 7
    window with sample covariances (×49/48); with the Gaussian window, sample covariances
    (×121/120) alone move the photograph's score by 3e-4."""
    x, y = pairs["photo-noise"]
    ours = float(ssim(torch.as_tensor(y), torch.as_tensor(x)))
    defaults = skimage.metrics.structural_similarity(x, y, channel_axis=0, data_range=1.0)
    sample = skimage.metrics.structural_similarity(x, y, channel_axis=0, gaussian_weights=True, data_range=1.0)
    assert abs(ours - defaults) > 1e-2 and abs(ours - sample) > 1e-4


def test_ssim_and_psnr_match_torchmetrics_fixture(pairs):
    """torchmetrics 1.9 (data/torchmetrics_ssim_psnr.json, make_torchmetrics_fixture.py): its
    Gaussian 11 × 11 SSIM map averaged over the valid positions equals ours to round-off; its
    own mean also counts the 5-pixel border computed on reflect-padded images (here up to
    0.0095 higher or lower), which this package leaves out like scikit-image. PSNR per image
    (its ``dim=(1, 2, 3)``); torchmetrics' 10/ln 10 is a float32 constant, so ~1e-6 dB apart."""
    reference = json.loads((Path(__file__).parent / "data" / "torchmetrics_ssim_psnr.json").read_text())
    rows = reference["pairs"]
    assert [row["name"] for row in rows] == list(pairs) == list(PAIR_NAMES)
    x = torch.as_tensor(np.stack([pairs[row["name"]][0] for row in rows]))
    y = torch.as_tensor(np.stack([pairs[row["name"]][1] for row in rows]))
    np.testing.assert_allclose(ssim(y, x).numpy(), [row["ssim_valid"] for row in rows], rtol=0, atol=1e-12)
    np.testing.assert_allclose(psnr(y, x).numpy(), [row["psnr_db"] for row in rows], rtol=0, atol=1e-5)


def test_ssim_batched_and_differentiable():
    x = torch.rand(2, 3, 32, 32, requires_grad=True)
    y = torch.rand(2, 3, 32, 32)
    s = ssim(x, y)
    assert s.shape == (2,)
    (1 - s).sum().backward()
    assert torch.isfinite(x.grad).all()


def test_gain_bias_match_recovers_affine_change():
    rng = np.random.default_rng(2)
    ref = torch.as_tensor(rng.random((2, 3, 32, 32)))
    changed = (ref - 0.05) / 1.7  # reference = 1.7·changed + 0.05
    matched, gain, bias = photometric_match(changed, ref)
    np.testing.assert_allclose(gain.numpy(), [1.7, 1.7], rtol=1e-12)
    np.testing.assert_allclose(bias.numpy(), [0.05, 0.05], atol=1e-12)
    np.testing.assert_allclose(matched.numpy(), ref.numpy(), atol=1e-12)


@pytest.mark.parametrize("method", MATCH_METHODS)
def test_match_recovers_a_gain_and_bias_per_batch_entry(method):
    rng = np.random.default_rng(3)
    ref = torch.as_tensor(rng.random((2, 3, 32, 32)))
    a, b = torch.tensor([1.7, 0.6], dtype=torch.float64), torch.tensor([0.05, -0.1], dtype=torch.float64)
    changed = (ref - b.view(2, 1, 1, 1)) / a.view(2, 1, 1, 1)  # reference = a·changed + b, per entry
    matched, gain, bias = photometric_match(changed, ref, method=method)
    # exact in arithmetic; float64 round-off of means over 3072 values stays ~1e-15
    np.testing.assert_allclose(gain.numpy(), a.numpy(), rtol=1e-12)
    np.testing.assert_allclose(bias.numpy(), b.numpy(), atol=1e-12)
    np.testing.assert_allclose(matched.numpy(), ref.numpy(), atol=1e-12)


def test_luminance_and_lstsq_differ_with_channel_contrast():
    rng = np.random.default_rng(4)
    ref = rng.random((3, 24, 24))
    est = ref * np.array([1.0, 0.5, 2.0])[:, None, None] + 0.1  # contrast differs per channel
    y = lambda im: np.tensordot([0.2126, 0.7152, 0.0722], im, axes=1)  # noqa: E731
    a_lum = y(ref).std() / y(est).std()  # Suppl. Note 11, population σ
    a_lsq = np.polyfit(est.ravel(), ref.ravel(), 1)[0]  # least squares over every sample
    _, gain, bias = photometric_match(torch.as_tensor(est), torch.as_tensor(ref))  # default: luminance
    _, gain_lsq, _ = photometric_match(torch.as_tensor(est), torch.as_tensor(ref), method="lstsq")
    # closed forms in float64 numpy, different summation order: agree to round-off
    assert float(gain) == pytest.approx(a_lum, rel=1e-10)
    assert float(bias) == pytest.approx(y(ref).mean() - a_lum * y(est).mean(), abs=1e-10)
    assert float(gain_lsq) == pytest.approx(a_lsq, rel=1e-10)
    assert abs(a_lum - a_lsq) > 0.1  # 1.70 vs 0.40 here: the methods weigh channels differently


def test_luminance_match_of_a_flat_estimate_and_unknown_method():
    ref = torch.as_tensor(np.random.default_rng(5).random((3, 16, 16)))
    matched, gain, bias = photometric_match(torch.full_like(ref, 0.3), ref)  # σ_Y ≈ 1e-17, round-off
    luminance = (torch.tensor([0.2126, 0.7152, 0.0722], dtype=ref.dtype).view(3, 1, 1) * ref).sum(0)
    assert float(gain) == 0.0
    assert float(bias) == pytest.approx(float(luminance.mean()), abs=1e-15)
    assert (matched == bias).all()  # 0·estimate + b: the reference's mean luminance, exactly
    with pytest.raises(InputError, match="lstsq or luminance"):
        photometric_match(ref, ref, method="histogram")


def test_a_grey_wall_imaged_as_grey_scores_the_psnr_ceiling():
    """A uniform grey capture of a uniform grey wall (any gain: the match takes it out) is an
    exact match: PSNR at its 100 dB ceiling, not +∞ (which broke the statistics), SSIM 1."""
    import numpy as np

    from metalens_cli.imaging.metrics import PSNR_CEILING_DB
    from metalens_cli.imaging.pipeline import score

    wall = np.full((3, 32, 32), 0.18, np.float32)
    result = score(0.5 * wall, wall)
    assert result["psnr_db"] == PSNR_CEILING_DB and abs(result["ssim"] - 1) < 1e-12
    ramp = wall * np.linspace(0.5, 1.5, 32, dtype=np.float32)  # a scene with something to get wrong
    noisy = ramp + 0.01 * np.random.default_rng(0).random(wall.shape, dtype=np.float32)
    assert 30 < score(noisy, ramp)["psnr_db"] < PSNR_CEILING_DB


@pytest.mark.parametrize("method", MATCH_METHODS)
def test_dirt_in_front_of_a_grey_wall_is_not_matched_away(method):
    """A flat reference leaves only the exposure to match (a = μ_ref/μ_est, b = 0): a free gain
    would be 0 and turn a capture with an obstruction into the wall itself, a perfect score."""
    from metalens_cli.imaging.pipeline import score
    from metalens_cli.io.image_files import linear_to_srgb

    wall = np.full((3, 64, 64), 0.18)
    yy, xx = np.mgrid[:64, :64]
    capture = 0.7 * wall * (1 - 0.8 * (np.hypot(yy - 32, xx - 32) < 12))  # darker exposure, one dark blob
    result = score(capture.astype(np.float32), wall.astype(np.float32), match=method)
    a = wall.mean() / capture.mean()
    assert result["gain"] == pytest.approx(a, rel=1e-6) and result["bias"] == 0
    matched, wall_srgb = linear_to_srgb(np.clip(a * capture, 0, 1)), linear_to_srgb(wall)  # scored as displayed
    assert result["psnr_db"] == pytest.approx(-10 * np.log10(np.mean((matched - wall_srgb) ** 2)), abs=1e-4)  # 21.8 dB
    _, gain, bias = photometric_match(torch.zeros(3, 8, 8), torch.full((3, 8, 8), 0.18), method)
    assert float(gain) == 0 and float(bias) == 0  # black stays black: no exposure brings it to grey
