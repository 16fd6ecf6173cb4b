"""Speed against error of the PSF propagators on the paper's lens; writes docs/benchmarks.md.

Lens: hyperbolic, λd = 532 nm, f = 4 mm, D = 2.516 mm, pitch 395 nm; sensor 512², 1.85 µm at
d = f. Every configuration runs in a fresh process (so "cold" includes building its kernels and
the peak memory is that process's peak resident set size, ru_maxrss, Python and torch included).
Errors are relative L2 norms against the direct Rayleigh-Sommerfeld reference on the central
33 × 33 pixels (the full 512² window is out of reach for rs), and for whole windows against the
radial path at doubled sampling.

Usage: python benchmarks/bench_psf.py [--device cpu|cuda]  (writes its section of docs/benchmarks.md:
``psf`` for the CPU, ``psf-cuda`` for a GPU, where the peak is ``torch.cuda.max_memory_allocated``
and every timing waits for the device)
"""

from __future__ import annotations

import argparse
import math
import multiprocessing as mp
import os
import platform
import resource
import sys
import tempfile
import time

import torch
from report import write_section

LENS = dict(lambda_d_m=532e-9, focal_length_m=4e-3, aperture_m=2.516e-3, pitch_m=395e-9)
PIXELS, PITCH, SUB = 512, 1.85e-6, 16
CASES = [
    (532e-9, math.inf, "532 nm, ∞ (sharp)"),
    (580e-9, 0.045, "580 nm, 45 mm (sharp)"),
    (430e-9, 0.045, "430 nm, 45 mm (defocused)"),
]
SCAN_WAVELENGTHS = [x * 1e-9 for x in range(430, 646, 5)]
SCAN_DEPTHS = [0.045, math.inf]


def _run(args) -> dict:
    """One configuration in this (fresh) process: cold and warm timings, peak RSS, PSFs to file."""
    propagator, wavelengths, depths, pixels, oversample, path, device = args
    from metalens_cli.optics import lens as L
    from metalens_cli.optics.psf import compute_psf
    from metalens_cli.optics.sampling import PsfGrid

    gpu = device.startswith("cuda")
    lens = L.hyperbolic(**LENS)
    kw = dict(propagator=propagator, oversample=oversample, dtype=torch.float32, device=device)
    if propagator == "rs":
        kw["dtype"] = torch.float64

    def timed():
        t = time.perf_counter()
        res = compute_psf(lens, PsfGrid(wavelengths, depths, pixels, PITCH), **kw)
        if gpu:
            torch.cuda.synchronize()
        return res, time.perf_counter() - t

    res, cold = timed()
    warm = timed()[1] if propagator == "radial" else math.nan
    torch.save(res.psf.double().cpu(), path)
    peak = torch.cuda.max_memory_allocated() if gpu else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    return {"cold_s": cold, "warm_s": warm, "peak_gib": peak / 2**30, "grid": res.grid, "timing_s": res.timing_s}


