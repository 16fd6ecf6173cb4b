"""`metalens optimize` from the command line: outputs, errors, and the run directory as a design spec."""

from __future__ import annotations

import json
from pathlib import Path

from metalens_cli.cli.main import run

TINY = Path(__file__).parents[1] / "design" / "tiny.toml"


def test_optimize_json_then_psf_scan_and_export_gds(tmp_path, capsys):
    out = tmp_path / "run"
    assert run(["optimize", str(TINY), "-o", str(out), "--steps", "2", "--json", "--quiet"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["run_dir"] == str(out) and report["settings"]["steps"] == 2
    assert run(["psf-scan", "--design", str(out), "--pixels", "16", "--wavelengths", "457nm,530nm", "-o", str(tmp_path / "p.exr"), "--json"]) == 0
    scan = json.loads(capsys.readouterr().out)
    assert scan["design"]["kind"] == "run" and len(scan["psfs"]) == 4
    assert run(["export-gds", "--design", str(out), "-o", str(tmp_path / "lens.gds"), "--json", "--quiet"]) == 0
    assert (tmp_path / "lens.gds").stat().st_size > 0


def test_invalid_preset_key_is_one_line_exit_2(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text(TINY.read_text().replace('seed = 0', 'seed = 0\ninit = "zeros"'))
    assert run(["optimize", str(bad), "-o", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "optimize.init" in err[0]


def test_existing_run_needs_resume(tmp_path, capsys):
    out = tmp_path / "run"
    assert run(["optimize", str(TINY), "-o", str(out), "--steps", "1", "--quiet"]) == 0
    assert run(["optimize", str(TINY), "-o", str(out), "--steps", "1", "--quiet"]) == 2
    assert "--resume" in capsys.readouterr().err
