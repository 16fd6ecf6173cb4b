"""Benchmark: the field of view on the paper's lens (hyperbolic 532 nm, f 4 mm, D 2.516 mm, pitch
395 nm; sensor 512² of 1.85 µm, corner at 9.5°).

One off-axis PSF (``optics.field.field_psf``, 255-pixel window, 530 nm, ∞) at the sensor's edge
   and corner: with ``field_psf``'s default angle margin (doubled, for small lenses) and with the
   single one the field PSF sets use (``optics.field.ON_AXIS_MARGIN``), their relative L2
   apart; the on-axis radial PSF for scale.
The off-axis estimate (``optics.field.estimate_field_psf``) beside each measurement.

Run alone (it times): python benchmarks/bench_field.py [--threads 2] [--device cpu|cuda]
Rewrites its section of docs/benchmarks.md: ``field`` for the CPU, ``field-cuda`` for a GPU (every
timing waits for the device).
"""

from __future__ import annotations

import argparse
import math
import time

import torch
from report import write_section

PIXELS, PITCH = 512, 1.85e-6
SPEC = "hyperbolic:532nm"


def _design():
    from metalens_cli.io.designs import resolve_design

    return resolve_design(SPEC, None, f_m=4e-3, aperture_m=2.516e-3, pitch_m=395e-9)


def _timed(on: str, run, *args, **kwargs):
    """(run(*args, **kwargs), seconds), the work queued on device ``on`` included."""
    start = time.perf_counter()
    result = run(*args, **kwargs)
    if on.startswith("cuda"):
        torch.cuda.synchronize()
    return result, time.perf_counter() - start


def one_psf(design, device: str) -> list[str]:
    from metalens_cli.imaging.field_psfs import corner_pixels
    from metalens_cli.optics.field import ON_AXIS_MARGIN, estimate_field_psf, field_psf
    from metalens_cli.optics.psf import compute_psf
    from metalens_cli.optics.sampling import PsfGrid

    lens, rows = design.lens, []
    grid = PsfGrid([530e-9], [math.inf], 255, PITCH)
    _, seconds = _timed(device, compute_psf, lens, grid, device=device)
    rows.append(f"| on axis (radial path) | 0° | — | {seconds:.2f} | — | — | — |")
    for label, height in (("sensor edge", PIXELS // 2), ("sensor corner", corner_pixels(PIXELS))):
        angle = math.atan2(height * PITCH, 4e-3)
        results = {}
        for oversample in (1.0, ON_AXIS_MARGIN):
            results[oversample] = _timed(device, field_psf, lens, grid, angle, device=device, oversample=oversample)
        ref, fast = results[1.0][0].psf, results[ON_AXIS_MARGIN][0].psf
        error = float((fast - ref).norm() / ref.norm())
        for oversample, (r, seconds) in results.items():
            margin = "doubled (default)" if oversample == 1.0 else "single (field sets)"
            estimate = estimate_field_psf(lens, grid, angle, oversample=oversample)
            forecast = "—" if device.startswith("cuda") else f"{estimate.seconds:.2f}"  # a CPU forecast
            rows.append(
                f"| {label}, {margin} | {math.degrees(angle):.2f}° | {r.grid['fft_size']}² | {seconds:.2f} "
                f"| {r.timing_s['kernels']:.2f} / {r.timing_s['propagate']:.2f} | {forecast} "
                f"| {'—' if oversample == 1.0 else f'{error:.1e}'} |"
            )
            print(rows[-1], flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--device", default="cpu", help="cpu or cuda")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    gpu = args.device.startswith("cuda")
    psf_rows = one_psf(_design(), args.device)
    machine = (
        f"{torch.cuda.get_device_name()} (GPU), torch {torch.__version__}, every timing waiting for the device"
        if gpu
        else f"{args.threads} threads, run alone"
    )
    lines = [
        f"## One off-axis PSF, {'cuda' if gpu else 'cpu'} (`python benchmarks/bench_field.py"
        f"{' --device cuda' if gpu else ''}`)",
        "",
        f"The paper's lens (hyperbolic 532 nm, f 4 mm, D 2.516 mm, pitch 395 nm), sensor pixels of 1.85 µm "
        f"(a 512² sensor's edge at 6.75°, corner at 9.5°), {machine}. One PSF, 530 nm, ∞, "
        "255-pixel window (`optics.field.field_psf`): seconds in all, kernels (the shifted transfer function) / "
        "propagation, and `estimate_field_psf`'s forecast; the last column is the relative L2 of the single-margin "
        "PSF (what the field PSF sets use) against the doubled-margin one (`field_psf`'s default).",
        "",
        "| field | angle | FFT grid | s | kernels / propagate s | estimated s | rel. L2 |",
        "|---|---|---|---|---|---|---|",
        *psf_rows,
    ]
    write_section("field-cuda" if gpu else "field", "\n".join(lines))


if __name__ == "__main__":
    main()
