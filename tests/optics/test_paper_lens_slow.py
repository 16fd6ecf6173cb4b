"""The paper's full lens (f = 4 mm, D = 2.516 mm, NA 0.3) through every propagator: slow checks.

Run with `pytest -m slow` (CI's second step). Tolerances come from docs/benchmarks.md, where
the same comparisons measured 4.7e-4 (radial vs rs) and 9.4e-4 (asm vs radial ×2).
"""

import math

import pytest
import torch

from metalens_cli.imaging.psf_scan import relative_l2
from metalens_cli.optics.lens import hyperbolic
from metalens_cli.optics.psf import compute_psf
from metalens_cli.optics.sampling import PsfGrid

pytestmark = pytest.mark.slow
LENS = dict(lambda_d_m=532e-9, focal_length_m=4e-3, aperture_m=2.516e-3, pitch_m=395e-9)


def test_radial_matches_rayleigh_sommerfeld_on_sharp_psf():
    # The hard case: the in-focus far PSF, core below one 1.85 µm pixel. rs is direct
    # integration in float64 (independent code); compared on the central 33² pixels.
    lens = hyperbolic(**LENS)
    radial = compute_psf(lens, PsfGrid([532e-9], [math.inf], 33, 1.85e-6)).psf[0, 0].numpy()
    exact = (
        compute_psf(lens, PsfGrid([532e-9], [math.inf], 33, 1.85e-6), propagator="rs", dtype=torch.float64)
        .psf[0, 0]
        .numpy()
    )
    assert relative_l2(radial, exact) < 1e-3


def test_asm_on_2d_map_matches_radial_over_whole_window():
    # The 2-D band-limited ASM on the meta-atom grid against the radial path at doubled sampling,
    # whole 512² window; the grid's staircase pupil edge limits agreement to ~1e-3.
    lens_2d = hyperbolic(**LENS, radial=False)
    asm = compute_psf(lens_2d, PsfGrid([532e-9], [math.inf], 512, 1.85e-6), propagator="asm").psf[0, 0].numpy()
    reference = (
        compute_psf(hyperbolic(**LENS), PsfGrid([532e-9], [math.inf], 512, 1.85e-6), oversample=2.0).psf[0, 0].numpy()
    )
    assert relative_l2(asm, reference) < 2e-3
