"""Pixel integration of intensity: radial and 2-D operators against closed forms."""

import math

import numpy as np
import pytest
import torch
from numpy.testing import assert_allclose
from scipy.special import erf

from metalens_cli.optics import sensor as S

PITCH = 1.85e-6


def gaussian_pixels(n, sigma):
    """Exact pixel integrals of exp(−ρ²/2σ²) over the N × N window (axis at pixel N//2)."""

    def cdf(x):
        return 0.5 * erf(x / (math.sqrt(2) * sigma)) * math.sqrt(2 * math.pi) * sigma

    c = S.pixel_centres(n, PITCH)
    px = cdf(c + PITCH / 2) - cdf(c - PITCH / 2)
    return px[:, None] * px[None, :]


@pytest.mark.parametrize("n", [7, 8])
@pytest.mark.parametrize("sigma", [0.3e-6, 3e-6])
def test_radial_operator_integrates_gaussian(n, sigma):
    step = 0.05e-6
    sensor = S.radial_sensor(step, n, PITCH)
    rho = torch.arange(sensor.n_radii, dtype=torch.float64) * step
    got = sensor.apply(torch.exp(-(rho**2) / (2 * sigma**2))[:, None])[0].numpy()
    want = gaussian_pixels(n, sigma)
    # Catmull-Rom interpolation error ~ (δ/σ)³ ≈ 5e-3 of the curvature term at σ = 0.3 µm,
    # integrated over the core: 2e-4 of the peak pixel (a 2 % error would fail).
    assert_allclose(got, want, rtol=0, atol=2e-4 * want.max())


def test_grid_operator_integrates_gaussian():
    sigma, n = 0.4e-6, 8
    g = np.arange(-200, 201) * 0.1e-6
    mat = S.grid_pixel_matrix(g, n, PITCH)
    got = mat @ np.exp(-(g[:, None] ** 2 + g[None, :] ** 2) / (2 * sigma**2)) @ mat.T
    want = gaussian_pixels(n, sigma)
    assert_allclose(got, want, rtol=0, atol=1e-4 * want.max())  # cubic error, δ/σ = 1/4


