"""The command line: JSON contracts, exit codes, one-line errors, startup without torch."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from metalens_cli.cli.main import run

PRESETS = Path(__file__).parents[2] / "presets"
PAPER_BANDS = ["--band", "457nm:22nm", "--band", "530nm:20nm", "--band", "628nm:28nm"]


def invoke(capsys, *args):
    code = run([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def test_symmetry_json_keys(capsys):
    code, out, err = invoke(
        capsys,
        "symmetry",
        "--f",
        "4mm",
        "--lambda-d",
        "450nm",
        "--wavelength",
        "440nm,450nm,530nm",
        "--depth",
        "45mm,inf",
        "--delta-z",
        "5mm",
        "--at-depth",
        "45mm",
        "--json",
    )
    assert code == 0 and err == ""
    data = json.loads(out)
    assert set(data) == {"f_m", "lambda_d_m", "rows", "focused_wavelengths", "delta"}
    assert [r["depth_m"] for r in data["rows"]] == [None, None, pytest.approx(0.0225)]
    assert data["focused_wavelengths"][1] == {"depth_m": None, "wavelength_m": 450e-9}
    assert data["delta"]["delta_wavelength_m"] == pytest.approx(-5e-9)


def test_symmetry_default_grid_from_preset(capsys):
    code, out, _ = invoke(capsys, "symmetry", "--preset", PRESETS / "hyperbolic-532.toml", "--json")
    data = json.loads(out)
    assert code == 0 and data["lambda_d_m"] == 532e-9 and len(data["rows"]) == 31


def test_symmetry_table_says_no_real_depth(capsys):
    code, out, _ = invoke(capsys, "symmetry", "--f", "4mm", "--lambda-d", "450nm", "--wavelength", "440nm")
    assert code == 0 and "no real depth" in out


def test_explicit_option_overrides_preset(capsys):
    _, out, _ = invoke(capsys, "symmetry", "--preset", PRESETS / "hyperbolic-532.toml", "--lambda-d", "450nm", "--json")
    assert json.loads(out)["lambda_d_m"] == 450e-9


def test_bands_check_paper_passes(capsys):
    code, out, _ = invoke(capsys, "bands", "check", "--preset", PRESETS / "split-spectrum.toml", "--json")
    data = json.loads(out)
    assert code == 0 and data["ok"] is True
    assert set(data) >= {"ok", "s", "conditions", "z_near_window_m", "f_window_m"}
    assert set(data["conditions"][0]) >= {"name", "lhs_m", "rhs_m", "margin_m", "ok"}


def test_bands_check_failure_exits_1_and_names_condition(capsys):
    code, out, _ = invoke(capsys, "bands", "check", *PAPER_BANDS, "--f", "4mm", "--z-near", "100mm")
    assert code == 1
    assert "Failing:" in out and "B.min_into_stop" in out


@pytest.mark.parametrize(
    "args, option",
    [
        (["symmetry", "--f", "4", "--lambda-d", "450nm"], "--f"),
        (["symmetry", "--f", "4mm", "--lambda-d", "450parsecs"], "--lambda-d"),
        (["symmetry", "--f", "-4mm", "--lambda-d", "450nm"], "--f"),
        (["symmetry", "--f", "4mm"], "--lambda-d"),
        (["bands", "check", "--band", "457nm", "--f", "4mm", "--z-near", "45mm"], "--band"),
        (["bands", "check", *PAPER_BANDS, "--f", "4mm", "--z-near", "nan"], "--z-near"),
        (["bands", "check", "--preset", "/nonexistent.toml"], "preset"),
        (["bands", "check", "--preset", str(PRESETS / "hyperbolic-532.toml")], "--band"),
    ],
)
def test_bad_input_one_line_exit_2(capsys, args, option):
    code, out, err = invoke(capsys, *args)
    assert code == 2 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("metalens: error:") and option in lines[0]
    assert "Traceback" not in err


def test_preset_show_json(capsys):
    code, out, _ = invoke(capsys, "preset", "show", PRESETS / "split-spectrum.toml", "--json")
    data = json.loads(out)
    assert (
        code == 0
        and data["lens"]["focal_length_m"] == 0.004
        and data["filter"]["centers_m"] == [457e-9, 530e-9, 628e-9]
    )


def test_plots_written(capsys, tmp_path):
    sym, bands = tmp_path / "sym.png", tmp_path / "bands.png"
    assert (
        invoke(capsys, "symmetry", "--f", "4mm", "--lambda-d", "450nm", "--z-near", "45mm", "--plot", sym, "--json")[0]
        == 0
    )
    assert (
        invoke(capsys, "bands", "check", "--preset", PRESETS / "split-spectrum.toml", "--plot", bands, "--json")[0] == 0
    )
    for path in (sym, bands):
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bands.png", "sym.png"]  # no temp files left


@pytest.mark.parametrize(
    "args, heavy",
    [
        (["--help"], "[]"),
        (["symmetry", "--f", "4mm", "--lambda-d", "450nm", "--json"], "[]"),
        (
            [
                "bands",
                "check",
                "--band",
                "457nm:22nm",
                "--band",
                "530nm:20nm",
                "--band",
                "628nm:28nm",
                "--f",
                "4mm",
                "--z-near",
                "45mm",
                "--json",
            ],
            "[]",
        ),
        (
            ["bands", "check", "--preset", str(PRESETS / "split-spectrum.toml"), "--json"],
            "['numpy']",
        ),  # it reports the preset's η(λ)
    ],
)
def test_closed_form_commands_do_not_import_torch(args, heavy):
    code = (
        "import sys; from metalens_cli.cli.main import run; rc = run(sys.argv[1:]); "
        "heavy = sorted({'torch', 'numpy', 'matplotlib'} & set(sys.modules)); "
        "sys.stderr.write(repr(heavy)); sys.exit(rc)"
    )
    proc = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0 and proc.stderr.endswith(heavy), proc.stderr


def test_installed_entry_point_subprocess():
    exe = shutil.which("metalens", path=os.path.dirname(sys.executable)) or shutil.which("metalens")
    assert exe is not None, "the metalens console script is not installed (pip install -e .)"
    proc = subprocess.run(
        [exe, "bands", "check", "--preset", str(PRESETS / "split-spectrum.toml"), "--json"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0 and json.loads(proc.stdout)["ok"] is True
    proc = subprocess.run([exe, "symmetry", "--f", "4"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and proc.stdout == ""


def test_python_dash_m():
    proc = subprocess.run(
        [sys.executable, "-m", "metalens_cli", "--version"], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 0 and "metalens" in proc.stdout


def test_symmetry_validate_json(capsys, tmp_path):
    plot = tmp_path / "map.png"
    code, out, _ = invoke(
        capsys,
        "symmetry",
        "--f",
        "4mm",
        "--lambda-d",
        "450nm",
        "--validate",
        "--aperture",
        "0.2mm",
        "--wavelength",
        "440nm,500nm,600nm",
        "--json",
        "--plot",
        plot,
    )
    validation = json.loads(out)["validation"]
    assert code == 0 and plot.exists()
    assert [set(r) for r in validation["rows"]] == [
        {"wavelength_m", "model_depth_m", "best_depth_m", "rel_deviation"}
    ] * 3
    assert validation["rows"][0]["model_depth_m"] is None
    assert validation["max_abs_rel_deviation"] < 1e-3  # NA 0.025: paraxial


def test_symmetry_validate_needs_aperture(capsys):
    code, _, err = invoke(capsys, "symmetry", "--f", "4mm", "--lambda-d", "450nm", "--validate")
    assert code == 2 and "--aperture" in err


def test_preset_show_reads_reconstruction_presets(capsys):
    code, out, err = invoke(capsys, "preset", "show", PRESETS / "quick-reconstruct.toml", "--json")
    data = json.loads(out)
    assert code == 0 and err == "" and set(data) >= {"network", "train", "data"} and data["train"]["steps"] == 2000


def test_help_names_the_environment_variables(capsys):
    code, out, _ = invoke(capsys, "--help")
    assert code == 0 and "Environment:" in out
    for name in ("METALENS_CACHE", "METALENS_DEEPLAB_WEIGHTS", "METALENS_TRACEBACK", "_METALENS_COMPLETE"):
        assert name in out
    for command in (["evaluate"], ["reconstruct", "train"]):
        code, out, _ = invoke(capsys, *command, "--help")
        assert code == 0 and "[env var: METALENS_LPIPS_WEIGHTS]" in " ".join(out.split())


def test_an_option_s_environment_variable_is_read_as_the_option(capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("METALENS_LPIPS_WEIGHTS", str(tmp_path / "gone"))
    code, out, err = invoke(capsys, "evaluate", "hyperbolic:532nm", "--pixels", "32")
    assert code == 2 and out == "" and err.count("\n") == 1
    assert "--lpips-weights" in err and "METALENS_LPIPS_WEIGHTS" in err and "does not exist" in err


def test_shell_completion_lists_commands_and_devices():
    env = {**os.environ, "_METALENS_COMPLETE": "bash_complete", "COMP_WORDS": "metalens sim", "COMP_CWORD": "1"}
    code = "import sys; sys.argv[0] = 'metalens'; from metalens_cli.cli.main import cli; cli()"
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0 and proc.stdout.split() == ["plain,simulate"]
    env.update(COMP_WORDS="metalens psf-scan --device ", COMP_CWORD="3")
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
    assert proc.stdout.split() == ["plain,auto", "plain,cpu", "plain,cuda", "plain,mps"]
