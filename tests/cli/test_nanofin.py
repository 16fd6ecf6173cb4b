"""`metalens nanofin efficiency` end to end: the JSON interface, the convergence report, errors."""

import json

import pytest

from metalens_cli.cli.main import run


def invoke(capsys, *args):
    code = run([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def test_json_interface_and_a_square_fin(capsys, tmp_path):
    code, out, err = invoke(capsys, "nanofin", "efficiency", "--wavelengths", "457nm,530nm", "--harmonics", "7", "--json",
                            "--plot", tmp_path / "nf.png")
    assert code == 0, err
    r = json.loads(out)
    assert r["wavelengths_m"] == [457e-9, 530e-9] and r["harmonics"] == 7
    for key in ("conversion_efficiency", "co_polarized", "transmittance"):
        assert len(r[key]) == 2 and all(0 <= v <= 1 for v in r[key])
    assert all(e + c <= t + 1e-12 for e, c, t in zip(r["conversion_efficiency"], r["co_polarized"], r["transmittance"]))
    assert r["material"]["name"] == "sinx" and (tmp_path / "nf.png").stat().st_size > 0
    code, out, _ = invoke(capsys, "nanofin", "efficiency", "--width", "150nm", "--length", "150nm", "--wavelengths", "530nm",
                          "--harmonics", "9", "--json")
    assert code == 0 and json.loads(out)["conversion_efficiency"][0] < 1e-5  # a square fin converts nothing


def test_auto_harmonics_report_their_convergence(capsys):
    code, out, err = invoke(capsys, "nanofin", "efficiency", "--wavelengths", "530nm", "--material", "2.0", "--tolerance", "0.01",
                            "--max-harmonics", "11", "--json")
    assert code == 0, err
    r = json.loads(out)
    table = r["convergence"]
    assert table[0]["harmonics"] == 5 and r["harmonics"] in [t["harmonics"] for t in table]
    chosen = next(k for k, t in enumerate(table) if t["harmonics"] == r["harmonics"])
    assert chosen == len(table) - 1 and abs(table[chosen]["conversion"] - table[chosen - 1]["conversion"]) < 0.01


@pytest.mark.parametrize(("args", "message"), [
    (["--width", "400nm"], "--width: 400 nm is larger than the 395 nm period"),
    (["--length", "0nm"], "--length"),
    (["--harmonics", "4"], "an odd number"),
    (["--material", "unobtainium"], "--material: 'unobtainium' is not a material"),
    (["--material", "2.0-0.1j"], "--material"),
    (["--material", "2.0", "--substrate", "tio2", "--wavelengths", "300nm"], "--substrate: 300 nm is outside the range of tio2"),
    (["--wavelengths", "1m"], "not an optical wavelength"),
    (["--harmonics", "41", "--max-memory", "1MiB"], "--max-memory"),
])
def test_bad_input_is_one_line_exit_2(capsys, args, message):
    code, out, err = invoke(capsys, "nanofin", "efficiency", *args)
    assert code == 2 and out == "" and err.count("\n") == 1 and message in err, err


def test_sweep_writes_its_map_and_recommends_a_fin(capsys, tmp_path):
    out = tmp_path / "sweep"
    code, stdout, err = invoke(capsys, "nanofin", "sweep", "--width", "250nm,300nm", "--length", "100nm,150nm", "--harmonics", "3",
                               "--band", "530nm:20nm", "-o", out, "--json")
    assert code == 0, err
    r = json.loads(stdout)
    assert sorted(p.name for p in out.iterdir()) == ["sweep.csv", "sweep.json", "sweep.npz", "sweep.png"]
    assert (out / "sweep.csv").read_text().count("\n") == 5
    c = r["recommended"]
    assert c["width_m"] in (250e-9, 300e-9) and c["length_m"] in (100e-9, 150e-9)
    assert c["converged"]["harmonics"] >= 5 and 0 < c["converged"]["conversion_efficiency"][0] < 1
    code, _, err = invoke(capsys, "nanofin", "sweep", "--width", "400nm", "--length", "100nm", "-o", tmp_path / "x")
    assert code == 2 and "--width: 400 nm is larger than the 395 nm period" in err
