"""Canvases around the sensor: the source image supplies the margin, reflection only past its edge."""

from pathlib import Path

import numpy as np
import pytest

from metalens_cli.imaging.canvas import fit_to_canvas, narrow_margin, sensor_crop
from metalens_cli.imaging.images import load_images
from metalens_cli.imaging.obstructions import make_obstruction


def test_sensor_field_does_not_depend_on_the_margin():
    image = np.random.default_rng(1).random((3, 300, 400)).astype(np.float32)
    plain = fit_to_canvas(image, (64, 64))
    for margin in (10, 100, 200):
        canvas = fit_to_canvas(image, (64, 64), margin)
        assert canvas.shape == (3, 64 + 2 * margin, 64 + 2 * margin)
        np.testing.assert_array_equal(sensor_crop(canvas, margin), plain)


def test_a_narrower_margin_is_the_central_crop_around_the_same_field():
    """A canvas of margin 20 narrowed to 7: the (H + 14)² centre, its sensor field the same; a
    margin wider than the canvas's is refused."""
    import torch

    canvas = torch.arange(2 * 3 * 50 * 50, dtype=torch.float32).reshape(2, 3, 50, 50)  # a 10² field, margin 20
    narrow = narrow_margin(canvas, 20, 7)
    assert narrow.shape == (2, 3, 24, 24)
    assert torch.equal(sensor_crop(narrow, 7), sensor_crop(canvas, 20))
    assert torch.equal(narrow_margin(canvas, 20, 20), canvas) and torch.equal(
        narrow_margin(canvas, 20, 0), sensor_crop(canvas, 20)
    )
    with pytest.raises(ValueError, match="margin 20"):
        narrow_margin(canvas, 20, 21)


def test_margin_comes_from_the_source_then_reflection():
    """A 100 × 160 source framed on a 100 × 100 sensor: the 30 extra columns each side are the
    source's own; rows past its edge (and columns past 30) are mirror images."""
    image = np.random.default_rng(2).random((3, 100, 160)).astype(np.float32)
    canvas = fit_to_canvas(image, (100, 100), 40)
    np.testing.assert_array_equal(canvas[:, 40:140, 10:170], image)
    np.testing.assert_array_equal(canvas[:, 39, 10:170], image[:, 0, :])  # symmetric reflection at the top edge
    np.testing.assert_array_equal(canvas[:, 40:140, 9], image[:, :, 0])  # and at the left edge of the source


def test_builtin_scenes_and_file_obstructions_fill_the_canvas(tmp_path):
    import cv2

    images = load_images("all", (32, 32), margin=20)[7:11]  # photographs and charts
    assert [i.linear.shape for i in images] == [(3, 72, 72)] * 4 and images[0].sensor.shape == (3, 32, 32)
    assert all(np.isfinite(i.linear).all() and i.linear.min() >= 0 for i in images)
    opaque = np.zeros((16, 16, 4), np.uint8)
    opaque[..., 3] = 255
    opaque[..., 2] = 200
    cv2.imwrite(str(tmp_path / "cover.png"), opaque)
    obstruction = make_obstruction(f"file:{tmp_path / 'cover.png'}", (32, 32), 0.045, 4e-3, 1.85e-6, 0, margin=20)
    assert obstruction.mask.shape == (1, 72, 72) and obstruction.mask.min() == 1.0 and obstruction.coverage == 1.0


def test_image_sets_and_folders(tmp_path, monkeypatch):
    from metalens_cli.errors import InputError
    from metalens_cli.imaging.images import CHART_COUNT, PHOTOGRAPHS, image_count, image_entries

    assert image_count("photos") == len(PHOTOGRAPHS) == 9 and image_count("charts") == CHART_COUNT
    assert image_count("all") == len(PHOTOGRAPHS) + CHART_COUNT and image_count("all", limit=3) == 3
    folder = tmp_path / "photos"
    folder.mkdir()
    (folder / "a.png").write_bytes(b"")
    monkeypatch.chdir(tmp_path)
    assert image_entries("photos") == list(PHOTOGRAPHS)  # the set wins over a folder of its name
    assert image_entries("./photos") == [Path("photos/a.png")]  # the folder, written as a path
    for source, message in (
        ("", "is empty"),
        ("nowhere", "no such folder"),
        (str(tmp_path / "photos" / "a.png") + "x", "no such"),
    ):
        with pytest.raises(InputError, match=message) as error:
            image_entries(source)
        assert "photos, charts, all" in str(error.value)


def test_a_photograph_missing_from_its_package_is_one_clear_error():
    from metalens_cli.errors import InputError
    from metalens_cli.imaging.images import Photograph, photograph_path

    for package in ("skimage", "no_such_package_here"):
        with pytest.raises(InputError, match=f"not in the installed {package}"):
            photograph_path(Photograph("gone", package, "data/gone.png", "nobody", "none", (1, 1)))


def test_the_photographs_are_as_documented():
    """Every photograph of the set is where its entry says, with the size and colour docs/images.md lists."""
    from metalens_cli.imaging.images import PHOTOGRAPHS, photograph_path
    from metalens_cli.io.image_files import read_image_file

    for photo in PHOTOGRAPHS:
        pixels, names, _ = read_image_file(photograph_path(photo), photo.name)
        assert pixels.shape[:2] == photo.shape and (names[0] != "Y") == photo.colour, photo.name
