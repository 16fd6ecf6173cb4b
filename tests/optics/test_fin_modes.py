"""The symmetric nanofin RCWA (optics.fin_modes) against answers that need no code (a
Fabry-Pérot slab, a square fin's zero conversion, a turned fin's swapped coefficients, energy
conservation), against its own full unreduced eigenproblem, and against meent (optics.nanofin)."""

import math

import numpy as np
import pytest
import torch

from metalens_cli.errors import InputError
from metalens_cli.optics import fin_modes
from metalens_cli.optics.fin import Fin
from metalens_cli.optics.fin_modes import fin_response_symmetric, fin_responses_symmetric
from metalens_cli.optics.nanofin import fin_response_meent

WAVELENGTHS = np.array([457e-9, 530e-9, 628e-9])
N_SUB = 1.46
PAPER_FIN = Fin(395e-9, 700e-9, 305e-9, 125e-9)
SQUARE_FIN = Fin(395e-9, 700e-9, 200e-9, 200e-9)


def response(fin, n_fin=2.0, harmonics=5, wavelengths=WAVELENGTHS, symmetric=True):
    count = len(wavelengths)
    return fin_response_symmetric(
        fin, np.full(count, n_fin, complex), np.full(count, N_SUB, complex), wavelengths, harmonics, symmetric=symmetric
    )


@pytest.mark.parametrize("symmetric", [True, False])
@pytest.mark.parametrize("harmonics", [3, 5])
def test_a_homogeneous_layer_is_a_fabry_perot_slab_and_converts_nothing(symmetric, harmonics):
    """w = l = p: a film of index n2 and thickness d between glass (n1) and air (n3), against the
    closed form t = t12·t23·e^{iβ}/(1 + r12·r23·e^{2iβ}), β = 2π·n2·d/λ, T = (n3/n1)|t|², to 1e-9
    (T, R, and t_xx = √(n3/n1)·t in phase too: e^{−iωt}, amplitudes at the layer's faces)."""
    d, n2 = 700e-9, 2.0
    r = response(Fin(395e-9, d, 395e-9, 395e-9), n2, harmonics, symmetric=symmetric)
    n1, n3 = N_SUB, 1.0
    beta = 2 * math.pi * n2 * d / WAVELENGTHS
    t = (
        (2 * n1 / (n1 + n2))
        * (2 * n2 / (n2 + n3))
        * np.exp(1j * beta)
        / (1 + ((n1 - n2) / (n1 + n2)) * ((n2 - n3) / (n2 + n3)) * np.exp(2j * beta))
    )
    np.testing.assert_allclose(r.transmittance, n3 / n1 * np.abs(t) ** 2, rtol=1e-9)
    np.testing.assert_allclose(r.transmittance + r.reflectance, 1.0, atol=1e-9)
    np.testing.assert_allclose(r.t_xx, math.sqrt(n3 / n1) * t, atol=1e-9)
    np.testing.assert_allclose(r.t_yy, r.t_xx, atol=1e-12)
    assert np.all(r.conversion < 1e-20)


@pytest.mark.parametrize("harmonics", [5, 9])
def test_a_square_fin_converts_nothing_exactly(harmonics):
    """A square fin converts nothing by symmetry; our factorisation treats x and y alike, so
    η < 1e-20 at every N (the full 2N² problem, where x and y incidence share one eigensystem;
    meent gives 2e-5 at N = 5)."""
    for symmetric in (True, False):
        r = response(SQUARE_FIN, harmonics=harmonics, symmetric=symmetric)
        assert np.all(r.conversion < 1e-20)
        assert np.all(r.co_polarized > 0.3)


def test_a_fin_turned_by_90_degrees_swaps_t_xx_and_t_yy():
    """Turning the fin (w, l) → (l, w) swaps t_xx and t_yy, to 1e-10, in the full 2N² problem."""
    turned = Fin(PAPER_FIN.period_m, PAPER_FIN.height_m, PAPER_FIN.length_m, PAPER_FIN.width_m)
    for harmonics in (5, 9):
        a, b = (response(fin, harmonics=harmonics, symmetric=False) for fin in (PAPER_FIN, turned))
        np.testing.assert_allclose(a.t_xx, b.t_yy, atol=1e-10)
        np.testing.assert_allclose(a.t_yy, b.t_xx, atol=1e-10)
        np.testing.assert_allclose(a.transmittance, b.transmittance, atol=1e-10)
    assert np.all(a.conversion > 0.3)  # a half-wave-like fin converts a good part


