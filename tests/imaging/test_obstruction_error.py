"""The obstruction's added error: against brute-force per-pixel sums, Parseval, and cases with a known answer."""

import numpy as np
import torch

from metalens_cli.imaging.formation import form_image, zero_order_light
from metalens_cli.imaging.obstruction_error import added_error, added_error_spectrum, error_parts

H, W, M = 6, 7, 2  # sensor and canvas margin: 5 × 5 PSFs need M = 2


def _conv(canvas, kernel, y, x):
    """Σ_i kernel[i] canvas[p − (i − N//2)] at canvas point p = (y, x), replicating the canvas's edge."""
    n0, n1 = kernel.shape
    total = 0.0
    for i in range(n0):
        for j in range(n1):
            yy = min(max(y - (i - n0 // 2), 0), canvas.shape[0] - 1)
            xx = min(max(x - (j - n1 // 2), 0), canvas.shape[1] - 1)
            total += kernel[i, j] * canvas[yy, xx]
    return total


def _lstsq_error(estimate, reference):
    """Mean squared error after the least-squares gain and bias, by numpy's lstsq."""
    design = np.stack([estimate.ravel(), np.ones(estimate.size)], axis=1)
    (gain, bias), *_ = np.linalg.lstsq(design, reference.ravel(), rcond=None)
    return float(np.mean((gain * estimate + bias - reference) ** 2))


def test_added_error_matches_a_brute_force_per_pixel_sum():
    rng = np.random.default_rng(7)
    shape = (H + 2 * M, W + 2 * M)
    clean, obs = rng.uniform(0, 1, (3, *shape)), rng.uniform(0, 0.4, (3, *shape))
    mask = rng.uniform(0, 1, (1, *shape)) * (rng.uniform(size=(1, *shape)) > 0.5)
    near, far = rng.uniform(0, 1, (3, 5, 5)), rng.uniform(0, 1, (3, 3, 3))
    near, far = near / near.sum(axis=(1, 2), keepdims=True), far / far.sum(axis=(1, 2), keepdims=True)
    zn, zf = rng.uniform(0, 1, (5, 5)), rng.uniform(0, 1, (5, 5))
    zn, zf, zeta = zn / zn.sum(), zf / zf.sum(), 0.05
    t = {k: torch.from_numpy(v) for k, v in dict(clean=clean, obs=obs, mask=mask, near=near, far=far).items()}
    capture = form_image(t["clean"], t["obs"], t["mask"], t["near"], t["far"], M)
    zo, zu = zero_order_light(
        t["clean"], t["obs"], t["mask"], t["near"], torch.from_numpy(zn)[None], torch.from_numpy(zf)[None], M
    )
    reference = torch.from_numpy(clean[:, M:-M, M:-M].copy())
    unobstructed = capture.unobstructed + zeta * zu
    parts, base = error_parts(
        reference, unobstructed, -capture.alpha * capture.unobstructed, capture.obstruction_light, zeta * (zo - zu)
    )
    shares = added_error(parts, base)

    # brute force: every sensor pixel as the sum the model defines
    m_obs = mask[0] * obs
    blocked = np.array(
        [[[_conv(mask[0], near[c], y, x) for x in range(shape[1])] for y in range(shape[0])] for c in range(3)]
    )
    o, u = np.zeros((3, H, W)), np.zeros((3, H, W))
    for c in range(3):
        for y in range(H):
            for x in range(W):
                p = (y + M, x + M)
                focused = _conv(clean[c], far[c], *p)
                alpha = min(max(blocked[c, p[0], p[1]], 0.0), 1.0)
                own = _conv(m_obs[c], near[c], *p)
                passed = (1 - np.clip(blocked[c], 0, 1)) * clean[c]
                zero_obstructed = _conv(m_obs[c], zn, *p) + _conv(passed, zf, *p)
                zero_clear = _conv(clean[c], zf, *p)
                o[c, y, x] = own + (1 - alpha) * focused + zeta * zero_obstructed
                u[c, y, x] = focused + zeta * zero_clear
    ref = clean[:, M:-M, M:-M]
    brute = _lstsq_error(o, ref) - _lstsq_error(u, ref)
    assert abs(brute) > 1e-4  # the case is not trivial (random light may lower the error)
    total = sum(s.mean() for s in shares.values())
    np.testing.assert_allclose(float(total), brute, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(unobstructed.numpy(), u, rtol=1e-10, atol=1e-12)
    formed = unobstructed - capture.alpha * capture.unobstructed + capture.obstruction_light + zeta * (zo - zu)
    np.testing.assert_allclose(formed.numpy(), o, rtol=1e-10, atol=1e-12)


def test_spectrum_bands_sum_to_the_shares_and_a_cosine_lands_in_its_band():
    rng = np.random.default_rng(3)
    h, w = 32, 32
    reference = torch.from_numpy(rng.uniform(0.2, 0.8, (3, h, w)))
    unobstructed = reference + 0.05 * torch.from_numpy(rng.normal(size=(3, h, w)))
    y, x = np.mgrid[0:h, 0:w]
    cosine = torch.from_numpy(np.broadcast_to(0.1 * np.cos(2 * np.pi * 5 * x / w), (3, h, w)).copy())
    parts, base = error_parts(reference, unobstructed, -0.2 * unobstructed, cosine)
    edges = [0.0, 0.1, 0.2, 0.75]
    bands = added_error_spectrum(parts, base, edges)
    shares = added_error(parts, base)
    for name in parts:
        np.testing.assert_allclose(bands[name].sum(-1).numpy(), shares[name].numpy(), rtol=1e-9, atol=1e-14)
    # the own light is a cosine of 5/32 = 0.156 cycles per pixel: all of its share in the band 0.1-0.2
    own = bands["own_light"].numpy()
    assert abs(own[:, 1].sum()) > 1e-4
    np.testing.assert_allclose(own[:, [0, 2]], 0.0, atol=1e-12)


def test_a_uniform_veil_adds_no_error_after_the_match_and_a_local_shadow_does():
    """An obstruction blocking the same fraction everywhere is an exposure change the least-squares
    match undoes; the same fraction blocked over half the field is not."""
    rng = np.random.default_rng(5)
    reference = torch.from_numpy(rng.uniform(0.1, 0.9, (3, 16, 16)))
    unobstructed = reference + 0.02 * torch.from_numpy(rng.normal(size=(3, 16, 16)))
    parts, base = error_parts(reference, unobstructed, -0.3 * unobstructed, torch.zeros_like(reference))
    assert abs(float(sum(s.mean() for s in added_error(parts, base).values()))) < 1e-12
    half = torch.zeros_like(reference)
    half[..., :8] = 0.3
    parts, base = error_parts(reference, unobstructed, -half * unobstructed, torch.zeros_like(reference))
    assert float(sum(s.mean() for s in added_error(parts, base).values())) > 1e-3


def test_parts_of_a_grey_wall_stay_grey_and_an_opaque_cover_hides_it():
    """Through a lens with its zero-order light (leak 1, ζ_c ≈ 0.3-0.45): a grey wall g with no
    cover images as the uniform g·(1 + ζ_c) and the cover adds nothing; an opaque cover hides
    the wall (O = U + S + E + Z = 0 when dark) and, glowing b everywhere, images as b·(1 + ζ_c):
    each light keeps its energy, focused or not."""
    from metalens_cli.imaging.obstruction_error import capture_parts
    from metalens_cli.imaging.pipeline import attach_zero_order, capture_psfs
    from metalens_cli.io.designs import resolve_design
    from metalens_cli.io.presets import load_preset

    design = resolve_design(
        "hyperbolic:532nm", load_preset("presets/hyperbolic-532.toml"), f_m=None, aperture_m=0.3e-3, pitch_m=None
    )
    psfs = attach_zero_order(
        capture_psfs(design, 0.045, 1.0, [450e-9, 530e-9, 610e-9, 690e-9], 1.85e-6, 16), design, 1.85e-6, 1.0
    )
    zeta = psfs.zero_order.scale.double()
    side = 16 + 2 * psfs.margin
    wall = torch.full((3, side, side), 0.3)
    clear, opaque = torch.zeros((1, side, side)), torch.ones((1, side, side))
    dark, glow = torch.zeros((3, side, side)), torch.full((3, side, side), 0.2)

    u, s, e, z = (x.double() for x in capture_parts(wall, dark, clear, psfs, psfs.margin))
    np.testing.assert_allclose(u.numpy(), (0.3 * (1 + zeta)).expand(3, 16, 16).numpy(), rtol=1e-4)
    parts, base = error_parts(wall[:, :16, :16].double(), u, s, e, z)
    assert abs(float(sum(v.mean() for v in added_error(parts, base).values()))) < 1e-10
    u, s, e, z = capture_parts(wall, dark, opaque, psfs, psfs.margin)
    np.testing.assert_allclose((u + s + e + z).numpy(), 0.0, atol=1e-6)
    u, s, e, z = (x.double() for x in capture_parts(wall, glow, opaque, psfs, psfs.margin))
    np.testing.assert_allclose((u + s + e + z).numpy(), (0.2 * (1 + zeta)).expand(3, 16, 16).numpy(), rtol=1e-4)
