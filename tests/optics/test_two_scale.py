"""The two-scale PSF (optics.two_scale): the split keeps the light exactly, one scale is the
PSF itself, and the radial halo computed at its own sampling (optics.channel_psf) agrees with the
halo summed from the sensor's pixels of the single-scale path."""

import numpy as np
import pytest
import torch

from metalens_cli.errors import InputError
from metalens_cli.optics.channel_psf import channel_psf_stack
from metalens_cli.optics.lens import hyperbolic
from metalens_cli.optics.two_scale import TwoScale, block_sum, check_scales, power, reach, split
from metalens_cli.optics.window import crop_window

PITCH = 1.85e-6


def _psf(n=61, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(3, n, n, generator=g, dtype=torch.float64)


def test_one_scale_is_the_psf_itself():
    psf = _psf()
    parts = split(psf, 1, 7)
    assert torch.equal(parts.fine(), psf)
    assert torch.equal(parts.core, psf[:, 27:34, 27:34]) and float(parts.halo[:, 27:34, 27:34].abs().max()) == 0


@pytest.mark.parametrize("scale, core", [(3, 9), (5, 15), (7, 7)])
def test_split_keeps_every_pixel_of_light_once(scale, core):
    psf = _psf()
    parts = split(psf, scale, core)
    torch.testing.assert_close(power(parts), psf.sum(dim=(-2, -1)), rtol=1e-12, atol=0)
    # the core is the PSF's central K × K; the blocks of the halo are sums of the sensor's pixels
    lo = 30 - core // 2
    assert torch.equal(parts.core, psf[:, lo : lo + core, lo : lo + core])
    m = parts.halo.shape[-1]
    padded = torch.nn.functional.pad(psf, ((m * scale - 61) // 2,) * 4)
    block = padded[:, :scale, :scale].sum(dim=(-2, -1))  # the corner block, by hand
    torch.testing.assert_close(parts.halo[:, 0, 0], block)
    # spread back to the sensor's pixels: the same power, and the core's pixels exact
    fine = parts.fine()
    torch.testing.assert_close(fine.sum(dim=(-2, -1)), psf.sum(dim=(-2, -1)))
    c = fine.shape[-1] // 2
    torch.testing.assert_close(
        fine[:, c - core // 2 : c + core // 2 + 1, c - core // 2 : c + core // 2 + 1], parts.core
    )


def test_block_sum_of_an_odd_window_about_its_axis():
    psf = torch.zeros(1, 7, 7, dtype=torch.float64)
    psf[0, 3, 3] = 1.0  # the axis
    psf[0, 3, 5] = 2.0  # two pixels right: in the block right of the axis block for s = 3
    blocks = block_sum(psf, 3)
    assert blocks.shape[-1] == 3 and float(blocks[0, 1, 1]) == 1.0 and float(blocks[0, 1, 2]) == 2.0


def test_bad_scales_name_the_field():
    for scale, core in [(2, 6), (3, 6), (3, 12), (0, 1)]:
        with pytest.raises(InputError) as error:
            check_scales(scale, core, "optimize.")
        assert error.value.field.startswith("optimize.")
    assert reach(101) == 50 and reach(101, 5, 25) == 5 * (21 // 2 + 2) - 1


@pytest.mark.parametrize("radial_step", [1, 2])
def test_radial_halo_matches_the_single_scale_psf_in_blocks(radial_step):
    """The halo computed from radial samples `radial_step` × coarser at s·p pixels against the
    block sums of the single-scale PSF: within 2e-4 (relative L2) at both depths; the core the
    same pixels as the single-scale PSF's centre (1e-6). The window rule asks for nearly all the
    light, so the windows are the capacity's, to within the few pixels by which the threshold,
    crossed in a slowly decaying tail, moves with the sampling of the encircled energy (the halo
    then spans the same blocks)."""
    lens = hyperbolic(532e-9, 1e-3, 0.2e-3, 395e-9)
    waves, depths = [470e-9, 532e-9, 620e-9], [10e-3, 1.0]
    weights = np.eye(3)
    kw = {"dtype": torch.float64, "energy": 1 - 1e-9}
    single = channel_psf_stack(lens, waves, depths, weights, 99, PITCH, **kw)
    double = channel_psf_stack(lens, waves, depths, weights, 99, PITCH, **kw, two_scale=TwoScale(3, 9, radial_step, 1))
    assert single.windows == ((99,) * 3,) * 2 and min(min(w) for w in double.windows) >= 93
    for one, two in zip(single.psfs, double.psfs):
        reference = split(one, 3, 9)
        n = min(reference.halo.shape[-1], two.halo.shape[-1])
        error = float((crop_window(two.halo, n) - crop_window(reference.halo, n)).norm() / reference.halo.norm())
        assert error < 2e-4, error
        torch.testing.assert_close(two.core, reference.core, rtol=0, atol=1e-6 * float(one.max()))
