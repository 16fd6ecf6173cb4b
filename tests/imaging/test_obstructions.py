"""Obstructions: coverage within the configured range, seeded, depth-aware sizes, files."""

import numpy as np
import pytest

from metalens_cli.errors import InputError
from metalens_cli.imaging.obstructions import make_obstruction, parse_obstructions, pixels_from_metres
from metalens_cli.io.presets import ObstructionConfig

SHAPE, F, PITCH = (128, 128), 4e-3, 1.85e-6


def make(kind, seed=0, depth=0.045, **kw):
    clean = np.random.default_rng(1).random((3, *SHAPE))
    return make_obstruction(kind, SHAPE, depth, F, PITCH, seed, params=ObstructionConfig(**kw), clean=clean)


def test_pixels_from_metres():
    assert pixels_from_metres(1e-3, 4e-3, 0.045, 1.85e-6) == pytest.approx(48.05, rel=1e-3)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_dirt_coverage_within_range(seed):
    o = make("dirt", seed, dirt_coverage=(0.2, 0.3))
    # the soft threshold is placed by bisection on the mean of every 4th pixel per axis: a
    # 1/16 sample of noise correlated over ≥ 4.5 px (the finest octave), measured within 0.01
    assert 0.2 - 0.015 <= o.coverage <= 0.3 + 0.015
    assert o.coverage == pytest.approx(o.settings["target_coverage"], abs=0.015)
    brown = o.rgb[:, o.mask[0] > 0.5].mean(axis=1)
    assert brown[0] > brown[1] > brown[2]  # brownish
    assert 0 < ((o.mask > 0) & (o.mask < 1)).mean() < 0.2  # soft edges exist


@pytest.mark.parametrize("kind", ["drops", "rain"])
def test_drop_coverage_within_range(kind):
    o = make(kind, drop_coverage=(0.05, 0.1), rain_coverage=(0.05, 0.1))
    footprint = float((o.mask > 0).mean())
    # disks are added until the footprint reaches the target; one more disk can overshoot by its area
    assert 0.05 <= footprint <= 0.1 + np.pi * (1.2e-3 * F / 0.045 / PITCH) ** 2 / o.mask.size
    if kind == "drops":
        assert o.mask.max() == pytest.approx(0.85) and o.rgb[0].max() > 5 * o.rgb[1].max()  # semi-opaque, red


def test_fence_coverage_matches_geometry():
    o = make("fence", fence_pitch_m=2e-3, fence_width_m=0.2e-3)
    w_over_p = 0.1
    assert o.coverage == pytest.approx(1 - (1 - w_over_p) ** 2, abs=0.02)  # two wire families; 128² sampling


@pytest.mark.parametrize("kind", ["dirt", "fence", "drops", "rain"])
def test_same_seed_same_obstruction(kind):
    a, b, c = make(kind, 5), make(kind, 5), make(kind, 6)
    assert np.array_equal(a.mask, b.mask) and np.array_equal(a.rgb, b.rgb)
    assert not np.array_equal(a.mask, c.mask)
    assert np.all(a.rgb[:, a.mask[0] == 0] == 0)  # I_obs = 0 where nothing obstructs


def test_depth_scales_features():
    near, far = make("fence", depth=0.04), make("fence", depth=0.08)
    assert near.settings["pitch_px"] == pytest.approx(2 * far.settings["pitch_px"])


def test_file_obstruction(tmp_path):
    import cv2

    rgba = np.zeros((64, 64, 4), np.uint8)
    rgba[16:48, 16:48] = (0, 0, 255, 255)  # BGR red, opaque square
    path = tmp_path / "square.png"
    cv2.imwrite(str(path), rgba)
    o = make(f"file:{path}")
    assert o.coverage == pytest.approx(0.25, abs=0.02)
    assert o.rgb[0].max() == pytest.approx(1.0) and o.rgb[2].max() == 0


def test_bad_specs():
    with pytest.raises(InputError):
        parse_obstructions("dirt,mud")
    with pytest.raises(InputError):
        parse_obstructions("file:/nonexistent.png")
    assert parse_obstructions("dirt, fence") == ["dirt", "fence"]
