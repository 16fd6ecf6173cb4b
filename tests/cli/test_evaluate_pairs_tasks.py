"""`metalens board` and `evaluate --pairs DIR --task`: a printed board photographed through two
lenses (synthetic: the board warped by a known homography, blurred, one lens sharper), each
capture registered onto the board and scored against its layout."""

import json

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter
from synthetic import save_png, warp

from metalens_cli.cli.main import run
from metalens_cli.io.image_files import linear_to_srgb, srgb_to_linear

SIDE = 384
HOMOGRAPHY = np.array([[1.01, 0.02, -5.0], [-0.015, 0.995, 3.0], [1e-5, -1e-5, 1.0]])
BLUR = {"sharp": 0.7, "blurry": 3.0}


def invoke(capsys, *args):
    code = run([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    import cv2

    root = tmp_path_factory.mktemp("board")
    (root / "gt").mkdir()
    for k in range(2):
        code = run(["board", "-o", str(root / "gt" / f"board{k}.png"), "--pixels", str(SIDE), "--seed", str(k)])
        assert code == 0
        board = srgb_to_linear(cv2.imread(str(root / "gt" / f"board{k}.png"))[:, :, ::-1] / 255.0)
        for design, sigma in BLUR.items():
            capture = warp(gaussian_filter(board, (sigma, sigma, 0)), HOMOGRAPHY, ripple_px=0.5)
            shade = np.ones((SIDE, SIDE, 1))
            shade[: SIDE // 3, : SIDE // 3] = 0.3  # a dark corner: the obstruction
            for condition, image in (("unobstructed", capture), ("obstructed", capture * shade)):
                save_png(root / design / condition / f"board{k}.png", linear_to_srgb(np.clip(image, 0, 1)), bits=16)
    return root


def test_board_writes_image_and_layout(bench):
    layout = json.loads((bench / "gt" / "board0.targets.json").read_text())
    assert layout["format"] == "metalens-targets/1" and layout["pixels"] == [SIDE, SIDE]
    assert {t["task"] for t in layout["targets"]} == {"markers", "qr"}


def test_pairs_tasks_found_through_the_sharper_lens(capsys, bench):
    code, stdout, stderr = invoke(capsys, "evaluate", "--pairs", bench, "--task", "markers,qr", "--json", "--quiet")
    assert code == 0, stderr
    rows = json.loads(stdout)["tasks"]

    def found(task, design, condition):
        return next(r for r in rows if (r["task"], r["design"], r["condition"]) == (task, design, condition))

    for task in ("markers", "qr"):
        clean = next(r for r in rows if r["task"] == task and r["design"] == "clean")
        assert clean["wrong_per_unit"] == 0.0 and clean["found_rate"] == 1.0  # the board itself
        sharp = found(task, "sharp", "unobstructed")
        assert sharp["found_rate"] >= found(task, "blurry", "unobstructed")["found_rate"]
    # registration puts the targets where the layout says: the sharper lens's markers are found, in place
    markers = found("markers", "sharp", "unobstructed")
    assert markers["found_rate"] >= 0.75 and markers["corner_error_px"] < 1.0, markers


def test_pairs_without_a_layout_exit_2(capsys, bench, tmp_path):
    import shutil

    copy = tmp_path / "bench"
    shutil.copytree(bench, copy)
    (copy / "gt" / "board1.targets.json").unlink()
    code, stdout, stderr = invoke(capsys, "evaluate", "--pairs", copy, "--task", "markers")
    assert code == 2 and "--task" in stderr and "board1.targets.json" in stderr


def test_board_imports_no_torch(tmp_path):
    import subprocess
    import sys

    code = (
        "import sys; from metalens_cli.cli.main import run; rc = run(sys.argv[1:]); "
        "sys.stderr.write(repr('torch' in sys.modules)); sys.exit(rc)"
    )
    args = ["board", "-o", str(tmp_path / "b.png"), "--pixels", "200"]
    proc = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0 and proc.stderr.endswith("False"), proc.stderr


def test_pairs_with_your_model(capsys, bench):
    """A detector (a callable here) on the registered captures, its truth its own output on the
    board: mAP 1 there, and no better through the blurry lens than through the sharp one."""
    args = ["evaluate", "--pairs", bench, "--task-model", "toy_models:cell_detector", "--json", "--quiet"]
    code, stdout, stderr = invoke(capsys, *args)
    assert code == 0, stderr
    rows = json.loads(stdout)["model"]
    assert next(r for r in rows if r["design"] == "clean")["map50_95"] == pytest.approx(1.0)

    def score(design):
        return next(r for r in rows if (r["design"], r["condition"]) == (design, "unobstructed"))["map50_95"]

    assert score("sharp") >= score("blurry")
