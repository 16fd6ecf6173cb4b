"""Slanted-edge SFR on synthetic edges of known blur, image reading, refusals."""

import math

import cv2
import numpy as np
import OpenEXR
import pytest
from numpy.testing import assert_allclose
from synthetic import render_edge

from metalens_cli.analysis.mtf import mtf50
from metalens_cli.analysis.slanted_edge import read_edge_image, slanted_edge_sfr
from metalens_cli.errors import InputError


def expected_sfr(frequencies: np.ndarray, tilt_deg: float, sigma_px: float) -> np.ndarray:
    """Gaussian blur × square pixel seen along the edge normal (a box of width cos θ convolved
    with one of width sin θ)."""
    theta = math.radians(tilt_deg)
    pixel = np.sinc(frequencies * math.cos(theta)) * np.sinc(frequencies * math.sin(theta))
    return np.exp(-2 * np.pi**2 * sigma_px**2 * frequencies**2) * pixel


@pytest.mark.parametrize("tilt", [2.0, 5.0, 10.0, -7.0])
@pytest.mark.parametrize("sigma", [0.5, 0.8, 1.6])
def test_noiseless_edge_matches_closed_form_up_to_nyquist(tilt, sigma):
    # Remaining errors: uneven sub-pixel phases within the ¼-px bins and the window; measured
    # ≤ 0.004 up to Nyquist. Tolerance 0.008; without the derivative and binning corrections
    # the sharp edges (σ ≤ 0.8 px) miss by 0.012-0.03. The fitted tilt is exact to ~1e-3°.
    sfr = slanted_edge_sfr(render_edge(128, 96, tilt, sigma), ["Y"]).channels[0]
    assert sfr.angle_deg == pytest.approx(tilt, abs=0.01)
    nyquist = sfr.frequencies_cy_per_px <= 0.5
    f = sfr.frequencies_cy_per_px[nyquist]
    assert_allclose(sfr.mtf[nyquist], expected_sfr(f, tilt, sigma), atol=0.008)
    assert sfr.frequencies_cy_per_px[-1] == pytest.approx(1.0, abs=0.02)


def test_noisy_edge_within_noise_tolerance():
    # Noise σn = 0.005 on a step of 0.6: an ESF bin averages ~32 pixels, the LSF window spans
    # ~190 noisy central differences, so each SFR sample carries ≈ 0.013 rms noise at Nyquist;
    # 40 seeds gave at most 0.038 over the 33 frequencies ≤ Nyquist. Tolerance 0.06 (≈ 4.5σ).
    # MTF50 averages over many samples: std 0.45 % over 40 seeds, rtol 3 %.
    tilt, sigma = 5.0, 1.2
    image = render_edge(128, 96, tilt, sigma) + 0.005 * np.random.default_rng(7).standard_normal((128, 96))
    sfr = slanted_edge_sfr(image, ["Y"]).channels[0]
    nyquist = sfr.frequencies_cy_per_px <= 0.5
    f = sfr.frequencies_cy_per_px[nyquist]
    assert_allclose(sfr.mtf[nyquist], expected_sfr(f, tilt, sigma), atol=0.06)
    fine = np.linspace(0, 0.5, 2001)
    assert_allclose(sfr.mtf50_cy_per_px, mtf50(fine, expected_sfr(fine, tilt, sigma)), rtol=0.03)


def test_horizontal_edge_and_dark_to_bright_reversal():
    # An edge 85° from vertical is 5° from horizontal: transposed, same SFR; inverting the
    # image only flips the LSF's sign.
    image = render_edge(96, 128, 85.0, 1.0)
    analysis = slanted_edge_sfr(1 - image, ["Y"])
    sfr = analysis.channels[0]
    assert analysis.orientation == "horizontal" and abs(sfr.angle_deg) == pytest.approx(5.0, abs=0.01)
    nyquist = sfr.frequencies_cy_per_px <= 0.5
    assert_allclose(sfr.mtf[nyquist], expected_sfr(sfr.frequencies_cy_per_px[nyquist], 5.0, 1.0), atol=0.01)


