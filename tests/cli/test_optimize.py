"""`metalens optimize` from the command line: outputs, errors, and the run directory as a design spec."""

from __future__ import annotations

import json
from pathlib import Path

from metalens_cli.cli.main import run

TINY = Path(__file__).parents[1] / "design" / "tiny.toml"


def test_optimize_json_then_psf_scan_and_export_gds(tmp_path, capsys):
    out = tmp_path / "run"
    assert run(["optimize", str(TINY), "-o", str(out), "--steps", "2", "--device", "auto", "--json", "--quiet"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["run_dir"] == str(out) and report["settings"]["steps"] == 2
    assert report["settings"]["device"] == "cpu"  # auto, resolved on a machine without a GPU
    assert (
        run(
            [
                "psf-scan",
                "--design",
                str(out),
                "--pixels",
                "16",
                "--wavelengths",
                "457nm,530nm",
                "-o",
                str(tmp_path / "p.exr"),
                "--json",
            ]
        )
        == 0
    )
    scan = json.loads(capsys.readouterr().out)
    assert scan["design"]["kind"] == "run" and len(scan["psfs"]) == 4
    assert run(["export-gds", "--design", str(out), "-o", str(tmp_path / "lens.gds"), "--json", "--quiet"]) == 0
    assert (tmp_path / "lens.gds").stat().st_size > 0


def test_invalid_preset_key_is_one_line_exit_2(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text(TINY.read_text().replace("seed = 0", 'seed = 0\ninit = "zeros"'))
    assert run(["optimize", str(bad), "-o", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "optimize.init" in err[0]


def test_existing_run_needs_resume(tmp_path, capsys):
    out = tmp_path / "run"
    assert run(["optimize", str(TINY), "-o", str(out), "--steps", "1", "--quiet"]) == 0
    assert run(["optimize", str(TINY), "-o", str(out), "--steps", "1", "--quiet"]) == 2
    assert "--resume" in capsys.readouterr().err


def test_training_raises_unobstructed_psnr_on_held_out_images(tmp_path, capsys):
    """Learning is judged on images it never saw, not on its loss: a tiny lens started from a
    random profile (blurry) and trained 15 steps images the built-in held-out set better than
    the same profile untrained (0 steps), unobstructed PSNR over the same units."""
    preset = tmp_path / "random.toml"
    preset.write_text(
        TINY.read_text()
        .replace("seed = 0", 'seed = 0\ninit = "random"\ntheta_basis = "spline"\ndesign_grid = 16')
        .replace("learning_rate = 0.05", "learning_rate = 0.2")
        .replace("t_max = 6", "t_max = 15")
    )
    scores = {}
    for steps in (0, 15):
        out = tmp_path / f"run{steps}"
        assert run(["optimize", str(preset), "-o", str(out), "--steps", str(steps), "--quiet"]) == 0
        capsys.readouterr()
        assert (
            run(["evaluate", str(out), "--pixels", "32", "--obstruction", "dirt", "--limit", "8", "--json", "--quiet"])
            == 0
        )
        rows = json.loads(capsys.readouterr().out)["rows"]
        scores[steps] = next(r["psnr_db"] for r in rows if r["condition"] == "unobstructed")
    assert scores[15] > scores[0] + 0.5
