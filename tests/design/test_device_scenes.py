"""Scenes and obstructions drawn with torch on the run's device (``design.device_scenes``): against
the host's noise and obstructions, against painting every shape in turn, and on a device whose
tensors hold no values (nothing read back)."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch

from metalens_cli.design import device_scenes
from metalens_cli.design.scenes import _colour, colours
from metalens_cli.design.step import scenes_on_device, step_batch
from metalens_cli.errors import InputError
from metalens_cli.imaging.noise import fractal_noise, perlin
from metalens_cli.imaging.obstructions import make_obstruction
from metalens_cli.io.presets import load_preset

TINY = Path(__file__).with_name("tiny.toml")


@pytest.fixture(scope="module")
def tiny():
    return load_preset(TINY)


def _with(preset, **changes):
    return dataclasses.replace(preset, optimize=dataclasses.replace(preset.optimize, **changes))


def test_colours_drawn_as_arrays_are_the_hosts():
    """``design.scenes.colours`` (numpy, element-wise) of one colour draws ``_colour``'s numbers
    (``colorsys``), bit for bit, over 2000 draws."""
    a, b = np.random.default_rng(4), np.random.default_rng(4)
    for _ in range(2000):
        np.testing.assert_array_equal(colours(a, 1)[0], _colour(b))


def test_noise_is_the_hosts():
    """The lattice draws of ``imaging.noise``: Perlin noise within float32 rounding (measured
    3e-6); a fractal sum that needs no resize (finest cell under 8 px) within 1e-5 (measured 1.2e-5
    before rounding to the tolerance's scale), and either draws as many numbers as the host's."""
    a, b = np.random.default_rng(1), np.random.default_rng(1)
    assert np.abs(perlin((100, 120), 7.3, a) - device_scenes.perlin((100, 120), 7.3, b, "cpu").numpy()).max() < 1e-5
    assert a.random() == b.random()
    a, b = np.random.default_rng(2), np.random.default_rng(2)
    host, device = fractal_noise((300, 300), 5.0, 3, a), device_scenes.fractal((300, 300), 5.0, 3, b, "cpu").numpy()
    assert np.abs(host - device).max() < 5e-5 and a.random() == b.random()
    a, b = np.random.default_rng(3), np.random.default_rng(3)
    fractal_noise((300, 300), 80.0, 3, a), device_scenes.fractal((300, 300), 80.0, 3, b, "cpu")
    assert a.random() == b.random()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_layers_paint_as_painting_every_shape(seed):
    """Each pixel painted by its ``LAYERS`` topmost shapes equals painting every shape in turn
    (relative L2 0 on these scenes, measured; 4e-5 to 9e-4 with 3 layers, 5e-3 to 1.2e-2 with 2),
    and a single layer is visibly wrong (the test can fail). Keeping the samples no layer uses (an
    accelerator's way) paints the same image, bit for bit."""
    shapes = device_scenes.draw_shapes((300, 300), 220, (8, 8, 292, 292), np.random.default_rng(seed))
    generator = torch.Generator().manual_seed(seed)
    background, fine = torch.rand(3, 300, 300, generator=generator), 0.3 * torch.randn(300, 300, generator=generator)
    exact = device_scenes.paint_every_shape(background, fine, shapes)

    def error(layers):
        return float((device_scenes.composite(background, fine, shapes, layers) - exact).norm() / exact.norm())

    assert error(device_scenes.LAYERS) < 1e-5
    assert error(1) > 1e-2
    kept = device_scenes.composite(background, fine, shapes, drop=False)  # an accelerator's way: nothing dropped
    assert torch.equal(kept, device_scenes.composite(background, fine, shapes, drop=True))


def test_grey_shapes_on_a_grey_wall_stay_grey_and_an_opaque_cover_hides_them():
    """Painting conserves: grey shapes without texture or shading over a grey background leave
    every pixel that grey (each pixel's weights sum to one, edges and layers included); a
    rectangle over the whole canvas on top shows its colour alone, whatever lies below."""
    shapes = device_scenes.draw_shapes((200, 200), 150, (8, 8, 192, 192), np.random.default_rng(5))
    n = len(shapes.r)
    flat = dataclasses.replace(shapes, colour=np.full((n, 3), 0.18), texture=np.zeros(n), slope=np.zeros(n))
    wall = torch.full((3, 200, 200), 0.18)
    fine = torch.randn(200, 200)
    assert float((device_scenes.composite(wall, fine, flat) - 0.18).abs().max()) < 1e-6
    cover = dataclasses.replace(
        shapes,
        **{
            f: np.append(getattr(shapes, f), v)
            for f, v in (
                ("r", 400.0),
                ("cy", 100.0),
                ("cx", 100.0),
                ("kind", 1),
                ("angle", 0.0),
                ("aspect", 1.0),
                ("size", 5.0),
                ("texture", 0.0),
                ("slope", 0.0),
            )
        },
        colour=np.vstack([shapes.colour, [0.05, 0.3, 0.7]]),
    )
    image = device_scenes.composite(torch.rand(3, 200, 200), fine, cover)
    assert float((image - torch.tensor([0.05, 0.3, 0.7])[:, None, None]).abs().max()) < 1e-6


def test_a_shapes_box_holds_every_pixel_it_covers():
    """Evaluated 12 px past its box on every side, no shape of any kind, size or orientation
    covers a pixel outside its box."""
    shapes = device_scenes.draw_shapes((400, 400), 300, (40, 40, 360, 360), np.random.default_rng(7))
    rows0, cols0, side = shapes.boxes()
    for kind in range(4):
        for k in np.flatnonzero(shapes.kind == kind)[:60]:
            origin = np.array([[rows0[k]], [cols0[k]]])
            tight = device_scenes._coverage(shapes, np.array([k]), origin, int(side[k]), (400, 400), "cpu")[0]
            wide = device_scenes._coverage(shapes, np.array([k]), origin - 12, int(side[k]) + 24, (400, 400), "cpu")[0]
            covered = set(tight[tight < 400 * 400].tolist())
            assert covered == set(wide[wide < 400 * 400].tolist()), (kind, k)


def test_dirt_and_fences_are_the_hosts():
    """The host's draws: a fence's wires within float32 rounding; dirt's coverage within 0.01 of
    the host's (its noise is resized with sample i exactly at pixel i·step, the host's with
    OpenCV's half-pixel convention, so the blobs sit up to a few pixels apart)."""
    preset = load_preset(TINY)
    args = ((64, 64), 20, 0.045, preset.lens.focal_length_m, preset.sensor.pixel_pitch_m)
    for kind in ("dirt", "fence"):
        host = make_obstruction(kind, args[0], *args[2:], [0, 1, 2, 17], params=preset.obstruction, margin=20)
        rgb, mask = device_scenes.obstruction(
            kind, *args, np.random.default_rng([0, 1, 2, 17]), preset.obstruction, "cpu"
        )
        assert rgb.shape == host.rgb.shape and mask.shape == host.mask.shape
        assert float(mask.min()) >= 0 and float(mask.max()) <= 1 and bool((rgb[:, mask[0] == 0] == 0).all())
        if kind == "fence":
            assert np.abs(mask.numpy() - host.mask).max() < 1e-4 and np.abs(rgb.numpy() - host.rgb).max() < 1e-5
        else:
            assert abs(float(mask.mean()) - float(host.mask.mean())) < 0.01


def test_a_batch_is_seeded_and_needs_no_values_from_the_device(tiny):
    """The same (seed, step, index), the same batch; another step, another. On the meta device,
    whose tensors hold no values, the batch is drawn all the same: nothing is read back."""
    preset = _with(tiny, scene_generator="torch", obstructions=("dirt", "fence"))
    a = step_batch(preset, 0, 3, [0, 1], 0.045, None, 30, "cpu")
    assert all(torch.equal(x, y) for x, y in zip(a, step_batch(preset, 0, 3, [0, 1], 0.045, None, 30, "cpu")))
    assert not torch.equal(a[0], step_batch(preset, 0, 4, [0, 1], 0.045, None, 30, "cpu")[0])
    n = preset.sensor.pixels + 60
    assert [tuple(x.shape) for x in a] == [(2, 3, n, n), (2, 3, n, n), (2, 1, n, n)]
    assert float(a[0].min()) >= 0.002 and float(a[0].max()) <= 1.0
    for step in range(4):
        assert all(x.device.type == "meta" for x in step_batch(preset, 0, step, [0, 1], 0.045, None, 30, "meta"))


def test_where_the_scenes_are_drawn(tiny, tmp_path):
    """ "auto": on an accelerator for procedural scenes and dirt or fences, else on the host (the
    CPU's scenes unchanged); "torch" refuses what it cannot draw, naming the key."""
    assert not scenes_on_device(tiny, "cpu") and scenes_on_device(tiny, "cuda")
    assert not scenes_on_device(_with(tiny, obstructions=("rain",)), "cuda")
    assert not scenes_on_device(_with(tiny, scene_generator="numpy"), "cuda")
    assert scenes_on_device(_with(tiny, scene_generator="torch"), "cpu")
    text = TINY.read_text().replace("[optimize]", '[optimize]\nscene_generator = "torch"\nobstructions = ["rain"]')
    path = tmp_path / "p.toml"
    path.write_text(text)
    with pytest.raises(InputError, match="optimize.scene_generator"):
        load_preset(path)
