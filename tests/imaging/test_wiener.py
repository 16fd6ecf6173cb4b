"""The oracle Wiener restoration: exact for a delta PSF without noise, never worse than the raw
capture in expectation on natural-statistics scenes; and the crossover of a verdict."""

import numpy as np
import torch

from metalens_cli.analysis.statistics import crossover
from metalens_cli.imaging.evaluation import expose
from metalens_cli.imaging.formation import convolve
from metalens_cli.imaging.pipeline import score
from metalens_cli.imaging.wiener import WienerFilter, choose_mu


def _one_over_f_squared(n: int, seed: int) -> np.ndarray:
    """A grey (3 equal channels) random scene with a 1/ν² power spectrum, linear values in 0.05..0.95."""
    rng = np.random.default_rng(seed)
    fy, fx = np.fft.fftfreq(n)[:, None], np.fft.fftfreq(n)[None, :]
    amplitude = 1 / np.maximum(np.hypot(fy, fx), 1 / n)
    field = np.fft.ifft2(amplitude * np.exp(2j * np.pi * rng.random((n, n)))).real
    field = 0.05 + 0.9 * (field - field.min()) / (field.max() - field.min())
    return np.repeat(field[None], 3, axis=0)


def _disc(n: int, radius: float) -> torch.Tensor:
    r = np.hypot(*np.meshgrid(np.arange(n) - n // 2, np.arange(n) - n // 2, indexing="ij"))
    return torch.as_tensor(np.repeat((r <= radius)[None].astype(float), 3, axis=0))


def _captures(psf: torch.Tensor, seeds, sensor: int, electrons):
    """(clean sensor crops, noisy captures) of 1/ν² scenes through ``psf``."""
    margin = psf.shape[-1] // 2
    cleans, captures = [], []
    for seed in seeds:
        canvas = _one_over_f_squared(sensor + 2 * margin, seed)
        blurred = convolve(torch.as_tensor(canvas), psf, margin).numpy()
        cleans.append(canvas[:, margin : margin + sensor, margin : margin + sensor])
        captures.append(expose(blurred, electrons, 2.5, generator=seed))
    return cleans, captures


def test_a_delta_psf_without_noise_restores_the_clean_image():
    delta = torch.zeros(3, 9, 9, dtype=torch.float64)
    delta[:, 4, 4] = 1
    cleans, captures = _captures(delta, [1, 2], 48, None)
    wiener = WienerFilter.of(delta, (48, 48))
    wiener.mu, errors = choose_mu(wiener, captures, cleans)
    assert np.all(wiener.mu == 0.0) and errors[:, 0].max() < 1e-12
    np.testing.assert_allclose(wiener(captures[0]), cleans[0], atol=1e-6)


def test_wiener_never_scores_below_raw_in_expectation_on_a_grey_one_over_f_squared_scene():
    """μ chosen on 4 held-out scenes; on 8 others the mean PSNR (the evaluation's score: least-
    squares match, sRGB) of the restoration is above the raw capture's, at a dim and a bright
    light level, through a 9-pixel disc blur."""
    psf = _disc(15, 4.5)
    for electrons in (np.full(3, 300.0), np.full(3, 30000.0)):
        held_clean, held = _captures(psf, range(100, 104), 64, electrons)
        wiener = WienerFilter.of(psf, (64, 64))
        wiener.mu, _ = choose_mu(wiener, held, held_clean)
        cleans, captures = _captures(psf, range(8), 64, electrons)
        raw = np.mean([score(x, c)["psnr_db"] for x, c in zip(captures, cleans)])
        restored = np.mean([score(wiener(x), c)["psnr_db"] for x, c in zip(captures, cleans)])
        assert restored > raw, (electrons[0], restored, raw)


def test_crossover_finds_the_level_where_the_difference_turns_positive():
    """d(L) = 0.4·log10(L / 1000) + noise per unit: the crossover is 1000 e⁻, inside its CI;
    differences positive everywhere are censored below, negative ones above."""
    rng = np.random.default_rng(0)
    levels = [100.0, 300.0, 1000.0, 3000.0, 10000.0]
    units = rng.normal(0, 0.3, 40)  # a unit effect shared by all levels (paired), plus noise
    d = np.array([0.4 * np.log10(L / 1000) + units + rng.normal(0, 0.05, 40) - units.mean() for L in levels])
    result = crossover(levels, d)
    lo, hi = result["crossover_ci"]
    assert lo < 1000 < hi and 700 < result["crossover"] < 1400, result
    assert result["wins"] == [False, False, False, True, True]
    assert crossover(levels, np.abs(d) + 0.5)["below"] and crossover(levels, -np.abs(d) - 0.5)["above"]
