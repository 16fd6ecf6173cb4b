"""Training scenes look like photographs by the numbers: their statistics against the photograph set."""

import numpy as np
import pytest

from metalens_cli.design.scenes import procedural_scene, training_scene
from metalens_cli.imaging.images import PHOTOGRAPHS, load_images
from metalens_cli.imaging.scene_statistics import STATISTICS, scene_statistics, spectrum_slope, summarise

N = 256


@pytest.fixture(scope="module")
def photographs():
    return {photo.name: image.linear for photo, image in zip(PHOTOGRAPHS, load_images("photos", (N, N)))}


def test_procedural_scenes_match_the_photographs_statistics(photographs):
    """Each statistic's mean over 16 scenes lies within half the photographs' spread (standard
    deviation) of their mean; saturation against the colour photographs only (four are grey).
    The generator before issue 31 failed all five (median luminance 0.38 vs 0.17, edge
    density 0.08 vs 0.33, log-luminance spread 0.15 vs 0.52, spectrum slope −2.9 vs −2.2, saturation 0.29 vs 0.50)."""
    scenes = summarise(procedural_scene((N, N), np.random.default_rng([0, k, 11])) for k in range(16))
    colour = [image for photo, image in zip(PHOTOGRAPHS, photographs.values()) if photo.colour]
    for name in STATISTICS:
        reference = summarise(colour if name == "saturation" else photographs.values())[name]
        assert abs(scenes[name]["mean"] - reference["mean"]) <= 0.5 * reference["std"], (name, scenes[name], reference)


def test_spectrum_slope_of_a_power_law_field():
    """A random field with power ∝ f^-β has slope −β (β = 2 and 3, to ±0.2: the Hann window mixes
    neighbouring frequencies, which flattens a 1/f² spectrum to about −1.85)."""
    rng = np.random.default_rng(0)
    k = np.fft.fftfreq(N)
    f = np.hypot(*np.meshgrid(k, k, indexing="ij"))
    f[0, 0] = 1.0
    for beta in (2.0, 3.0):
        field = np.fft.ifft2(np.fft.fft2(rng.standard_normal((N, N))) * f ** (-beta / 2)).real
        image = np.repeat((0.5 + 0.1 * field / field.std())[None], 3, axis=0)
        assert spectrum_slope(image) == pytest.approx(-beta, abs=0.2)


def test_statistics_of_plain_images():
    grey = np.full((3, 64, 64), 0.18, np.float32)
    stats = scene_statistics(np.pad(grey, ((0, 0), (0, 64), (0, 64)), constant_values=0.18))
    assert (
        stats["saturation"] == 0
        and stats["edge_density"] == 0
        and stats["log_luminance_std"] == pytest.approx(0, abs=1e-6)
    )
    assert stats["luminance_median"] == pytest.approx(0.18, rel=1e-5)
    red = np.zeros((3, 128, 128), np.float32)
    red[0] = 0.5
    assert scene_statistics(red)["saturation"] == pytest.approx(1.0)


def test_training_scenes_are_seeded():
    a = training_scene((64, 64), 3, 10, 1)
    np.testing.assert_array_equal(a, training_scene((64, 64), 3, 10, 1))
    assert not np.array_equal(a, training_scene((64, 64), 3, 11, 1))
    assert a.dtype == np.float32 and a.shape == (3, 64, 64) and 0.002 <= a.min() and a.max() <= 1
