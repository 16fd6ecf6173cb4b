"""evaluate --task end to end on a small lens: task rows with the clean ceiling, per-unit outcomes
in the JSON, bad tasks refused in one line before any work."""

import json

from metalens_cli.cli.main import run

SMALL = ["--f", "4mm", "--aperture", "0.3mm", "--pixels", "160", "--wavelengths", "420:680:40nm"]
SMALL += ["--z-near", "45mm", "--z-far", "1m", "--images", "photos", "--limit", "2", "--seed", "0"]


def invoke(capsys, *args):
    code = run([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def test_markers_rows_ceiling_and_units(capsys):
    code, stdout, stderr = invoke(
        capsys,
        "evaluate",
        "hyperbolic:532nm",
        *SMALL,
        "--obstruction",
        "dirt",
        "--task",
        "markers",
        "--json",
        "--quiet",
    )
    assert code == 0, stderr
    report = json.loads(stdout)
    rows = report["tasks"]
    clean = next(r for r in rows if r["design"] == "clean")
    assert clean["found_rate"] == 1.0 and clean["wrong_per_unit"] == 0.0 and clean["n"] == 2
    cells = {(r["capture"], r["condition"]) for r in rows if r["design"] == "hyperbolic:532nm"}
    assert cells == {("raw", "unobstructed"), ("raw", "obstructed")}
    for row in rows:
        assert 0.0 <= row["found_rate"] <= 1.0 and row["size_unit"] == "marker side (px)"
        assert row["targets"] == 4  # 2 units × the 2 marker sizes whose footprint fits a third of 160 px
    unit = report["units"][0]["tasks"]["markers"]
    assert len(unit["keys"]) == len(unit["sizes"]) == len(unit["obstructed"]["found"]) == 2


def test_table_shows_the_task(capsys):
    code, stdout, stderr = invoke(
        capsys, "evaluate", "hyperbolic:532nm", *SMALL, "--obstruction", "dirt", "--task", "markers"
    )
    assert code == 0, stderr
    assert "Task markers" in stdout and "clean" in stdout


def test_bad_tasks_exit_2_in_one_line(capsys, tmp_path):
    for args in (
        ["--task", "faces"],
        ["--task", "qr", "--pixels", "96"],  # no QR code fits a 96² sensor
    ):
        code, stdout, stderr = invoke(capsys, "evaluate", "hyperbolic:532nm", *SMALL, *args)
        assert code == 2, (args, stderr)
        assert "--task" in stderr and "Traceback" not in stderr and stdout == ""
        assert len(stderr.strip().splitlines()) == 1, stderr


def test_cli_task_names_are_the_cores():
    from metalens_cli.cli.evaluate import TASKS
    from metalens_cli.imaging import targets

    assert TASKS == targets.TASKS
