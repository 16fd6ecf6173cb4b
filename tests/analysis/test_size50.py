"""size50: the logistic fit against scipy's general optimiser, its bounds, its interval."""

import numpy as np
import pytest
import scipy.optimize

from metalens_cli.analysis.size50 import logistic_fit, size50
from metalens_cli.errors import InputError


def _draw(n_units: int, a: float, b: float, seed: int = 0):
    rng = np.random.default_rng(seed)
    sizes = np.tile(np.geomspace(10, 200, 8), n_units)
    p = 1 / (1 + np.exp(-(a + b * np.log(sizes))))
    return sizes, rng.random(sizes.size) < p, np.repeat(np.arange(n_units), 8)


def test_fit_matches_a_general_optimiser():
    """Newton's method with the ridge against Nelder-Mead on the same penalised likelihood."""
    sizes, found, _ = _draw(40, -12.0, 3.0)
    x = np.log(sizes)

    def loss(beta):
        z = beta[0] + beta[1] * x
        return np.sum(np.logaddexp(0, z) - found * z) + 0.5 * 1e-3 * x.size * beta[1] ** 2

    reference = scipy.optimize.minimize(loss, [0.0, 1.0], method="Nelder-Mead", options={"xatol": 1e-9, "fatol": 1e-12})
    np.testing.assert_allclose(logistic_fit(x, found), reference.x, rtol=1e-4)


def test_interval_covers_the_true_size50():
    true = np.exp(12.0 / 3.0)  # 54.6
    sizes, found, units = _draw(40, -12.0, 3.0)
    fit = size50(sizes, found, units)
    assert fit["bound"] is None
    assert fit["ci"][0] < true < fit["ci"][1]
    assert fit["ci"][1] / fit["ci"][0] < 1.6


def test_bounds_and_a_separated_sample():
    sizes = np.tile([10.0, 20.0, 40.0, 80.0], 5)
    units = np.repeat(np.arange(5), 4)
    assert size50(sizes, np.ones(20, bool), units)["bound"] == "below"
    assert size50(sizes, np.ones(20, bool), units)["size50"] == pytest.approx(10.0)
    assert size50(sizes, np.zeros(20, bool), units)["bound"] == "above"
    separated = size50(sizes, sizes >= 40, units)  # a perfect step: size50 between 20 and 40
    assert separated["bound"] is None and 20 < separated["size50"] < 40
    flat = size50(sizes, sizes <= 20, units)  # small ones found, large ones not
    assert flat["bound"] == "flat" and flat["size50"] is None and flat["ci"] is None


def test_bad_samples_are_refused():
    with pytest.raises(InputError, match="sizes"):
        size50([1.0, -2.0], [True, False], [0, 1])
    with pytest.raises(InputError, match="sizes"):
        size50([1.0, 2.0], [True], [0, 1])
