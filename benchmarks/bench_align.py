"""Time `register` + `apply` of a synthetic 2048² RGB capture onto its reference: writes its section of
docs/benchmarks.md.

Run: python benchmarks/bench_align.py [--repeat 3] [--side 2048]
The reference is a multi-scale texture (smoothed noise, σ 2-64 px, random colours); the capture
sees it through a known homography (2° rotation, 3 % zoom, shift, mild perspective) plus a smooth
6-pixel sinusoidal ripple, blurred (Gaussian σ 1.5 px) and with a per-channel gain and a bias,
as a metalens capture is. PSNR (dB) compares the aligned capture, gain and bias undone, with the
equally blurred reference over the valid region. Target: register + apply ≤ 3 s with --refine flow.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import statistics
import time

import cv2
import numpy as np
from report import write_section

from metalens_cli.imaging.registration import register

MARGIN, BLUR_PX, RIPPLE_PX, BIAS = 128, 1.5, 6.0, 0.03
GAIN = np.array([0.7, 0.55, 0.85], np.float32)


def scene(side: int, seed: int = 0) -> np.ndarray:
    """(side, side, 3) float32 in 0.05..0.95: smoothed noise at σ = 2-64 px with random colours."""
    rng = np.random.default_rng(seed)
    image = np.zeros((side, side, 3), np.float32)
    for sigma in (2, 4, 8, 16, 32, 64):
        layer = cv2.GaussianBlur(rng.standard_normal((side, side)).astype(np.float32), (0, 0), sigma)
        image += (layer / layer.std())[:, :, None] * rng.uniform(0.3, 1.0, 3).astype(np.float32)
    image -= image.min()
    return 0.05 + 0.9 * image / image.max()


def pair(side: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(reference, capture, blurred reference): the capture's pixel (x, y) sees the scene at
    CAMERA·(x, y, 1) plus the ripple, then blur, gain and bias."""
    world = scene(side + 2 * MARGIN)
    reference = world[MARGIN : MARGIN + side, MARGIN : MARGIN + side]
    angle, zoom = math.radians(2), 1.03
    camera = np.array(
        [
            [zoom * math.cos(angle), -zoom * math.sin(angle), MARGIN - 30],
            [zoom * math.sin(angle), zoom * math.cos(angle), MARGIN + 15],
            [1e-5, -5e-6, 1],
        ]
    )
    y, x = np.mgrid[:side, :side].astype(np.float64)
    w = camera[2, 0] * x + camera[2, 1] * y + camera[2, 2]
    u = (camera[0, 0] * x + camera[0, 1] * y + camera[0, 2]) / w + RIPPLE_PX * np.sin(3 * np.pi * y / side)
    v = (camera[1, 0] * x + camera[1, 1] * y + camera[1, 2]) / w + RIPPLE_PX * np.cos(2 * np.pi * x / side)
    capture = cv2.remap(
        world, u.astype(np.float32), v.astype(np.float32), cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT
    )
    capture = cv2.GaussianBlur(capture, (0, 0), BLUR_PX) * GAIN + BIAS
    return reference, capture, cv2.GaussianBlur(reference, (0, 0), BLUR_PX)


def timed(reference, capture, blurred, refine: str, repeat: int) -> dict:
    """Wall and CPU seconds of register and apply per call, and the PSNR of the last result."""
    register_s, apply_s, cpu = [], [], []
    for _ in range(repeat):
        start, start_cpu = time.perf_counter(), time.process_time()
        registration = register(reference, capture, refine=refine)
        middle = time.perf_counter()
        aligned = registration.apply(capture)
        register_s.append(middle - start)
        apply_s.append(time.perf_counter() - middle)
        cpu.append(time.process_time() - start_cpu)
    mask = registration.valid_mask()
    error = (aligned[mask] - BIAS) / GAIN - blurred[mask]
    return {
        "register": register_s,
        "apply": apply_s,
        "total": [a + b for a, b in zip(register_s, apply_s)],
        "cpu": cpu,
        "psnr_db": 10 * math.log10(1 / float(np.mean(error**2))),
        "inliers": registration.inliers,
        "matches": registration.matches,
        "valid": float(mask.mean()),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--side", type=int, default=2048)
    args = parser.parse_args()
    reference, capture, blurred = pair(args.side)
    load = os.getloadavg()[0]
    rows = {refine: timed(reference, capture, blurred, refine, args.repeat) for refine in ("flow", "none", "tps")}
    lines = [
        "## Registration of a capture (`align`)",
        "",
        f"Command: `python benchmarks/bench_align.py --repeat {args.repeat} --side {args.side}`; {os.cpu_count()} CPUs "
        f"(1-min load average {load:.1f} when started: other work shares them), Python {platform.python_version()}, "
        f"OpenCV {cv2.__version__}, numpy {np.__version__}. A {args.side} × {args.side} RGB float32 pair: known "
        f"homography + {RIPPLE_PX:g}-px sinusoidal ripple, capture blurred (σ {BLUR_PX:g} px) with per-channel gain "
        "and bias. Target: register + apply ≤ 3 s with `--refine flow`.",
        "PSNR: aligned capture (gain and bias undone) against the equally blurred reference, over the valid region.",
        "",
        "| refine | register wall median (s) | apply wall median (s) | total wall median (s) | total wall min (s) "
        "| CPU median (s) | matches / inliers | valid % | PSNR (dB) |",
        "|---|---|---|---|---|---|---|---|---|",
        *[
            f"| {refine} | {statistics.median(r['register']):.2f} | {statistics.median(r['apply']):.2f} | "
            f"{statistics.median(r['total']):.2f} | {min(r['total']):.2f} | {statistics.median(r['cpu']):.2f} | "
            f"{r['matches']} / {r['inliers']} | {100 * r['valid']:.1f} | {r['psnr_db']:.1f} |"
            for refine, r in rows.items()
        ],
    ]
    write_section("align", "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
