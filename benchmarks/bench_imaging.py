"""Benchmark: one 512 × 512 RGB obstructed capture with the PSFs given (transforms precomputed),
on the canvas its near and far PSF windows need (``imaging.formation``).

Each configuration runs in ``--processes`` fresh processes, with glibc's default allocator
settings and with :func:`metalens_cli.runtime.retain_freed_memory` (what ``metalens`` applies
at start-up): without it some processes page-fault the FFT work arrays back in on every call.

Windows (odd sides, pixels) default to what ``optics.blur.psf_window`` gives the hyperbolic 532 nm
lens of the paper (f 4 mm, D 2.516 mm) for z_near = 40 mm and z_far = 1 m: over 400-700 nm (no
filter) and over the tri-band filter's pass bands (443-644 nm).

Run: python benchmarks/bench_imaging.py [--threads 2] [--windows NEAR:FAR ...] [--processes 6].
Rewrites its section of docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time


def child(size: int, near_n: int, far_n: int, threads: int, repeats: int, retain: bool) -> dict:
    """Time ``form_image`` in this process; returns medians and page faults per call."""
    import resource

    import torch

    from metalens_cli.imaging.formation import canvas_margin, form_image, psf_transform
    from metalens_cli.runtime import retain_freed_memory

    applied = retain_freed_memory() if retain else False
    torch.set_num_threads(threads)
    gen = torch.Generator().manual_seed(0)
    margin = canvas_margin(near_n, far_n)
    canvas = size + 2 * margin
    clean, obs = torch.rand(3, canvas, canvas, generator=gen), torch.rand(3, canvas, canvas, generator=gen)
    mask = (torch.rand(1, canvas, canvas, generator=gen) > 0.7).float()
    near, far = torch.rand(3, near_n, near_n, generator=gen), torch.rand(3, far_n, far_n, generator=gen)
    t0 = time.perf_counter()
    tn, tf = psf_transform(near, (size, size)), psf_transform(far, (size, size))
    prep = time.perf_counter() - t0
    for _ in range(3):
        form_image(clean, obs, mask, tn, tf, margin)
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        form_image(clean, obs, mask, tn, tf, margin)
        times.append(time.perf_counter() - t0)
    faults = (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults) / repeats
    return {
        "median_ms": 1e3 * statistics.median(times),
        "min_ms": 1e3 * min(times),
        "faults_per_call": faults,
        "spectra_ms": 1e3 * prep,
        "fft": f"{tn.fft_shape[0]}² / {tf.fft_shape[0]}²",
        "retained": applied,
    }


def optics_windows() -> list[tuple[int, int]]:
    """(near, far) windows of the hyperbolic 532 nm paper lens without and with the tri-band filter."""
    import numpy as np

    from metalens_cli.optics.blur import psf_window
    from metalens_cli.optics.lens import hyperbolic

    lens = hyperbolic(532e-9, 4e-3, 2.516e-3, 395e-9)
    bands = (
        np.arange(400e-9, 701e-9, 5e-9),
        np.concatenate(
            [np.arange(c - w, c + w + 1e-10, 2e-9) for c, w in ((457e-9, 14e-9), (530e-9, 12e-9), (628e-9, 16e-9))]
        ),
    )
    return [tuple(psf_window(lens, list(waves), [z], 4e-3, 1.85e-6) for z in (0.04, 1.0)) for waves in bands]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--windows", nargs="+", help="NEAR:FAR window sides [from the optics, see the docstring]")
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--processes", type=int, default=6)
    parser.add_argument("--child", nargs=3, metavar=("NEAR", "FAR", "RETAIN"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(
            json.dumps(
                child(
                    args.size, int(args.child[0]), int(args.child[1]), args.threads, args.repeats, args.child[2] == "1"
                )
            )
        )
        return
    windows = [tuple(int(v) for v in w.split(":")) for w in args.windows] if args.windows else optics_windows()
    from report import write_section

    rows = [
        "## Image formation (`python benchmarks/bench_imaging.py`)",
        "",
        f"One obstructed {args.size} × {args.size} RGB capture on the canvas its PSF windows need (sensor + N//2 of "
        f"the larger window on every side), PSF transforms precomputed once, float32, {args.threads} threads. Windows: "
        "the hyperbolic 532 nm paper lens at z_near 40 mm and z_far 1 m, over 400-700 nm (first row pair) and over the "
        f"tri-band filter's pass bands (second), from `optics.blur.psf_window`. Each line: {args.processes} fresh "
        f"processes × {args.repeats} calls; the median and the worst of the per-process medians, and minor page faults "
        "per call. `retained`: `metalens_cli.runtime.retain_freed_memory()` applied, as `metalens` does at start-up. "
        "Target ≤ 80 ms.",
        "",
        "| PSF windows near / far | FFT sizes near / far | allocator | median ms | worst process ms "
        "| page faults / call | transforms once (ms) |",
        "|---|---|---|---|---|---|---|",
    ]
    for near_n, far_n in windows:
        for retain in (False, True):
            runs = [
                json.loads(
                    subprocess.run(
                        [
                            sys.executable,
                            __file__,
                            "--child",
                            str(near_n),
                            str(far_n),
                            str(int(retain)),
                            "--threads",
                            str(args.threads),
                            "--size",
                            str(args.size),
                            "--repeats",
                            str(args.repeats),
                        ],
                        check=True,
                        capture_output=True,
                        text=True,
                    ).stdout
                )
                for _ in range(args.processes)
            ]
            medians = [r["median_ms"] for r in runs]
            rows.append(
                f"| {near_n}² / {far_n}² | {runs[0]['fft']} | {'retained' if retain else 'glibc default'} | "
                f"{statistics.median(medians):.1f} | {max(medians):.1f} | "
                f"{statistics.median(r['faults_per_call'] for r in runs):.0f} | "
                f"{statistics.median(r['spectra_ms'] for r in runs):.1f} |"
            )
            print(rows[-1], flush=True)
    write_section("imaging", "\n".join(rows))


if __name__ == "__main__":
    main()
