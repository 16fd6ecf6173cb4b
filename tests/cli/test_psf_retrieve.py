"""`metalens psf retrieve` end to end: a measured cube of a lens with a known defocus and spherical
aberration → the retrieved θ, a design spec the other commands take; one-line refusals with
nothing written."""

import json
import math

import numpy as np
import pytest
import torch

from metalens_cli.cli.main import run
from metalens_cli.io.designs import resolve_design
from metalens_cli.io.psf_cube_files import write_psf_cube
from metalens_cli.optics.lens import Metalens, hyperbolic
from metalens_cli.optics.psf import compute_psf
from metalens_cli.optics.sampling import PsfGrid

F, D, PITCH = 300e-6, 60e-6, 395e-9  # NA 0.1; see tests/analysis/test_phase_retrieval.py
WAVELENGTHS, DEPTHS = [500e-9, 532e-9, 570e-9], [math.inf, 2e-3]
PIXELS, PIXEL_PITCH = 40, 0.8e-6
GEOMETRY = ["--f", "300um", "--aperture", "60um", "--pitch", "395nm"]
TRUTH = (0.8, -0.5)  # rad: defocus 2ρ² − 1, primary spherical 6ρ⁴ − 6ρ² + 1


def invoke(capsys, *args):
    code = run([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def measured_psfs(wavelengths=WAVELENGTHS, depths=DEPTHS, snr=300, seed=2):
    lens = hyperbolic(532e-9, F, D, PITCH)
    rho = np.arange(lens.theta.shape[0]) * PITCH / (D / 2)
    delta = TRUTH[0] * (2 * rho**2 - 1) + TRUTH[1] * (6 * rho**4 - 6 * rho**2 + 1)
    aberrated = Metalens(lens.theta + torch.from_numpy(delta) / 2, PITCH, D, F)
    psf = compute_psf(aberrated, PsfGrid(wavelengths, depths, PIXELS, PIXEL_PITCH, F), dtype=torch.float64)
    psf = psf.psf.numpy()
    psf = psf / psf.sum(axis=(-2, -1), keepdims=True)
    sigma = psf.max(axis=(-2, -1), keepdims=True) / snr
    return (psf + np.random.default_rng(seed).normal(size=psf.shape) * sigma).astype(np.float32)


def write_cube(path, psf, wavelengths=WAVELENGTHS, depths=DEPTHS, design="lens #3", **extra):
    write_psf_cube(
        path, psf, np.array(wavelengths), np.array(depths), PIXEL_PITCH, design, normalization="sum-to-one", extra=extra
    )


def test_retrieve_from_the_header_design_then_use_the_result_as_a_design(capsys, tmp_path):
    """The header's design (as psf-scan writes it: spec and geometry) is the nominal; the result
    is a radial θ .npy that resolve_design takes with the same geometry."""
    cube = tmp_path / "measured.npz"
    header = {"spec": "hyperbolic:532nm", "f_m": F, "aperture_m": D, "pitch_m": PITCH}
    write_cube(cube, measured_psfs(), design=header)
    out_path = tmp_path / "retrieved.npy"
    code, out, err = invoke(capsys, "psf", "retrieve", cube, "-o", out_path, "--terms", "3", "--json")
    assert code == 0, err
    report = json.loads(out)  # exactly one JSON object
    assert report["design"]["spec"] == "hyperbolic:532nm" and report["converged"]
    terms = report["terms"]
    assert [t["name"] for t in terms] == ["Z(2,0) defocus", "Z(4,0) primary spherical", "Z(6,0) secondary spherical"]
    for term, truth in zip(terms, (*TRUTH, 0.0)):
        assert abs(term["coefficient_rad"] - truth) < 3 * term["sigma_rad"]
        assert term["coefficient_waves"] == pytest.approx(term["coefficient_rad"] / (2 * math.pi))
    assert len(report["psfs"]) == 6 and report["psfs"][0]["depth_m"] is None
    assert all(p["relative_l2"] < p["relative_l2_nominal"] for p in report["psfs"])
    design = resolve_design(str(out_path), f_m=F, aperture_m=D, pitch_m=PITCH)
    nominal = hyperbolic(532e-9, F, D, PITCH)
    assert design.lens.radial and design.lens.theta.shape == nominal.theta.shape
    rho = np.arange(nominal.theta.shape[0]) * PITCH / (D / 2)
    c = [t["coefficient_rad"] for t in terms]
    delta = (
        c[0] * (2 * rho**2 - 1)
        + c[1] * (6 * rho**4 - 6 * rho**2 + 1)
        + c[2] * (20 * rho**6 - 30 * rho**4 + 12 * rho**2 - 1)
    )
    np.testing.assert_allclose(design.lens.theta.numpy(), nominal.theta.numpy() + delta / 2, atol=1e-9)
    code, out, err = invoke(
        capsys,
        "psf",
        "retrieve",
        cube,
        "-o",
        tmp_path / "again.npy",
        "--design",
        "hyperbolic:532nm",
        *GEOMETRY,
        "--terms",
        "2",
        "--nuisance",
        "none",
    )
    assert code == 0, err
    assert "Z(4,0) primary spherical" in out and "rel. L2" in out


@pytest.mark.parametrize(
    ("make", "expected"),
    [
        ("single", "MEASURED: one depth and one wavelength"),
        ("nan", "holds NaN or infinity"),
        ("saturated", "MEASURED: 1 of its frames were imported with saturated pixels"),
        ("no-design", "--design: not given, and the cube's design 'lens #3' does not resolve"),
    ],
)
def test_cubes_that_cannot_constrain_the_phase_are_refused_with_nothing_written(capsys, tmp_path, make, expected):
    cube = tmp_path / "measured.npz"
    psf = np.ones((2, 3, PIXELS, PIXELS), np.float32)
    if make == "single":
        write_cube(cube, psf[:1, :1], [532e-9], [math.inf])
    elif make == "nan":
        write_cube(cube, psf)
        with np.load(cube) as members:
            arrays = dict(members)
        arrays["psf"][0, 0, 3, 3] = np.nan  # no writer writes NaN: the reader refuses the file
        np.savez(cube, **arrays)
    else:
        frames = [{"file": "a.png", "saturated_pixels": 3 if make == "saturated" else 0}]
        write_cube(cube, psf, frames=frames)
    out_path = tmp_path / "retrieved.npy"
    design = [] if make == "no-design" else ["--design", "hyperbolic:532nm", *GEOMETRY]
    code, out, err = invoke(capsys, "psf", "retrieve", cube, "-o", out_path, *design, "--json")
    assert code == 2 and out == ""
    assert expected in err and len(err.strip().splitlines()) == 1, err
    assert not out_path.exists() and list(tmp_path.iterdir()) == [cube]