def test_energy_is_conserved_for_a_lossless_fin_and_lost_in_an_absorbing_one():
    """T + R = 1 to 1e-9 without loss (all propagating orders, 9 × 9 orders, diffraction into
    the substrate included); an index 2.0 + 0.05i absorbs (T + R < 0.99)."""
    lossless = response(PAPER_FIN, harmonics=9)
    np.testing.assert_allclose(lossless.transmittance + lossless.reflectance, 1.0, atol=1e-9)
    assert np.all(lossless.conversion + lossless.co_polarized <= lossless.transmittance + 1e-12)
    lossy = response(PAPER_FIN, 2.0 + 0.05j, harmonics=9)
    assert np.all(lossy.transmittance + lossy.reflectance < 0.99)


def test_a_grazing_order_is_finite():
    """λ = p: the first orders graze the air side (kz = 0, a Rayleigh anomaly): the result is
    finite, T + R = 1 to 1e-9, and within 2e-3 of λ = p·(1 ± 1e-6) (a square-root cusp)."""
    wavelengths = PAPER_FIN.period_m * np.array([1 - 1e-6, 1, 1 + 1e-6])
    r = response(PAPER_FIN, harmonics=5, wavelengths=wavelengths)
    np.testing.assert_allclose(r.transmittance + r.reflectance, 1.0, atol=1e-9)
    assert np.abs(np.diff(r.conversion)).max() < 2e-3


@pytest.mark.parametrize("n_fin", [2.0, 2.0 + 0.05j])
@pytest.mark.parametrize("harmonics", [5, 9])
def test_the_symmetric_reduction_reproduces_the_full_problem(n_fin, harmonics):
    """The two (N² + 1)/2 subspace problems against the full 2N² eigenproblem with the same
    factorisation: every output to 1e-9."""
    fast, full = (response(PAPER_FIN, n_fin, harmonics, symmetric=s) for s in (True, False))
    for name in ("t_xx", "t_yy", "conversion", "co_polarized", "transmittance", "reflectance"):
        np.testing.assert_allclose(getattr(fast, name), getattr(full, name), atol=1e-9, err_msg=name)


def full_operator(fin, harmonics, wavelength=530e-9, eps=4.0):
    """Ω² = P·Q of the full problem over [E_x; E_y] (all N × N orders each)."""
    fields = fin_modes._fields(harmonics, False, None)
    orders = torch.arange(harmonics, dtype=torch.float64) - (harmonics - 1) // 2
    kx = (orders * wavelength / fin.period_m).expand(1, harmonics, -1)
    p, q = fin_modes._layer_matrices(
        fields,
        kx,
        kx.transpose(-1, -2),
        torch.tensor([eps + 0j]),
        torch.tensor([fin.width_m / fin.period_m]),
        torch.tensor([fin.length_m / fin.period_m]),
        harmonics,
    )
    return (p @ q)[0].numpy()


def test_the_full_operator_commutes_with_the_fins_mirrors():
    """The derivation of the reduction: x → −x maps (E_x, E_y)[m, n] to (−E_x, E_y)[−m, n], y → −y
    to (E_x, −E_y)[m, −n]; both commute with Ω² to 1e-12 (relative), and so does the diagonal
    mirror (E_x, E_y)[m, n] → (E_y, E_x)[n, m] for a square fin (our x/y-symmetric factorisation)."""
    harmonics = 7
    size = harmonics * harmonics
    grid = np.arange(size).reshape(harmonics, harmonics)  # [n, m]
    flip_x, flip_y, swap = (np.eye(size)[g.ravel()] for g in (grid[:, ::-1], grid[::-1, :], grid.T))

    def blocks(a, b, c, d):
        return np.block([[a, b], [c, d]])

    zero = np.zeros((size, size))
    mirror_x, mirror_y = blocks(-flip_x, zero, zero, flip_x), blocks(flip_y, zero, zero, -flip_y)
    diagonal = blocks(zero, swap, swap, zero)
    for fin, mirrors in ((PAPER_FIN, (mirror_x, mirror_y)), (SQUARE_FIN, (mirror_x, mirror_y, diagonal))):
        omega = full_operator(fin, harmonics)
        for s in mirrors:
            assert np.abs(s @ omega @ s - omega).max() < 1e-12 * np.abs(omega).max()
    omega = full_operator(PAPER_FIN, harmonics)
    assert np.abs(diagonal @ omega @ diagonal - omega).max() > 1e-3  # the check can fail


def test_several_fins_in_one_batch_match_one_at_a_time():
    """fin_responses_symmetric over a list against separate calls: to 1e-12."""
    fins = [PAPER_FIN, SQUARE_FIN, Fin(395e-9, 600e-9, 100e-9, 250e-9)]
    count = len(WAVELENGTHS)
    batch = fin_responses_symmetric(fins, np.full(count, 2.0), np.full(count, N_SUB), WAVELENGTHS, 7)
    for fin, together in zip(fins, batch):
        alone = response(fin, harmonics=7)
        for name in ("t_xx", "t_yy", "transmittance", "reflectance"):
            np.testing.assert_allclose(getattr(together, name), getattr(alone, name), atol=1e-12, err_msg=name)
        assert together.seconds.shape == WAVELENGTHS.shape and together.harmonics == 7


