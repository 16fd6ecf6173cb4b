"""evaluate --task text end to end (RapidOCR installed as README says; skipped without it)."""

import json

import pytest

from metalens_cli.cli.main import run

SMALL = ["--f", "4mm", "--aperture", "0.3mm", "--pixels", "256", "--wavelengths", "420:680:40nm"]
SMALL += ["--z-near", "45mm", "--z-far", "1m", "--images", "photos", "--limit", "2", "--seed", "0"]


def test_text_rows_with_line_recall_and_cer(capsys):
    pytest.importorskip("rapidocr")
    code = run(["evaluate", "hyperbolic:532nm", *SMALL, "--obstruction", "dirt", "--task", "text", "--json", "--quiet"])
    out, err = capsys.readouterr()
    assert code == 0, err
    rows = json.loads(out)["tasks"]
    clean = next(r for r in rows if r["design"] == "clean")
    assert clean["found_rate"] >= 0.75 and clean["cer"] <= 0.25 and clean["line_recall"] >= clean["found_rate"]
    for row in rows:
        assert row["size_unit"] == "text size, em (px)" and 0 <= row["cer"] <= 1
    unit = json.loads(out)["units"][0]["tasks"]["text"]
    assert len(unit["obstructed"]["cer"]) == len(unit["keys"])
