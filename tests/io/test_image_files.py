"""The sRGB transfer curves (io.image_files) against colour-science's, the reference package."""

import colour
import numpy as np

from metalens_cli.io.image_files import linear_to_srgb, srgb_to_linear


def test_srgb_curves_match_colour_science_and_invert():
    x = np.concatenate([np.linspace(-0.1, 1.1, 2001), [0.04045, 0.0031308]])
    np.testing.assert_allclose(
        srgb_to_linear(x, np.float64), colour.cctf_decoding(np.clip(x, 0, 1), function="sRGB"), rtol=1e-12, atol=1e-15
    )
    np.testing.assert_allclose(
        linear_to_srgb(x, np.float64), colour.cctf_encoding(np.clip(x, 0, 1), function="sRGB"), rtol=1e-12, atol=1e-15
    )
    y = np.linspace(0, 1, 257)
    np.testing.assert_allclose(linear_to_srgb(srgb_to_linear(y, np.float64), np.float64), y, atol=1e-12)
    assert srgb_to_linear(np.ones((2, 3))).dtype == np.float32