def test_meent_agrees_on_the_papers_fin():
    """meent (Li's rules with its own x-then-y factorisation, optics.nanofin) at N = 17 against
    ours at N = 21, near convergence for both (their η differ by < 4e-4 at N = 21 and 25): η and
    T within 2e-3, t_xx and t_yy within 1e-2 (same conventions: phase and time sign)."""
    count = len(WAVELENGTHS)
    indices = np.full(count, 2.0, complex), np.full(count, N_SUB, complex)
    ours = fin_response_symmetric(PAPER_FIN, *indices, WAVELENGTHS, 21)
    theirs = fin_response_meent(PAPER_FIN, *indices, WAVELENGTHS, 17)
    np.testing.assert_allclose(ours.conversion, theirs.conversion, atol=2e-3)
    np.testing.assert_allclose(ours.transmittance, theirs.transmittance, atol=2e-3)
    np.testing.assert_allclose(ours.t_xx, theirs.t_xx, atol=1e-2)
    np.testing.assert_allclose(ours.t_yy, theirs.t_yy, atol=1e-2)


@pytest.mark.slow
def test_meent_agrees_at_the_same_and_at_high_order():
    """meent at N = 21 and 25 against ours at the same N: η and T within 2e-3; and converged,
    meent at N = 25 against ours at N = 31: η and T within 5e-4, t within 3e-3 (~40 s)."""
    count = len(WAVELENGTHS)
    indices = np.full(count, 2.0, complex), np.full(count, N_SUB, complex)
    ours = {n: fin_response_symmetric(PAPER_FIN, *indices, WAVELENGTHS, n) for n in (21, 25, 31)}
    theirs = {n: fin_response_meent(PAPER_FIN, *indices, WAVELENGTHS, n) for n in (21, 25)}
    for n, tolerance in ((21, 2e-3), (25, 2e-3), (31, 5e-4)):
        reference = theirs[min(n, 25)]
        np.testing.assert_allclose(ours[n].conversion, reference.conversion, atol=tolerance)
        np.testing.assert_allclose(ours[n].transmittance, reference.transmittance, atol=tolerance)
    np.testing.assert_allclose(ours[31].t_xx, theirs[25].t_xx, atol=3e-3)
    np.testing.assert_allclose(ours[31].t_yy, theirs[25].t_yy, atol=3e-3)


@pytest.mark.parametrize(
    ("fin", "harmonics", "message"),
    [
        ((395e-9, 700e-9, 400e-9, 125e-9), 5, "width: 400 nm is larger than the 395 nm period"),
        ((395e-9, -1e-9, 305e-9, 125e-9), 5, "height"),
        ((395e-9, 700e-9, 305e-9, 125e-9), 4, "an odd number"),
    ],
)
def test_bad_input_is_refused(fin, harmonics, message):
    with pytest.raises(InputError, match=message):  # a fin is checked as it is made
        response(Fin(*fin), harmonics=harmonics)


def test_the_numbers_do_not_depend_on_torch_set_num_threads():
    """pytorch/pytorch#142815: once torch.set_num_threads has been called, torch's batched LU on
    the CPU runs LAPACK's getrf from several threads at once and MKL returns invalid pivots (an
    error) or wrong numbers for matrices above ~14 × 14. fin_modes factorises one problem at a
    time on the CPU: the full path at N = 9 (324 × 324 systems, 3 wavelengths) gives the same
    numbers in a fresh process and after set_num_threads(2), to 1e-12."""
    import json
    import subprocess
    import sys

    code = (
        "import json, sys, numpy as np, torch\n"
        "if sys.argv[1] == 'set': torch.set_num_threads(2)\n"
        "from metalens_cli.optics.fin_modes import fin_response_symmetric\n"
        "from metalens_cli.optics.fin import Fin\n"
        "r = fin_response_symmetric(Fin(395e-9, 700e-9, 305e-9, 125e-9), np.full(3, 2.0), np.full(3, 1.46),"
        " np.array([457e-9, 530e-9, 628e-9]), 9, symmetric=False)\n"
        "print(json.dumps(r.conversion.tolist()))\n"
    )
    runs = [
        subprocess.run([sys.executable, "-c", code, mode], capture_output=True, text=True, timeout=120)
        for mode in ("fresh", "set")
    ]
    assert all(run.returncode == 0 for run in runs), runs[-1].stderr[-500:]
    fresh, after = (np.array(json.loads(run.stdout)) for run in runs)
    np.testing.assert_allclose(after, fresh, rtol=1e-12)