def run(propagator, wavelengths, depths, device, pixels=PIXELS, oversample=1.0):
    """Run one configuration in a fresh spawned process; returns (stats, psf)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "psf.pt")
        with mp.get_context("spawn").Pool(1) as pool:
            stats = pool.apply(_run, ((propagator, wavelengths, depths, pixels, oversample, path, device),))
        return stats, torch.load(path)


def rel_l2(x: torch.Tensor, ref: torch.Tensor) -> float:
    return ((x - ref).norm() / ref.norm()).item()


def centre(psf: torch.Tensor) -> torch.Tensor:
    c = PIXELS // 2
    return psf[..., c - SUB : c + SUB + 1, c - SUB : c + SUB + 1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu", help="cpu or cuda")
    device = parser.parse_args().device
    gpu = device.startswith("cuda")
    lines, log = [], lambda s: print(s, file=sys.stderr, flush=True)

    refs = {}
    for lam, z, name in CASES:
        stats, psf = run("rs", [lam], [z], device, pixels=2 * SUB + 1)
        refs[name] = (psf[0, 0], stats)
        log(f"rs {name}: {stats['cold_s']:.1f} s")

    rows, single = [], {}
    for propagator, oversample in [("radial", 0.5), ("radial", 1.0), ("radial", 2.0), ("asm", 1.0)]:
        for lam, z, name in CASES:
            stats, psf = run(propagator, [lam], [z], device, oversample=oversample)
            err = rel_l2(centre(psf[0, 0]), refs[name][0])
            rows.append((propagator, oversample, name, stats, err))
            single[propagator, oversample, name] = (stats, psf[0, 0])
            log(f"{propagator} ×{oversample} {name}: {stats['cold_s']:.2f} s, err {err:.2e}")

    scan, scan_psf = run("radial", SCAN_WAVELENGTHS, SCAN_DEPTHS, device)
    fine, fine_psf = run("radial", SCAN_WAVELENGTHS, SCAN_DEPTHS, device, oversample=2.0)
    per_psf = [
        rel_l2(scan_psf[i, j], fine_psf[i, j]) for i in range(len(SCAN_DEPTHS)) for j in range(len(SCAN_WAVELENGTHS))
    ]
    asm_full, asm_psf = single["asm", 1.0, CASES[0][2]]
    asm_vs_fine = rel_l2(asm_psf, single["radial", 2.0, CASES[0][2]][1])

    machine = (
        f"{torch.cuda.get_device_name()} (GPU), torch {torch.__version__}"
        if gpu
        else f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPU cores, torch "
        f"{torch.__version__}, {torch.get_num_threads()} threads"
    )
    memory = (
        "GPU memory (`torch.cuda.max_memory_allocated`; every timing waits for the device, the stages "
        "inside a run do not)"
        if gpu
        else "the process's peak resident set size (`ru_maxrss`, including ~0.4 GiB of Python + torch)"
    )
    lines += [
        f"## PSF propagators, {'GPU' if gpu else 'CPU'}",
        "",
        f"Produced by `python benchmarks/bench_psf.py{' --device ' + device if gpu else ''}` (writes this "
        f"section). Machine: {machine}.",
        "",
        "Lens: hyperbolic, λd = 532 nm, f = 4 mm, D = 2.516 mm, pitch 395 nm; sensor 512 × 512, "
        "1.85 µm, at d = f; float32 (rs: float64). Each run is a fresh process: *cold* includes "
        "building kernels (Hankel matrices, pixel operator, transfer function), *warm* reuses "
        "them (the optimisation setting). Peak memory is " + memory + ". Error: relative L2 against direct "
        "Rayleigh-Sommerfeld integration on the central 33 × 33 pixels (full-window rs is out of "
        "reach; the cost of these pixels is given below the table).",
        "",
        "### One PSF",
        "",
        "| propagator | sampling | case | cold s | warm s | peak GiB | rel. L2 vs rs | grid |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for propagator, oversample, name, stats, err in rows:
        g = stats["grid"]
        grid = (
            f"{g['hankel_samples']} ν × {g['pupil_nodes']} r nodes, R = "
            f"{g['support_radius_m'] * 1e3:.2f} mm, δρ = {g['output_step_m'] * 1e9:.0f} nm"
            if propagator == "radial"
            else f"FFT {g['fft_size']}², window {g['window_samples']}² at {g['window_step_m'] * 1e9:.1f} nm"
        )
        lines.append(
            f"| {propagator} | ×{oversample:g} | {name} | {stats['cold_s']:.2f} | "
            f"{stats['warm_s']:.2f} | {stats['peak_gib']:.2f} | {err:.1e} | {grid} |"
        )
    lines += [
        "",
        "rs reference cost (33 × 33 pixels, float64): "
        + ", ".join(f"{name}: {st['cold_s']:.0f} s" for name, (_, st) in refs.items()),
        "",
    ]
    lines += [
        "### Targets",
        "",
        f"- Full scan 430:645:5 nm (44) × {{45 mm, ∞}} = 88 PSFs of 512², radial path: "
        f"**{scan['warm_s']:.2f} s warm**, {scan['cold_s']:.2f} s cold "
        f"(stages, cold: "
        + ", ".join(f"{k} {v:.2f} s" for k, v in scan["timing_s"].items())
        + f"); peak {scan['peak_gib']:.2f} GiB. Target ≤ 5 s.",
        f"- Its error: max relative L2 over the 88 PSFs against the radial path at doubled "
        f"sampling {max(per_psf):.1e} (median {sorted(per_psf)[len(per_psf) // 2]:.1e}); against "
        "rs on the central pixels see the ×1 rows above. Target ≤ 1e-3.",
        f"- One full-aperture PSF through the 2-D asm path (532 nm, ∞): **{asm_full['cold_s']:.2f} s**"
        f" (stages: "
        + ", ".join(f"{k} {v:.2f} s" for k, v in asm_full["timing_s"].items())
        + f"), peak **{asm_full['peak_gib']:.2f} GiB**; relative L2 against the radial path at "
        f"doubled sampling over the whole window {asm_vs_fine:.1e}. Target ≤ 6 s at ≤ 4 GiB.",
        "",
    ]
    path = write_section("psf-cuda" if gpu else "psf", "\n".join(lines))
    log(f"wrote {path}")


if __name__ == "__main__":
    main()