def test_sparse_grid_operator_is_the_dense_product_and_its_gradient():
    # an off-centre Gaussian (rows y ≠ columns x, so a transposed product would fail), closed form too
    sigma, n = 0.4e-6, 9
    g = np.arange(-300, 301) * 0.07e-6
    image = torch.from_numpy(np.exp(-((g[:, None] - 1e-6) ** 2 + (g[None, :] + 2e-6) ** 2) / (2 * sigma**2)))
    mat = torch.from_numpy(S.grid_pixel_matrix(g, n, PITCH))
    op = S.GridPixels.build(g, n, PITCH, dtype=torch.float64)
    assert op.matrix.layout == torch.sparse_csr
    dense = mat @ image @ mat.T
    torch.testing.assert_close(op(image), dense, rtol=1e-12, atol=1e-30)
    assert int(dense.argmax()) == (n // 2 + 1) * n + (n // 2 - 1)  # row y = +1 px, column x = −1 px
    weights = torch.rand(n, n, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    a, b = image.clone().requires_grad_(), image.clone().requires_grad_()
    (op(a) * weights).sum().backward()
    ((mat @ b @ mat.T) * weights).sum().backward()
    torch.testing.assert_close(a.grad, b.grad, rtol=1e-12, atol=1e-30)


def test_axis_is_centre_of_pixel_n_half_for_odd_and_even():
    for n in (5, 6):
        sensor = S.radial_sensor(0.1e-6, n, PITCH)
        rho = torch.arange(sensor.n_radii, dtype=torch.float64) * 0.1e-6
        img = sensor.apply(torch.exp(-(rho**2) / (2 * (0.5e-6) ** 2))[:, None])[0]
        assert divmod(int(img.argmax()), n) == (n // 2, n // 2)
        assert torch.allclose(img, img.T)  # 8-fold symmetry around the axis pixel
        assert torch.allclose(img[n // 2 - 1], img[n // 2 + 1])


def test_area_of_pixel_in_disc():
    # whole pixel inside, outside, and a quarter-disc in a pixel with a corner on the axis
    assert_allclose(S.pixel_disc_area(1.0, 2.0, 1.0, 2.0, 10.0), 1.0, rtol=1e-12)
    assert S.pixel_disc_area(5.0, 6.0, 5.0, 6.0, 1.0) == 0
    assert_allclose(S.pixel_disc_area(0.0, 2.0, 0.0, 2.0, 1.0), math.pi / 4, rtol=1e-12)
    assert_allclose(S.pixel_disc_area(-2.0, 2.0, -2.0, 2.0, 1.0), math.pi, rtol=1e-12)


def test_radial_operator_backward_is_the_same_every_time():
    """Each octant row's gradient sums its (up to 8) pixels in a fixed order: repeated backward
    passes agree bit for bit (advanced indexing's backward added them with atomics across threads
    and differed from run to run on a busy CPU, which broke bit-identical resumes of training).
    A race shows only sometimes: this caught the old path in about 1 of 3 runs on a busy machine;
    tests/design/test_training.py's resume tests failed every time there."""
    op = S.radial_sensor(0.2e-6, 1001, 1.85e-6)
    gen = torch.Generator().manual_seed(0)
    x = torch.rand(op.n_radii, 3, generator=gen, dtype=torch.float32)
    weight = torch.rand(3, 1001, 1001, generator=gen)
    grads = []
    for _ in range(8):
        xx = x.clone().requires_grad_(True)
        (op.apply(xx) * weight).sum().backward()
        grads.append(xx.grad)
    assert all(torch.equal(g, grads[0]) for g in grads[1:])


def test_radial_operator_gradient_matches_finite_differences():
    """The operator's hand-written backward (the transpose of the whole operator, for a window cut
    from it) against central differences, float64."""
    op = S.radial_sensor(0.4e-6, 7, 1.85e-6)
    x = torch.rand(op.n_radii, 2, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(op.apply, (x,), eps=1e-6, atol=1e-9)


def test_radial_operator_forward_mode_derivative_is_the_operator():
    """The operator's jvp (forward-mode AD, what psf retrieve's Jacobian uses) is the linear map
    applied to the tangent, for a window cut from a larger operator too."""
    import torch.autograd.forward_ad as fwad

    S.radial_sensor(0.4e-6, 11, 1.85e-6)  # a larger operator cached: the 7-pixel one is cut from it
    op = S.radial_sensor(0.4e-6, 7, 1.85e-6)
    x = torch.rand(op.n_radii, 2, dtype=torch.float64)
    tangent = torch.rand(op.n_radii, 2, dtype=torch.float64)
    with fwad.dual_level():
        out = fwad.unpack_dual(op.apply(fwad.make_dual(x, tangent)))
    assert torch.equal(out.primal, op.apply(x))
    assert_allclose(out.tangent.numpy(), op.apply(tangent).numpy(), rtol=1e-14, atol=0)


def test_an_extended_operator_equals_a_fresh_build():
    """Extending an operator computes only the rows of the pixels it lacks: the result is the
    operator built at once, entry for entry; the cache extends by at least ``larger_window``."""
    small = S.build_radial_sensor(0.3e-6, 21, 1.85e-6)
    grown, fresh = S.build_radial_sensor(0.3e-6, 45, 1.85e-6, start=small), S.build_radial_sensor(0.3e-6, 45, 1.85e-6)
    assert grown.rows == fresh.rows and grown.n_radii == fresh.n_radii
    assert (grown.matrix.csr != fresh.matrix.csr).nnz == 0
    x = torch.rand(fresh.n_radii, 2, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    torch.testing.assert_close(grown.apply(x), fresh.apply(x), rtol=0, atol=0)
    S.radial_sensor(0.35e-6, 21, 1.85e-6)
    assert S.radial_sensor(0.35e-6, 23, 1.85e-6).n_pixels == 23
    assert S._SENSORS[(0.35e-6, 1.85e-6, 4)].n_pixels == S.larger_window(21)
