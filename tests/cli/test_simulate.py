"""simulate and evaluate end to end on a small lens and 48-pixel images."""

import json

import numpy as np
import pytest

from metalens_cli.cli.main import run

SMALL = [
    "--f",
    "4mm",
    "--aperture",
    "0.3mm",
    "--pixels",
    "48",
    "--wavelengths",
    "420:680:20nm",
    "--z-near",
    "45mm",
    "--z-far",
    "1m",
]


def invoke(capsys, *args):
    code = run([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def photo_dir(tmp_path_factory):
    import cv2

    folder = tmp_path_factory.mktemp("photos")
    rng = np.random.default_rng(0)
    cv2.imwrite(str(folder / "a.png"), (rng.random((60, 80, 3)) * 255).astype(np.uint8))
    cv2.imwrite(str(folder / "b.jpg"), np.full((50, 50, 3), 128, np.uint8))
    return folder


def test_simulate_writes_outputs(capsys, tmp_path, photo_dir):
    out = tmp_path / "sim"
    code, stdout, _ = invoke(
        capsys,
        "simulate",
        "hyperbolic:532nm",
        *SMALL,
        "--images",
        photo_dir,
        "--obstruction",
        "fence",
        "-o",
        out,
        "--json",
    )
    assert code == 0
    report = json.loads(stdout)
    assert report == json.loads((out / "simulate.json").read_text())
    assert [i["name"] for i in report["images"]] == ["a", "b"]
    assert set(report["psf_energy"]["near"]) == {"R", "G", "B"}
    assert all(
        0.99 <= report["psf_energy"][d][c] <= 1.001 for d in ("near", "far") for c in "RGB"
    )  # windows hold the light
    assert report["canvas_margin_px"] == max(report["psf_window_px"].values()) // 2 and report["warnings"] == []
    for name in (
        "a_clean.png",
        "a_obstructed.exr",
        "a_unobstructed.png",
        "a_alpha.png",
        "a_obstruction.png",
        "contact_sheet.png",
    ):
        assert (out / name).stat().st_size > 0
    assert 0 < report["images"][0]["alpha_coverage"] < 1
    code, _, err = invoke(capsys, "simulate", "hyperbolic:532nm", *SMALL, "--images", photo_dir, "-o", out)
    assert (
        code == 2 and "--output: folder" in err and "'a_alpha.exr' (and" in err and "--overwrite" in err
    )  # refused before work
    code, stdout, err = invoke(
        capsys,
        "simulate",
        "hyperbolic:532nm",
        *SMALL,
        "--images",
        photo_dir,
        "--obstruction",
        "dirt",
        "-o",
        out,
        "--overwrite",
        "--json",
    )
    assert code == 0 and json.loads((out / "simulate.json").read_text())["obstruction"] == "dirt", err


def test_evaluate_json_csv_plot(capsys, tmp_path, photo_dir):
    csv, plot = tmp_path / "e.csv", tmp_path / "e.png"
    code, stdout, stderr = invoke(
        capsys,
        "evaluate",
        "hyperbolic:532nm",
        "hyperbolic:630nm",
        *SMALL,
        "--images",
        photo_dir,
        "--seed",
        "0",
        "--obstruction",
        "dirt,drops",
        "--json",
        "--csv",
        csv,
        "--plot",
        plot,
    )
    assert code == 0 and plot.stat().st_size > 0
    report = json.loads(stdout)
    assert len(report["rows"]) == 2 * 2 * 2 and report["photometric_match"] == "lstsq"
    for row in report["rows"]:
        assert set(row) == {
            "design",
            "capture",
            "obstruction",
            "condition",
            "n",
            "psnr_db",
            "psnr_db_ci",
            "ssim",
            "ssim_ci",
        }
        assert row["capture"] == "raw"  # no --recon
        assert row["condition"] in ("unobstructed", "obstructed") and row["psnr_db"] > 0 and -1 <= row["ssim"] <= 1
        assert row["n"] == 2 and row["psnr_db_ci"][0] <= row["psnr_db"] <= row["psnr_db_ci"][1]
    assert len(report["units"]) == 2 * 2 * 2 and len(report["comparisons"]) == 2 * 3 * 2  # kinds × conditions × metrics
    assert (
        csv.read_text().splitlines()[0]
        == "design,capture,obstruction,condition,n,psnr_db,psnr_db_lo,psnr_db_hi,ssim,ssim_lo,ssim_hi"
    )
    assert "LPIPS" in stderr and "2 units per cell (2 image(s) × 1 seed(s)), fewer than 20" in stderr


def test_evaluate_table(capsys):
    code, stdout, _ = invoke(
        capsys, "evaluate", "hyperbolic:532nm", *SMALL, "--obstruction", "rain", "--limit", "1", "--seed", "0:1"
    )
    assert code == 0 and "Raw Δ" in stdout and "1 images × 2 seeds" in stdout


PAPER_LENS = [
    "--f",
    "4mm",
    "--aperture",
    "2.516mm",
    "--pitch",
    "395nm",
    "--pixels",
    "48",
    "--wavelengths",
    "420:680:20nm",
    "--z-near",
    "45mm",
    "--z-far",
    "1m",
]


@pytest.fixture(scope="module")
def grey_wall(tmp_path_factory):
    """The issue's case: a grey PNG (value 128) and fully transparent / fully opaque RGBA covers."""
    import cv2

    folder = tmp_path_factory.mktemp("wall")
    cv2.imwrite(str(folder / "grey.png"), np.full((128, 128, 3), 128, np.uint8))
    cv2.imwrite(str(folder / "clear.png"), np.zeros((128, 128, 4), np.uint8))
    cover = np.zeros((128, 128, 4), np.uint8)
    cover[..., :3], cover[..., 3] = (30, 60, 60), 255  # BGR: a brownish cover, opaque
    cv2.imwrite(str(folder / "opaque.png"), cover)
    return folder


def _learned_like(path):
    """A radial θ(r) unlike any closed form: the hyperbolic profile plus smooth random ripples of
    ±2 rad (what a learned design looks like to the optics), saved as a design .npy."""
    from metalens_cli.optics.lens import hyperbolic

    theta = hyperbolic(532e-9, 4e-3, 2.516e-3, 395e-9).theta.numpy()
    r = np.linspace(0, 1, theta.size)
    ripples = sum(np.random.default_rng(k).normal() * np.sin((k + 1) * np.pi * r) for k in range(12))
    np.save(path, theta + 2 * ripples / np.abs(ripples).max())
    return path


@pytest.mark.parametrize("design", ["hyperbolic", "learned"])
def test_grey_wall_is_grey_and_an_opaque_cover_hides_it(capsys, tmp_path, grey_wall, design):
    """Through the paper's lens (near blur ≈ 120-330 px on a 48-px sensor): a grey wall images as
    the same grey at every pixel, behind a clear cover too; an opaque cover leaves only its colour."""
    from metalens_cli.io.image_files import read_exr_rgb, srgb_to_linear

    spec = "hyperbolic:532nm" if design == "hyperbolic" else str(_learned_like(tmp_path / "theta.npy"))
    grey = float(srgb_to_linear(np.array(128 / 255)))
    for cover, out in (("clear", tmp_path / "clear"), ("opaque", tmp_path / "opaque")):
        code, _, _ = invoke(
            capsys,
            "simulate",
            spec,
            *PAPER_LENS,
            "--images",
            grey_wall / "grey.png",
            "--obstruction",
            f"file:{grey_wall / f'{cover}.png'}",
            "-o",
            out,
        )
        assert code == 0
        unobstructed, obstructed = (read_exr_rgb(out / f"grey_{c}.exr") for c in ("unobstructed", "obstructed"))
        alpha = read_exr_rgb(out / "grey_alpha.exr")
        np.testing.assert_allclose(unobstructed, grey, rtol=5e-3)  # the bound: 0.5 % at every pixel
        if cover == "clear":
            np.testing.assert_allclose(obstructed, grey, rtol=5e-3)
            np.testing.assert_allclose(alpha, 0.0, atol=1e-3)
        else:
            colour = srgb_to_linear(np.array([60, 60, 30]) / 255)[:, None, None]  # RGB of the cover
            np.testing.assert_allclose(alpha, 1.0, atol=1e-3)
            np.testing.assert_allclose(obstructed, np.broadcast_to(colour, obstructed.shape), rtol=1e-2)


@pytest.mark.parametrize(
    "args",
    [
        ["simulate", "hyperbolic:532nm", *SMALL, "--obstruction", "mud", "-o", "x"],
        ["evaluate", "hyperbolic:532nm", *SMALL, "--images", "/nonexistent"],
        ["evaluate", "nonsense", *SMALL],
        ["simulate", "hyperbolic:532nm", *SMALL, "--z-near", "2m", "-o", "x"],
        ["evaluate", "hyperbolic:532nm", *SMALL, "--field", "auto", "--field-tolerance", "0"],
        ["simulate", "hyperbolic:532nm", *SMALL, "--field-tolerance", "1%", "-o", "x"],
    ],
)
def test_bad_input_one_line_exit_2(capsys, args):
    code, stdout, stderr = invoke(capsys, *args)
    assert code == 2 and stdout == ""
    assert len(stderr.strip().splitlines()) == 1 and stderr.startswith("metalens: error:")


def test_obstruction_preview_sheet(capsys, tmp_path):
    sheet = tmp_path / "sheet.png"
    code = run(
        [
            "obstruction",
            "preview",
            "--kinds",
            "dirt,fence",
            "--z-near",
            "40mm,50mm",
            "--pixels",
            "64",
            "--pixel-pitch",
            "14.8um",
            "-o",
            str(sheet),
            "--json",
        ]
    )
    report = json.loads(capsys.readouterr().out)
    assert code == 0 and sheet.read_bytes()[:4] == b"\x89PNG"
    assert [(o["kind"], o["depth_m"]) for o in report["obstructions"]] == [
        ("dirt", 0.04),
        ("fence", 0.04),
        ("dirt", 0.05),
        ("fence", 0.05),
    ]
    dirt = [o["coverage"] for o in report["obstructions"] if o["kind"] == "dirt"]
    assert all(0.15 <= c <= 0.35 for c in dirt)  # the default configured coverage range


def test_cli_choices_match_the_core():
    """The CLI spells the choices out to start without torch; they must stay the core's."""
    from metalens_cli.cli.evaluate import MATCH_METHODS
    from metalens_cli.cli.simulate import FORMATIONS
    from metalens_cli.imaging import formation, metrics

    assert FORMATIONS == formation.FORMATIONS and MATCH_METHODS == metrics.MATCH_METHODS


def test_evaluate_defaults_give_enough_units(capsys):
    """The default set (the photographs) × the default seeds (0:2) gives ≥ 20 units per cell, so
    no few-units warning; the least-squares match is the default."""
    code, stdout, stderr = invoke(
        capsys, "evaluate", "hyperbolic:532nm", *SMALL, "--obstruction", "dirt", "--json", "--quiet"
    )
    assert code == 0, stderr
    report = json.loads(stdout)
    assert (
        report["images"][:2] == ["astronaut", "chelsea"] and len(report["images"]) == 9 and report["seeds"] == [0, 1, 2]
    )
    assert {row["n"] for row in report["rows"]} == {27} and report["photometric_match"] == "lstsq"
    assert not any("units per cell" in w for w in report["warnings"])


def test_simulate_quiet_says_nothing_and_reports_the_resolved_device(capsys, tmp_path, photo_dir):
    args = ["simulate", "hyperbolic:532nm", *SMALL, "--images", photo_dir, "--device", "auto", "--json"]
    code, stdout, err = invoke(capsys, *args, "-o", tmp_path / "quiet", "--quiet")
    assert code == 0 and err == ""
    assert json.loads(stdout)["device"] == "cpu"  # auto, resolved on a machine without a GPU


def test_simulate_reports_progress_per_image(capsys, tmp_path, photo_dir, monkeypatch):
    """The core calls back before the first image and after each; the command draws the bar on
    a terminal's stderr (here a captured stderr that says it is one) unless --quiet."""
    from contextlib import contextmanager

    from metalens_cli.cli import progress, simulate

    calls, real = [], progress.progress_bar

    @contextmanager
    def recording(description, quiet=False):
        with real(description, quiet) as update:

            def both(done, total):
                calls.append((description, quiet, done, total))
                update(done, total)

            yield both

    monkeypatch.setattr(simulate, "progress_bar", recording)
    monkeypatch.setattr(progress.sys.stderr, "isatty", lambda: True, raising=False)
    args = ["simulate", "hyperbolic:532nm", *SMALL, "--images", photo_dir, "--json"]
    code, stdout, err = invoke(capsys, *args, "-o", tmp_path / "shown")
    assert code == 0 and json.loads(stdout)["images"]
    assert calls == [("simulate", False, 0, 2), ("simulate", False, 1, 2), ("simulate", False, 2, 2)]
    assert "simulate" in err  # the bar (rich, transient) was drawn on stderr
    calls.clear()
    code, _, err = invoke(capsys, *args, "-o", tmp_path / "quiet", "--quiet")
    assert code == 0 and err == "" and [c[1] for c in calls] == [True] * 3