def test_channels_and_given_roi():
    # Three channels blurred differently: each SFR follows its own σ; a given ROI is kept as is.
    sigmas = (0.8, 1.2, 2.0)
    image = np.dstack([render_edge(120, 120, 4.0, s) for s in sigmas])
    analysis = slanted_edge_sfr(image, ["R", "G", "B"], roi=(20, 10, 80, 100))
    assert analysis.roi == (20, 10, 80, 100)
    for sfr, sigma in zip(analysis.channels, sigmas):
        f = sfr.frequencies_cy_per_px[sfr.frequencies_cy_per_px <= 0.5]
        assert_allclose(sfr.mtf[: f.size], expected_sfr(f, 4.0, sigma), atol=0.01)
    assert [s.channel for s in analysis.channels] == ["R", "G", "B"]


def test_frequencies_in_lpmm_with_a_pitch():
    sfr = slanted_edge_sfr(render_edge(96, 96, 6.0, 1.0), ["Y"]).channels[0]
    # 0.5 cycle/pixel at 1.85 µm is 270.27 lp/mm.
    assert_allclose(sfr.frequencies_lpmm(1.85e-6), sfr.frequencies_cy_per_px * 1e3 / 1.85, rtol=1e-12)


@pytest.mark.parametrize(
    ("tilt", "message"), [(0.5, "from the pixel grid"), (44.6, "within 1° of 45°"), (89.5, "from the pixel grid")]
)
def test_edges_near_0_45_90_degrees_refused(tilt, message):
    with pytest.raises(InputError, match=message):
        slanted_edge_sfr(render_edge(128, 128, tilt, 1.0), ["Y"])


def test_no_edge_and_bad_roi_refused():
    flat = 0.5 + 0.01 * np.random.default_rng(0).standard_normal((64, 64))
    with pytest.raises(InputError, match="no edge"):
        slanted_edge_sfr(flat, ["Y"], roi=(0, 0, 64, 64))
    with pytest.raises(InputError, match="not inside"):
        slanted_edge_sfr(render_edge(64, 64, 5.0, 1.0), ["Y"], roi=(10, 10, 60, 20))


def test_reading_png_tiff_exr(tmp_path):
    edge = render_edge(64, 64, 5.0, 1.0)
    rgb = np.dstack([edge, 0.5 * np.ones_like(edge), 1 - edge])
    cv2.imwrite(str(tmp_path / "e.png"), np.round(rgb[..., ::-1] * 255).astype(np.uint8))  # OpenCV writes BGR
    cv2.imwrite(str(tmp_path / "e.tif"), np.round(edge * 65535).astype(np.uint16))
    OpenEXR.File(
        {"type": OpenEXR.scanlineimage}, {name: rgb[..., k].astype(np.float32) for k, name in enumerate("RGB")}
    ).write(str(tmp_path / "e.exr"))
    png, names = read_edge_image(tmp_path / "e.png")
    assert names == ["R", "G", "B"]
    assert_allclose(png, rgb, atol=0.5 / 255)  # 8-bit rounding, channels back in RGB order
    tif, names = read_edge_image(tmp_path / "e.tif")
    assert names == ["Y"] and tif.shape == (64, 64, 1)
    assert_allclose(tif[..., 0], edge, atol=0.5 / 65535)
    exr, _ = read_edge_image(tmp_path / "e.exr")
    assert_allclose(exr, rgb, rtol=1e-7)  # float32 storage
    decoded, _ = read_edge_image(tmp_path / "e.png", srgb=True)
    assert decoded[0, 0, 1] == pytest.approx(((128 / 255 + 0.055) / 1.055) ** 2.4)  # sRGB 0.502 → 0.216 linear
    with pytest.raises(InputError, match="linear"):
        read_edge_image(tmp_path / "e.exr", srgb=True)
    (tmp_path / "bad.png").write_text("not an image")
    with pytest.raises(InputError, match="not a readable"):
        read_edge_image(tmp_path / "bad.png")
