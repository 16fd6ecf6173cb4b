"""Vision-task targets and their detectors: exact ground truth, a sharp capture finds every target,
blur raises size50, a grey wall gives no detections."""

import numpy as np
import pytest
import torch

from metalens_cli.analysis.size50 import size50
from metalens_cli.errors import InputError
from metalens_cli.imaging.formation import form_image
from metalens_cli.imaging.images import CleanImage, load_images
from metalens_cli.imaging.targets import INK, PAPER, TASKS, check_tasks, draw_targets, layout, render, task_sizes
from metalens_cli.imaging.task_detection import score_tasks, to_grey8

SENSOR = (384, 384)
CODES = ("markers", "qr")  # the tasks OpenCV detects (text needs RapidOCR: tests/imaging/test_text_task.py)


@pytest.fixture(scope="module")
def photos():
    return load_images("photos", SENSOR, 3, margin=4)


def test_layout_is_seeded_inside_the_sensor_and_without_overlap():
    a = layout(TASKS, SENSOR, 3, 1)
    assert [(t.key, t.footprint) for t in a] == [(t.key, t.footprint) for t in layout(TASKS, SENSOR, 3, 1)]
    assert [t.footprint for t in a] != [t.footprint for t in layout(TASKS, SENSOR, 4, 1)]
    for task in TASKS:
        sizes = sorted(t.size_px for t in a if t.task == task)
        assert np.allclose(sizes, sorted(task_sizes(task, SENSOR)), rtol=0.02)  # footprints are whole pixels
    boxes = [t.footprint for t in a]
    for i, (x0, y0, w, h) in enumerate(boxes):
        assert 0 <= x0 and x0 + w <= SENSOR[1] and 0 <= y0 and y0 + h <= SENSOR[0]
        for x1, y1, w1, h1 in boxes[i + 1 :]:
            assert x0 >= x1 + w1 or x1 >= x0 + w or y0 >= y1 + h1 or y1 >= y0 + h
    assert len({t.key for t in a}) == len(a)
    for t in a:  # the code (or ink) lies inside its footprint
        x0, y0, w, h = t.footprint
        assert (t.corners.min(0) >= [x0 - 0.5, y0 - 0.5]).all() and (t.corners.max(0) <= [x0 + w, y0 + h]).all()


def test_rendered_targets_hold_their_ink_exactly():
    """Area averaging keeps the printed ink: the footprint's mean reflectance is the cells' ink
    fraction, whatever the (fractional) size of a cell."""
    for target in layout(CODES, SENSOR, 0, 0):
        from metalens_cli.imaging.targets import _code_cells

        ink = (_code_cells(target.task, target.key) < 128).mean()
        assert render(target).mean() == pytest.approx(PAPER - (PAPER - INK) * ink, abs=2e-4)


def test_sharp_capture_finds_every_target_at_its_corners(photos):
    """Through a delta-function PSF the capture is the scene: every target is found, none wrongly,
    a marker's corners within 0.75 px of the truth (sub-pixel refinement), a QR code's within a
    module (zxing-cpp places the fourth corner from the other three)."""
    delta = torch.zeros(3, 5, 5, dtype=torch.float64)
    delta[:, 2, 2] = 1.0
    for index, image in enumerate(photos):
        targets = layout(CODES, SENSOR, 0, index)
        scene = draw_targets(image, targets)
        canvas = torch.as_tensor(scene.linear, dtype=torch.float64)
        zero = torch.zeros_like(canvas)
        capture = form_image(canvas, zero, zero[:1], delta, delta, scene.margin).unobstructed.numpy()
        np.testing.assert_allclose(capture, scene.sensor, atol=1e-6)
        for task, outcome in score_tasks(capture, targets, CODES).items():
            drawn = [t for t in targets if t.task == task]
            assert outcome.found.all() and outcome.wrong == 0, (task, outcome)
            limit = [0.75 if task == "markers" else t.size_px for t in drawn]
            assert (outcome.corner_error_px < limit).all(), (task, outcome)


def test_grey_wall_gives_no_detections():
    for level in (0.0, 0.18, 1.0):
        wall = np.full((3, *SENSOR), level, dtype=np.float32)
        for outcome in score_tasks(wall, layout(CODES, SENSOR, 0, 0), CODES).values():
            assert not outcome.found.any() and outcome.wrong == 0
    assert (to_grey8(np.full((3, 8, 8), 0.5)) == 0).all()  # no contrast to stretch: black, not noise


def test_size50_grows_with_blur(photos):
    """Gaussian blurs of σ = 0 (sharp), 1, 2, 3 px: size50 of markers never falls, and rises from sharp
    to the strongest blur."""
    import cv2

    fits = []
    for sigma in (0, 1, 2, 3):
        sizes, found, units = [], [], []
        for seed in (0, 1):
            for index, image in enumerate(photos):
                targets = layout(("markers",), SENSOR, seed, index)
                scene = draw_targets(image, targets).sensor
                if sigma:
                    scene = np.stack([cv2.GaussianBlur(c, (0, 0), sigma) for c in scene])
                outcome = score_tasks(scene, targets, ("markers",))["markers"]
                sizes += [t.size_px for t in targets]
                found += outcome.found.tolist()
                units += [(seed, index)] * len(targets)
        fits.append(size50(sizes, found, [f"{s}-{i}" for s, i in units]))
    values = [f["size50"] for f in fits]
    assert fits[0]["bound"] == "below"
    assert all(b >= a for a, b in zip(values, values[1:])), values
    assert values[-1] > 1.5 * values[0], values


def test_unknown_task_and_empty_layout():
    with pytest.raises(InputError, match="--task"):
        check_tasks(["faces"])
    assert task_sizes("qr", (96, 96)).size == 0  # no QR footprint fits a third of 96 px
    image = CleanImage("x", np.zeros((3, 8, 8), np.float32))
    assert draw_targets(image, []) is image


def test_opencv_keeps_its_contrib_modules():
    """The detectors need opencv-contrib's aruco: no other package may have installed a second cv2."""
    import cv2

    assert hasattr(cv2, "aruco") and hasattr(cv2, "QRCodeDetector")


def test_detector_image_is_the_srgb_curve_within_one_code():
    """to_grey8's table against the closed-form sRGB curve on auto-levelled luminance."""
    from metalens_cli.imaging.images import luminance
    from metalens_cli.io.image_files import linear_to_srgb

    x = np.random.default_rng(0).random((3, 128, 128)).astype(np.float32) ** 3
    y = luminance(x.astype(np.float64))
    lo, hi = np.percentile(y, (0.5, 99.5))
    exact = np.round(255 * linear_to_srgb(np.clip((y - lo) / (hi - lo), 0, 1))).astype(int)
    assert np.abs(to_grey8(x).astype(int) - exact).max() <= 1
