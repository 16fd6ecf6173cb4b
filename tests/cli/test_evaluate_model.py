"""evaluate --task-model end to end on a small lens: the user's detector (ONNX and torch.export)
and segmenter scored against their own output on the clean scenes; a mAP of 1 on the clean
scenes, lower through a lens; labels from a folder; bad models refused before any work."""

import json

import numpy as np
import pytest
import torch
from toy_models import BrightSegmenter, CellDetector

from metalens_cli.cli.main import run

PIXELS = 160
SMALL = ["--f", "4mm", "--aperture", "0.3mm", "--pixels", str(PIXELS), "--wavelengths", "420:680:40nm"]
SMALL += ["--z-near", "45mm", "--z-far", "1m", "--limit", "2", "--seed", "0", "--obstruction", "dirt"]


def invoke(capsys, *args):
    code = run([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def _export(module, path):
    x = torch.rand(1, 3, PIXELS, PIXELS)
    if path.suffix == ".onnx":
        pytest.importorskip("onnx")
        pytest.importorskip("onnxruntime")
        torch.onnx.export(module, (x,), str(path), dynamo=False, input_names=["images"])
    else:
        torch.export.save(torch.export.export(module, (x,)), str(path))
    return path


@pytest.mark.parametrize("suffix", [".onnx", ".pt2"])
def test_detector_scores_one_on_clean_and_less_through_the_lens(capsys, tmp_path, suffix):
    model = _export(CellDetector(), tmp_path / f"detector{suffix}")
    code, stdout, stderr = invoke(
        capsys, "evaluate", "hyperbolic:532nm", *SMALL, "--images", "photos", "--task-model", model, "--json", "--quiet"
    )
    assert code == 0, stderr
    rows = json.loads(stdout)["model"]
    clean = next(r for r in rows if r["design"] == "clean")
    assert clean["map50"] == pytest.approx(1.0) and clean["map50_95"] == pytest.approx(1.0)
    raw = next(r for r in rows if r["condition"] == "obstructed")
    assert raw["map50_95"] < 1.0
    assert raw["map50_95_ci"][0] <= raw["map50_95"] <= raw["map50_95_ci"][1]


def test_segmenter_and_table(capsys, tmp_path):
    model = _export(BrightSegmenter(), tmp_path / "segmenter.pt2")
    args = ["evaluate", "hyperbolic:532nm", *SMALL, "--images", "photos", "--task-model", model, "--task-kind"]
    code, stdout, stderr = invoke(capsys, *args, "segment", "--json", "--quiet")
    assert code == 0, stderr
    rows = json.loads(stdout)["model"]
    assert next(r for r in rows if r["design"] == "clean")["miou"] == pytest.approx(1.0)
    assert all(0 <= r["iou_foreground"] <= 1 for r in rows)
    code, stdout, stderr = invoke(capsys, *args, "segment")
    assert code == 0 and "Your model" in stdout and "mIoU" in stdout


def test_labels_from_a_folder(capsys, tmp_path):
    """YOLO labels of a folder's images, framed as the images are: a box drawn in the image is
    found where its label says, so the clean scene scores mAP50 = 1."""
    import cv2

    images, labels = tmp_path / "images", tmp_path / "labels"
    images.mkdir()
    labels.mkdir()
    for k in range(2):
        image = np.full((200, 240, 3), 128, np.uint8)  # framed on the 160² sensor: scaled 0.8, cropped 16 px a side
        y, x = 60 + 20 * k, 80  # on the sensor: rows 48-64 or 64-80, columns 48-64, cells of the detector
        image[y : y + 20, x : x + 20] = 255  # one bright 20 × 20 square: 16 px on the sensor, one anchor cell
        cv2.imwrite(str(images / f"im{k}.png"), image)
        (labels / f"im{k}.txt").write_text(f"0 {(x + 10) / 240} {(y + 10) / 200} {20 / 240} {20 / 200}\n")
    model = _export(CellDetector(), tmp_path / "detector.pt2")
    code, stdout, stderr = invoke(
        capsys, "evaluate", "hyperbolic:532nm", *SMALL, "--images", images, "--task-model", model,
        "--task-labels", labels, "--json", "--quiet",
    )  # fmt: skip
    assert code == 0, stderr
    clean = next(r for r in json.loads(stdout)["model"] if r["design"] == "clean")
    assert clean["map50"] == pytest.approx(1.0)


def test_bad_model_options_exit_2_before_any_work(capsys, tmp_path):
    garbage = tmp_path / "model.pt2"
    garbage.write_bytes(b"not a model")
    flat = tmp_path / "flat.pt2"
    torch.export.save(torch.export.export(torch.nn.Flatten(), (torch.rand(1, 3, 8, 8),)), str(flat))
    import cv2

    labels, images = tmp_path / "labels", tmp_path / "images"
    labels.mkdir()
    images.mkdir()
    cv2.imwrite(str(images / "a.png"), np.full((40, 40, 3), 90, np.uint8))  # no a.txt in labels
    detector = _export(CellDetector(), tmp_path / "detector.pt2")
    for args, field in (
        (["--task-model", garbage], "--task-model"),
        (["--task-model", flat], "--task-model"),  # (N, 3·H·W): neither detection form
        (["--task-model", detector, "--task-labels", labels, "--images", images], "--task-labels"),
        (["--task-model", detector, "--task-labels", tmp_path / "none"], "--task-labels"),
    ):
        code, stdout, stderr = invoke(capsys, "evaluate", "hyperbolic:532nm", *SMALL, *args)
        assert code == 2, (args, stderr)
        assert field in stderr and "Traceback" not in stderr and stdout == ""
