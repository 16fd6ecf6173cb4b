"""Benchmark: one 512 × 512 RGB obstructed capture with the PSFs given (spectra precomputed).

Each configuration runs in ``--processes`` fresh processes, with glibc's default allocator
settings and with :func:`metalens_cli.runtime.retain_freed_memory` (what ``metalens`` applies
at start-up): without it some processes page-fault the FFT work arrays back in on every call.

Run: python benchmarks/bench_imaging.py [--threads 2] [--psf 512 255 127] [--processes 6].
Rewrites its section of docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time


def child(size: int, psf: int, threads: int, repeats: int, retain: bool) -> dict:
    """Time ``form_image`` in this process; returns medians and page faults per call."""
    import resource

    import torch

    from metalens_cli.imaging.formation import form_image, psf_spectrum
    from metalens_cli.runtime import retain_freed_memory

    applied = retain_freed_memory() if retain else False
    torch.set_num_threads(threads)
    gen = torch.Generator().manual_seed(0)
    clean, obs = torch.rand(3, size, size, generator=gen), torch.rand(3, size, size, generator=gen)
    mask = (torch.rand(1, size, size, generator=gen) > 0.7).float()
    near, far = torch.rand(3, psf, psf, generator=gen), torch.rand(3, psf, psf, generator=gen)
    near, far = near / near.sum((-2, -1), keepdim=True), far / far.sum((-2, -1), keepdim=True)
    t0 = time.perf_counter()
    sn, sf = psf_spectrum(near, (size, size)), psf_spectrum(far, (size, size))
    prep = time.perf_counter() - t0
    for _ in range(3):
        form_image(clean, obs, mask, sn, sf)
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        form_image(clean, obs, mask, sn, sf)
        times.append(time.perf_counter() - t0)
    faults = (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults) / repeats
    return {"median_ms": 1e3 * statistics.median(times), "min_ms": 1e3 * min(times), "faults_per_call": faults,
            "spectra_ms": 1e3 * prep, "fft": sn.fft_shape[0], "retained": applied}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--psf", type=int, nargs="+", default=[512, 255, 127])
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--processes", type=int, default=6)
    parser.add_argument("--child", nargs=2, metavar=("PSF", "RETAIN"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(args.size, int(args.child[0]), args.threads, args.repeats, args.child[1] == "1")))
        return
    from report import write_section

    rows = [
        "## Image formation (`python benchmarks/bench_imaging.py`)",
        "",
        f"One obstructed {args.size} × {args.size} RGB capture, PSF spectra precomputed once, float32, "
        f"{args.threads} threads. Each line: {args.processes} fresh processes × {args.repeats} calls; the median and the "
        "worst of the per-process medians, and minor page faults per call. `retained`: "
        "`metalens_cli.runtime.retain_freed_memory()` applied, as `metalens` does at start-up. Target ≤ 50 ms.",
        "",
        "| PSF window | FFT size | allocator | median ms | worst process ms | page faults / call | spectra once (ms) |",
        "|---|---|---|---|---|---|---|",
    ]
    for n in args.psf:
        for retain in (False, True):
            runs = [json.loads(subprocess.run(
                [sys.executable, __file__, "--child", str(n), str(int(retain)), "--threads", str(args.threads),
                 "--size", str(args.size), "--repeats", str(args.repeats)],
                check=True, capture_output=True, text=True).stdout) for _ in range(args.processes)]
            medians = [r["median_ms"] for r in runs]
            rows.append(f"| {n}² | {runs[0]['fft']}² | {'retained' if retain else 'glibc default'} | "
                        f"{statistics.median(medians):.1f} | {max(medians):.1f} | "
                        f"{statistics.median(r['faults_per_call'] for r in runs):.0f} | "
                        f"{statistics.median(r['spectra_ms'] for r in runs):.1f} |")
            print(rows[-1], flush=True)
    write_section("imaging", "\n".join(rows))


if __name__ == "__main__":
    main()
