"""Benchmark: one 512 × 512 RGB obstructed capture with the PSFs given (spectra precomputed).

Run: python benchmarks/bench_imaging.py [--threads 2] [--psf 512]. Prints a markdown table row.
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch
from report import write_section

from metalens_cli.imaging.formation import form_image, psf_spectrum


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--psf", type=int, nargs="+", default=[512, 255, 127])
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    h = args.size
    gen = torch.Generator().manual_seed(0)
    clean, obs = torch.rand(3, h, h, generator=gen), torch.rand(3, h, h, generator=gen)
    mask = (torch.rand(1, h, h, generator=gen) > 0.7).float()
    rows = [
        "## Image formation (`python benchmarks/bench_imaging.py`)",
        "",
        "One obstructed 512 × 512 RGB capture, PSF spectra precomputed once, float32. Target ≤ 50 ms.",
        "",
        "| image | PSF window | FFT size | threads | median ms | min ms | spectra once (ms) |",
        "|---|---|---|---|---|---|---|",
    ]
    for n in args.psf:
        near, far = torch.rand(3, n, n, generator=gen), torch.rand(3, n, n, generator=gen)
        near, far = near / near.sum((-2, -1), keepdim=True), far / far.sum((-2, -1), keepdim=True)
        t0 = time.perf_counter()
        sn, sf = psf_spectrum(near, (h, h)), psf_spectrum(far, (h, h))
        prep = time.perf_counter() - t0
        for _ in range(3):
            form_image(clean, obs, mask, sn, sf)
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            form_image(clean, obs, mask, sn, sf)
            times.append(time.perf_counter() - t0)
        rows.append(f"| {h}² RGB | {n}² | {sn.fft_shape[0]}² | {args.threads} | {1e3 * statistics.median(times):.1f} | "
                    f"{1e3 * min(times):.1f} | {1e3 * prep:.1f} |")
    print("\n".join(rows))
    write_section("imaging", "\n".join(rows))


if __name__ == "__main__":
    main()
