"""Captures with two-scale PSFs (imaging.formation, optics.two_scale): one scale is today's
convolution; a grey wall stays grey, an opaque cover hides the scene and a point's light is
conserved at any scale; the error against the single-scale capture stays within the budget the
training defaults were chosen by (docs/benchmarks.md), for the hyperbolic lens at both depths
and for a lens whose rippled θ scatters light the way learned ones do."""

import dataclasses

import numpy as np
import pytest
import torch

from metalens_cli.errors import InputError
from metalens_cli.imaging.formation import convolve, form_image, psf_margin
from metalens_cli.imaging.images import load_images
from metalens_cli.imaging.obstructions import make_obstruction
from metalens_cli.optics.channel_psf import channel_psf_stack
from metalens_cli.optics.lens import hyperbolic
from metalens_cli.optics.two_scale import TwoScale, split

PITCH = 1.85e-6
BUDGET = 2e-3  # relative L2 of captures at the training defaults' accuracy (docs/benchmarks.md)


def _disc(n=101, radius=40.0):
    y, x = torch.meshgrid(torch.arange(n) - n // 2, torch.arange(n) - n // 2, indexing="ij")
    r = torch.hypot(x.double(), y.double())
    return ((r < radius).double() + 30 * torch.exp(-(r**2) / 3)).expand(3, n, n).clone()


def _canvas(shape, seed=0, dtype=torch.float64):
    return torch.rand(*shape, generator=torch.Generator().manual_seed(seed), dtype=dtype)


def test_one_scale_is_todays_convolution():
    psf = _disc()
    parts = split(psf, 1, 11)
    m = psf_margin(psf)
    canvas = _canvas((2, 3, 40 + 2 * m, 56 + 2 * m))
    torch.testing.assert_close(convolve(canvas, parts, m), convolve(canvas, psf, m), rtol=0, atol=1e-12)


@pytest.mark.parametrize("scale, core", [(3, 9), (5, 25), (7, 21)])
def test_grey_wall_cover_and_point_light(scale, core):
    parts = split(_disc(), scale, core)
    m = psf_margin(parts) + 3  # a larger canvas than needed is trimmed
    h, w = 37, 52  # neither a multiple of the scale
    grey = torch.full((3, h + 2 * m, w + 2 * m), 0.37, dtype=torch.float64)
    none, full = (
        torch.zeros(1, *grey.shape[-2:], dtype=torch.float64),
        torch.ones(1, *grey.shape[-2:], dtype=torch.float64),
    )
    wall = form_image(grey, torch.zeros_like(grey), none, parts, parts, m)
    assert float((wall.obstructed - 0.37).abs().max()) < 1e-12
    cover = form_image(grey, torch.zeros_like(grey), full, parts, parts, m)
    assert float(cover.obstructed.abs().max()) < 1e-12 and float((cover.alpha - 1).abs().max()) < 1e-12
    # a point far from the sensor's edges whose blur the sensor holds: all its light arrives
    big = 160
    point = torch.zeros(3, big + 2 * m, big + 2 * m, dtype=torch.float64)
    point[:, m + big // 2, m + big // 2 + 1] = 1.0
    torch.testing.assert_close(convolve(point, parts, m).sum(dim=(-2, -1)), torch.ones(3, dtype=torch.float64))


def test_a_canvas_short_of_the_halo_margin_is_refused():
    parts = split(_disc(), 5, 25)
    m = psf_margin(parts) - 1
    with pytest.raises(InputError, match="margin"):
        convolve(torch.zeros(3, 20 + 2 * m, 20 + 2 * m), parts, m)


@pytest.mark.parametrize("ripple", [0.0, 0.3])
def test_capture_error_within_budget_at_both_depths(ripple):
    """Halo pixels of 5 × 5 around a 65-pixel core, the radial halo sampled 2× coarser (the
    training defaults, forced on windows of 260-630 px where the default rule, blocks of at most
    N/200, would take 1 or 3) against the single-scale capture of a photograph behind dirt and behind a
    fence, at the paper's lens scale (f 4 mm, D 2.5 mm, 1.85 µm pixels, the cover at 40 mm):
    the hyperbolic lens, and the same with a θ ripple that spreads its light as learned lenses
    do (windows of 300-600 px)."""
    lens = hyperbolic(532e-9, 4e-3, 2.516e-3, 395e-9)
    if ripple:
        k = torch.arange(lens.theta.numel(), dtype=torch.float64)
        lens = dataclasses.replace(lens, theta=lens.theta + ripple * torch.sin(2 * np.pi * k / 40))
    waves, depths = [470e-9, 532e-9, 620e-9], [40e-3, 1.0]
    one = channel_psf_stack(lens, waves, depths, np.eye(3) / 3, 1501, PITCH)
    two = channel_psf_stack(lens, waves, depths, np.eye(3) / 3, 1501, PITCH, two_scale=TwoScale(5, 65, 2, 1))
    assert not one.outgrown.any() and not two.outgrown.any()
    m, n = max(psf_margin(*one.psfs), psf_margin(*two.psfs)), 48
    (photo,) = load_images("photos", (n, n), limit=1, margin=m)
    clean = torch.as_tensor(photo.linear)
    for kind in ("dirt", "fence"):
        cover = make_obstruction(kind, (n, n), 40e-3, 4e-3, PITCH, 0, clean=photo.linear, margin=m)
        rgb, mask = torch.as_tensor(cover.rgb), torch.as_tensor(cover.mask)
        a = form_image(clean, rgb, mask, *one.psfs, m).obstructed
        b = form_image(clean, rgb, mask, *two.psfs, m).obstructed
        assert float((a - b).norm() / a.norm()) < BUDGET, kind


def test_channel_psfs_margin_is_that_of_the_forms_captures_use():
    """ChannelPsfs.margin comes from the windows alone; the split PSFs the captures convolve need
    exactly it (imaging.formation.psf_margin)."""
    from metalens_cli.imaging.channel_psfs import ChannelPsfs

    for n_near, n_far in [(757, 897), (425, 397), (1301, 999), (61, 45)]:
        for scales in [None, TwoScale(5, 65, 2), TwoScale(5, 65, 2, 1), TwoScale(9, 99, 1, 1)]:
            psfs = ChannelPsfs(
                torch.rand(3, n_near, n_near), torch.rand(3, n_far, n_far), 0.04, 1.0, [], [], [], 0.0, two_scale=scales
            )
            assert psfs.margin == psf_margin(*psfs.capture_forms()), (n_near, n_far, scales)
