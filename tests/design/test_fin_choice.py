"""The fin to fabricate: the best mean η whose fabrication neighbourhood keeps 95 % of it."""

import numpy as np

from metalens_cli.design.fin_choice import FinMap, band_wavelengths, recommend


def fin_map(score):
    score = np.asarray(score, float)
    widths, lengths = np.arange(score.shape[1]) * 5e-9 + 200e-9, np.arange(score.shape[0]) * 5e-9 + 50e-9
    return FinMap(widths, lengths, [(530e-9, 20e-9)], band_wavelengths([(530e-9, 20e-9)]), score[:, :, None], 9, 0.0)


def test_a_sharp_peak_loses_to_a_broad_plateau():
    score = np.full((7, 7), 0.2)
    score[1, 1] = 0.9  # best, but its neighbours (±10 nm = ±2 cells) fall to 0.2
    score[3:7, 3:7] = 0.7  # a plateau
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
    waves = band_wavelengths([(457e-9, 22e-9), (628e-9, 28e-9)], 3)
    np.testing.assert_allclose(waves[:, [0, -1]], [[446e-9, 468e-9], [614e-9, 642e-9]])
    np.testing.assert_allclose(waves[:, 1], [457e-9, 628e-9])
    assert band_wavelengths([(457e-9, 22e-9)]).shape == (1, 8)
    np.testing.assert_allclose(band_wavelengths([(457e-9, 22e-9)], 1), [[457e-9]])


def test_refine_recomputes_the_chosen_fin_and_its_neighbourhood():
    """Coarse to fine: the map at N = 3, the chosen fin and its ±10 nm neighbours at N = 7; the
    refined score against fin_response of the chosen fin alone at N = 7, averaged per band."""
    from metalens_cli.design.fin_choice import fin_map as compute_map
    from metalens_cli.design.fin_choice import refine
    from metalens_cli.optics.fin import Fin
    from metalens_cli.optics.nanofin import fin_response

    bands = [(457e-9, 22e-9), (628e-9, 28e-9)]

    def index(w):
        return np.full(np.shape(w), 2.0 + 0j)

    def substrate(w):
        return np.full(np.shape(w), 1.46 + 0j)

    m = compute_map(
        395e-9,
        700e-9,
        [250e-9, 260e-9, 270e-9, 400e-9],
        [100e-9, 110e-9],
        bands,
        index,
        substrate,
        3,
        samples_per_band=2,
    )
    assert np.isnan(m.eta[:, 3]).all() and not np.isnan(m.eta[:, :3]).any()  # 400 nm does not fit in the cell
    choice = recommend(m)
    fine = refine(m, choice, 395e-9, 700e-9, index, substrate, 7)
    assert fine["fins"] == len(
        {
            (length, w)
            for length in m.lengths_m
            for w in m.widths_m[:3]
            if abs(length - choice["length_m"]) <= 10.001e-9 and abs(w - choice["width_m"]) <= 10.001e-9
        }
    )
    waves = m.wavelengths_m
    alone = fin_response(
        Fin(395e-9, 700e-9, choice["width_m"], choice["length_m"]),
        index(waves.ravel()),
        substrate(waves.ravel()),
        waves.ravel(),
        7,
    )
    np.testing.assert_allclose(fine["eta_per_band"], alone.conversion.reshape(waves.shape).mean(axis=1), atol=1e-12)
    assert fine["worst_neighbour"] <= fine["score"] and fine["harmonics"] == 7


def test_a_sweep_warns_of_no_convergence_an_edge_fin_and_a_fragile_converged_neighbourhood():
    from metalens_cli.design.fin_choice import _warnings

    m = fin_map(np.full((3, 3), 0.7))
    table = [{"harmonics": 33, "max_change": 3e-3}, {"harmonics": 35, "max_change": 2e-3}]
    inner = {
        "width_m": m.widths_m[1],
        "length_m": m.lengths_m[1],
        "robust": True,
        "keep": 0.95,
        "converged": {"converged": True, "convergence": table, "robust": True, "harmonics": 35},
    }
    assert _warnings(m, inner) == []
    edge = {**inner, "width_m": m.widths_m[0]}
    assert "lies on the grid's edge" in _warnings(m, edge)[0]
    fragile = {**inner, "converged": {**inner["converged"], "converged": False, "robust": False}}
    said = _warnings(m, fragile)
    assert "moved up to 0.002 from N = 33 to 35" in said[0] and "converged at N = 35, a neighbour" in said[1]
