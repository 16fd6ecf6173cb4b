"""evaluate --light/--wiener end to end on a small lens: one table per light level, verdicts,
bad levels refused in one line."""

import json

import pytest

from metalens_cli.cli.main import run

SMALL = ["--f", "4mm", "--aperture", "0.3mm", "--pixels", "32", "--wavelengths", "420:680:40nm"]
SMALL += ["--z-near", "45mm", "--z-far", "1m", "--images", "charts", "--limit", "2", "--seed", "0"]


def invoke(capsys, *args):
    code = run([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def test_light_levels_give_rows_comparisons_and_verdicts_per_level(capsys, tmp_path):
    csv = tmp_path / "rows.csv"
    code, stdout, stderr = invoke(
        capsys,
        "evaluate",
        "hyperbolic:532nm",
        "hyperbolic:630nm",
        *SMALL,
        "--obstruction",
        "dirt",
        "--light",
        "daylight,none,250",
        "--wiener",
        "--json",
        "--quiet",
        "--csv",
        csv,
    )
    assert code == 0, stderr
    report = json.loads(stdout)
    lights = ["noise-free", "250 e⁻", "20000 e⁻"]
    assert list(dict.fromkeys(r["light"] for r in report["rows"])) == lights
    # 3 levels × 2 designs × (raw, wiener) × 2 conditions
    assert len(report["rows"]) == 3 * 2 * 2 * 2 and {r["capture"] for r in report["rows"]} == {"raw", "wiener"}
    assert {c["light"] for c in report["comparisons"]} == set(lights)
    verdicts = report["verdicts"]
    assert [(v["capture"], v["obstruction"]) for v in verdicts] == [("raw", "dirt"), ("wiener", "dirt")]
    assert all(v["levels"] == [250.0, 20000.0] and "verdict" in v and "noise_free" in v for v in verdicts)
    assert report["camera"] == {"read_electrons": 2.5, "zero_order_leak": 0.01}
    assert all(len(c["wiener_mu"]) == 3 for c in report["cameras"])
    assert csv.read_text().splitlines()[0].startswith("light,design,capture")


@pytest.mark.parametrize(
    "args",
    [
        ["--light", "bright"],
        ["--light", "0"],
        ["--light", "2000", "--photons", "2000"],
        ["--zero-order-leak", "2", "--light", "2000"],
        ["--wiener", "--photons", "100"],
    ],
)
def test_bad_camera_input_is_one_line_exit_2(capsys, args):
    code, stdout, stderr = invoke(capsys, "evaluate", "hyperbolic:532nm", *SMALL, *args)
    assert code == 2 and stdout == ""
    assert len(stderr.strip().splitlines()) == 1 and stderr.startswith("metalens: error:"), stderr


def test_cli_camera_defaults_are_the_cores():
    """The CLI spells its defaults out to start without numpy; they must stay the core's."""
    from metalens_cli.cli.evaluate import evaluate
    from metalens_cli.imaging import camera

    defaults = {p.name: p.default for p in evaluate.params}
    assert defaults["read_electrons"] == camera.DEFAULT_READ_ELECTRONS
    assert defaults["zero_order_leak"] == camera.DEFAULT_ZERO_ORDER_LEAK
