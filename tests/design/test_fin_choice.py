"""The fin to fabricate: the best mean η whose fabrication neighbourhood keeps 95 % of it."""

import numpy as np

from metalens_cli.design.fin_choice import band_wavelengths, FinMap, recommend


def fin_map(score):
    score = np.asarray(score, float)
    widths, lengths = np.arange(score.shape[1]) * 5e-9 + 200e-9, np.arange(score.shape[0]) * 5e-9 + 50e-9
    return FinMap(widths, lengths, [(530e-9, 20e-9)], band_wavelengths([(530e-9, 20e-9)]), score[:, :, None], 9, 0.0)


def test_a_sharp_peak_loses_to_a_broad_plateau():
    score = np.full((7, 7), 0.2)
    score[1, 1] = 0.9                # best, but its neighbours (±10 nm = ±2 cells) fall to 0.2
    score[3:7, 3:7] = 0.7            # a plateau
    choice = recommend(fin_map(score))
    assert choice["robust"] and choice["score"] == 0.7
    assert choice["width_m"] >= 215e-9 - 1e-15 and choice["length_m"] >= 65e-9 - 1e-15
    assert choice["worst_neighbour"] >= 0.95 * 0.7


def test_a_neighbour_outside_the_cell_makes_a_fin_fragile():
    """A fin next to grid fins that do not fit in the cell (NaN) cannot keep its η under a
    fabrication error; with no other fin the best is returned and said to be fragile."""
    choice = recommend(fin_map([[np.nan, 0.9]]), tolerance_m=5e-9)
    assert not choice["robust"] and choice["score"] == 0.9


def test_band_wavelengths_span_each_band():
    waves = band_wavelengths([(457e-9, 22e-9), (628e-9, 28e-9)])
    np.testing.assert_allclose(waves[:, [0, -1]], [[446e-9, 468e-9], [614e-9, 642e-9]])
    np.testing.assert_allclose(waves[:, 1], [457e-9, 628e-9])
