"""Benchmark: one 512 × 512 RGB obstructed capture with field-varying PSFs
(``imaging.field_formation``), against the on-axis ``form_image``; the fast path's error against
direct per-pixel sums; gather against scatter form.

The PSF sets stand in for the optics' (not in this package yet): a geometric ray trace of a lens
of f = 4 mm, D = 2.516 mm (the paper's f/1.6) that focuses each colour band exactly on axis
(hyperbolic at the band's wavelength), sensor 1.85 µm pixels at f·(1 − 0.004, 1, 1 + 0.004) for
B, G, R (a band's focal shift), heights every 24 px to the sensor's corner (362 px). Far: plane
waves, coma growing to ~80 px at the corner, the on-axis core within one pixel, window 101 px.
Near: a point 45 mm away, each channel averaged over sensor distances ±2 % (the spread of focal
lengths across a 25 nm band of a diffractive lens), a 90-150 px disc, window 201 px. Every PSF
is blurred by a 0.45 px Gaussian (the diffraction core).

Run: python benchmarks/bench_field_imaging.py [--tolerance 0.01] [--repeats 7] [--threads 2].
Prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time

import numpy as np

F, D, PIXEL = 4e-3, 2.516e-3, 1.85e-6
HEIGHTS = tuple(range(0, 361, 24)) + (362,)


def ray_psf(height_px: float, depth_m: float, n: int, distance_m: float, rays: int) -> np.ndarray:
    """Geometric PSF (n × n, chief ray at the centre pixel, unit sum) of the image point at
    ``height_px`` along +x: a rays × rays pupil grid traced and splatted bilinearly."""
    a = D / 2
    g = (np.arange(rays) + 0.5) / rays * D - a
    x, y = np.meshgrid(g, g)
    inside = x**2 + y**2 <= a * a
    x, y = x[inside], y[inside]
    tan = height_px * PIXEL / F
    if math.isinf(depth_m):
        sx, sy = np.full_like(x, tan / math.hypot(1, tan)), np.zeros_like(y)
    else:
        dx = x + depth_m * tan  # from the source at (−z·tan, 0, −z)
        r = np.sqrt(dx**2 + y**2 + depth_m**2)
        sx, sy = dx / r, y / r
    r = np.sqrt(x**2 + y**2 + F**2)
    sx, sy = sx - x / r, sy - y / r  # a lens focusing the band on axis at f
    c = np.sqrt(1 - sx**2 - sy**2)
    u = (x + distance_m * sx / c) / PIXEL - distance_m * tan / PIXEL + n // 2
    v = (y + distance_m * sy / c) / PIXEL + n // 2
    i, j = np.floor(v).astype(int), np.floor(u).astype(int)
    fv, fu = v - i, u - j
    img = np.zeros((n + 1) * (n + 1))
    for di, wv in ((0, 1 - fv), (1, fv)):
        for dj, wu in ((0, 1 - fu), (1, fu)):
            ok = (i + di >= 0) & (i + di < n) & (j + dj >= 0) & (j + dj < n)
            img += np.bincount(((i + di) * (n + 1) + j + dj)[ok], (wv * wu)[ok], minlength=img.size)
    return img.reshape(n + 1, n + 1)[:n, :n]


def blurred(img: np.ndarray, sigma: float = 0.45) -> np.ndarray:
    k = np.arange(-3, 4)
    kernel = np.exp(-(k**2) / (2 * sigma**2))
    kernel /= kernel.sum()
    img = np.apply_along_axis(np.convolve, 0, img, kernel, "same")
    return np.apply_along_axis(np.convolve, 1, img, kernel, "same")


def psf_set(depth_m: float, n: int, spread: float, samples: int, rays: int):
    from metalens_cli.imaging.field_formation import FieldPsfSet

    shifts = np.linspace(-spread, spread, samples) if samples > 1 else np.zeros(1)
    psfs = [
        [
            blurred(sum(ray_psf(h, depth_m, n, F * (1 + band + s), rays) for s in shifts))
            for band in (0.004, 0.0, -0.004)  # R, G, B
        ]
        for h in HEIGHTS
    ]
    import torch

    return FieldPsfSet(HEIGHTS, torch.tensor(np.array(psfs), dtype=torch.float32))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--tolerance", type=float, default=None, help="default: the module's")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--pixels", type=int, default=300, help="pixels checked against direct sums")
    args = parser.parse_args()

    import torch

    from metalens_cli.imaging import field_formation as ff
    from metalens_cli.imaging.dead_leaves import dead_leaves
    from metalens_cli.imaging.formation import canvas_margin, form_image, psf_transform

    torch.set_num_threads(args.threads)
    tolerance = ff.DEFAULT_TOLERANCE if args.tolerance is None else args.tolerance
    report: dict = {"threads": args.threads, "tolerance": tolerance}
    t0 = time.perf_counter()
    sets = {"far": psf_set(math.inf, 101, 0.0, 1, 600), "near": psf_set(0.045, 201, 0.02, 33, 300)}
    report["psf_sets_s"] = round(time.perf_counter() - t0, 1)
    size = 512
    margin = canvas_margin(201, 101)
    prepared = {}
    for name, s in sets.items():
        t0 = time.perf_counter()
        prepared[name] = ff.field_transform(s, (size, size), tolerance=tolerance)
        t = prepared[name]
        report[name] = {
            "prepare_s": round(time.perf_counter() - t0, 1),
            "tile_px": t.mean.sensor_hw[0],
            "fft": t.mean.fft_shape[0],
            "eigen_psfs": len(t.term_tile),
            "per_tile_and_channel_max": int(t.ranks.max()),
            "psf_field_error": round(t.error, 4),
            "spectra_mib": round((t.basis.spectrum.numel() * 8 + t.maps.numel() * 4) / 2**20),
        }
    g = torch.Generator().manual_seed(0)
    shape = (3, size + 2 * margin, size + 2 * margin)
    clean = torch.from_numpy(dead_leaves(shape[1:], 3, sensor_shape=(size, size)))
    colour = torch.rand(shape, generator=g)
    mask = (torch.rand(1, *shape[1:], generator=g) > 0.7).float()
    times, plain = [], []
    on_axis = psf_transform(sets["near"].psfs[0], (size, size)), psf_transform(sets["far"].psfs[0], (size, size))
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        ff.form_image_field(clean, colour, mask, prepared["near"], prepared["far"], margin)
        times.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        form_image(clean, colour, mask, *on_axis, margin)
        plain.append(time.perf_counter() - t0)
    report["capture_s"] = {"median": round(statistics.median(times), 3), "all": [round(t, 2) for t in times]}
    report["form_image_on_axis_s"] = round(statistics.median(plain), 3)

    # the fast path against direct sums at random pixels: dead leaves (the scene) and white noise
    rows, cols = (torch.randint(0, size, (args.pixels,), generator=g) for _ in range(2))
    noise = torch.rand(shape, generator=g)
    for name, s in sets.items():
        n = s.psfs.shape[-1]
        k = n // 2
        psf = ff.field_psf(s, (cols - size // 2).float(), (rows - size // 2).float()).flip(-2, -1)
        for scene_name, scene in (("dead_leaves", clean), ("white_noise", noise)):
            fast = ff.field_convolve(scene, prepared[name], margin)[:, rows, cols]
            exact = torch.stack(
                [
                    (psf[p] * scene[:, r + margin - k : r + margin + k + 1, c + margin - k : c + margin + k + 1]).sum(
                        (-2, -1)
                    )
                    for p, (r, c) in enumerate(zip(rows.tolist(), cols.tolist()))
                ],
                dim=1,
            )
            deviation = exact - exact.mean(1, keepdim=True)
            report[name][f"{scene_name}_error"] = round(float((fast - exact).norm() / exact.norm()), 5)
            report[name][f"{scene_name}_error_of_deviation"] = round(float((fast - exact).norm() / deviation.norm()), 5)

    # gather against scatter (far blur): scatter = (gather with point-reflected PSFs)ᵀ
    flipped = ff.field_transform(
        ff.FieldPsfSet(HEIGHTS, sets["far"].psfs.flip(-2, -1)), (size, size), tolerance=tolerance
    )
    far_margin = 101 // 2
    for scene_name, scene in (("dead_leaves", clean), ("grey_wall", torch.full_like(clean, 0.5))):
        sensor = scene[:, margin:-margin, margin:-margin]
        probe = torch.zeros(3, size + 2 * far_margin, size + 2 * far_margin, requires_grad=True)
        (scatter,) = torch.autograd.grad(ff.field_convolve(probe, flipped, far_margin), probe, sensor)
        gather = ff.field_convolve(scene, prepared["far"], margin)
        scatter = scatter[..., far_margin:-far_margin, far_margin:-far_margin]
        inner = np.s_[..., far_margin:-far_margin, far_margin:-far_margin]  # every source within reach on the sensor
        report[f"scatter_vs_gather_{scene_name}"] = {
            "relative_l2": round(float((scatter[inner] - gather[inner]).norm() / gather[inner].norm()), 4),
            "max_relative": round(float(((scatter[inner] - gather[inner]).abs() / gather[inner]).max()), 4),
        }
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
