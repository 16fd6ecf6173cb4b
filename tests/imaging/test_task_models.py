"""A user's model: every file form gives the same output as the module it was exported from;
outputs decoded in both detection forms and both segmentation forms; bad models refused before
any work, naming --task-model."""

import sys

import numpy as np
import pytest
import torch
from toy_models import BrightSegmenter, CellDetector

from metalens_cli.errors import InputError
from metalens_cli.imaging.task_models import decode, load_task_model

SIDE = 64


def _image(seed=0):
    rng = np.random.default_rng(seed)
    image = np.full((SIDE, SIDE, 3), 120, np.uint8)
    for _ in range(4):
        y, x = rng.integers(0, SIDE - 16, 2) // 16 * 16
        image[y : y + 16, x : x + 16] = rng.choice([10, 240])
    return image


def _export(module, folder, form):
    x = torch.rand(1, 3, SIDE, SIDE)
    path = folder / f"model.{form}"
    if form == "onnx":
        pytest.importorskip("onnx")
        torch.onnx.export(module, (x,), str(path), dynamo=False, input_names=["images"])
    elif form == "pt2":
        torch.export.save(torch.export.export(module, (x,)), str(path))
    else:
        torch.jit.save(torch.jit.trace(module, (x,)), str(path))
    return path


@pytest.mark.parametrize("form", ["onnx", "pt2", "pt"])
def test_every_file_form_runs_like_the_module(tmp_path, form):
    if form == "onnx":
        pytest.importorskip("onnxruntime")
    image = _image()
    reference = CellDetector()(torch.as_tensor(image.transpose(2, 0, 1)[None], dtype=torch.float32) / 255)
    reference = decode(reference.numpy(), "detect", (SIDE, SIDE))[0]
    model = load_task_model(str(_export(CellDetector(), tmp_path, form)), "detect", check_pixels=SIDE)
    found = model(image)
    assert model.seconds > 0
    np.testing.assert_allclose(found.boxes, reference.boxes, atol=1e-4)
    np.testing.assert_allclose(found.scores, reference.scores, atol=1e-5)
    np.testing.assert_array_equal(found.classes, reference.classes)
    assert (found.scores > 0.5).sum() >= 1  # the toy detector sees the squares


def test_callable_and_fixed_boxes(tmp_path):
    model = load_task_model("toy_models:boxes_callable", "detect", check_pixels=SIDE)
    found = model(_image())
    np.testing.assert_allclose(found.boxes, [[10, 10, 30, 40]])
    assert found.classes.tolist() == [2] and found.scores.tolist() == [0.9]


def test_raw_head_is_suppressed_and_scaled():
    """Two overlapping anchors of one class: one box survives; a model that saw 32 px boxes an
    image of 64 px at twice the size."""
    head = np.zeros((1, 4 + 2, 3))
    head[0, :4, 0], head[0, 4, 0] = [10, 10, 8, 8], 0.9
    head[0, :4, 1], head[0, 4, 1] = [11, 10, 8, 8], 0.8  # IoU 0.78 with the first: suppressed
    head[0, :4, 2], head[0, 5, 2] = [11, 10, 8, 8], 0.7  # the other class: kept
    found = decode(head, "detect", (64, 64), input_hw=(32, 32))[0]
    assert found.classes.tolist() == [0, 1]
    np.testing.assert_allclose(found.boxes[0], [12, 12, 28, 28])
    padded = np.array([[[1, 2, 3, 4, 0.5, 1], [0, 0, 0, 0, 0, 0]]])  # (N, K, 6) with a padding row
    assert len(decode(padded, "detect", (8, 8))[0].scores) == 1


def test_segmentation_forms():
    scores = np.zeros((1, 3, 4, 4))
    scores[0, 2, :2] = 1.0
    assert (decode(scores, "segment", (4, 4))[0][:2] == 2).all()
    probability = np.full((1, 1, 4, 4), 0.6)
    assert (decode(probability, "segment", (8, 8))[0] == 1).all()  # resized by nearest neighbour
    logits = np.full((1, 1, 4, 4), -2.0)
    assert (decode(logits, "segment", (4, 4))[0] == 0).all()
    classes = np.arange(16).reshape(1, 4, 4)
    assert (decode(classes, "segment", (4, 4))[0] == classes[0]).all()
    seg = BrightSegmenter()(torch.full((1, 3, 4, 4), 0.9))
    assert (decode(seg.numpy(), "segment", (4, 4))[0] == 1).all()


def test_bad_models_are_refused_naming_the_option(tmp_path, monkeypatch):
    garbage = tmp_path / "model.onnx"
    garbage.write_bytes(b"not a model")
    cases = [
        (str(tmp_path / "missing.pt2"), "detect"),
        (str(garbage), "detect"),
        ("no_such_module:f", "detect"),
        ("toy_models:CELL", "detect"),  # not callable
        ("model.txt", "detect"),
        ("toy_models:boxes_callable", "segment"),  # (N, 1, 6) is no segmentation
    ]
    if not _has("onnxruntime"):
        cases.remove((str(garbage), "detect"))
    for spec, kind in cases:
        with pytest.raises(InputError) as error:
            load_task_model(spec, kind, check_pixels=SIDE)
        assert error.value.field == "--task-model", spec
    wrong = tmp_path / "wrong.pt2"
    x = torch.rand(1, 3, SIDE, SIDE)
    torch.export.save(torch.export.export(torch.nn.Flatten(), (x,)), str(wrong))  # (N, 3·H·W)
    with pytest.raises(InputError, match="returned shape"):
        load_task_model(str(wrong), "detect", check_pixels=SIDE)
    monkeypatch.setitem(sys.modules, "onnxruntime", None)  # not installed
    with pytest.raises(InputError, match=r"metalens-cli\[tasks\]"):
        load_task_model(str(garbage), "detect")
    with pytest.raises(InputError) as error:
        load_task_model("x.pt2", "classify")
    assert error.value.field == "--task-kind"


def _has(name):
    import importlib.util

    return importlib.util.find_spec(name) is not None


def test_a_model_that_refuses_a_size_says_so(tmp_path):
    """A torch.export program is specialised to its example's shape: another size is an
    InputError naming the option and the size, not a traceback."""
    model = load_task_model(str(_export(CellDetector(), tmp_path, "pt2")), "detect", check_pixels=SIDE)
    with pytest.raises(InputError, match="failed on a 48 × 48 image") as error:
        model(np.zeros((48, 48, 3), np.uint8))
    assert error.value.field == "--task-model"
