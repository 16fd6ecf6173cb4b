"""Benchmark: the field of view on the paper's lens (hyperbolic 532 nm, f 4 mm, D 2.516 mm, pitch
395 nm; sensor 512² of 1.85 µm, corner at 9.5°).

One off-axis PSF (``optics.field.field_psf``, 255-pixel window, 530 nm, ∞) at the sensor's edge
   and corner: with ``field_psf``'s default angle margin (doubled, for small lenses) and with the
   single one the field PSF sets use (``imaging.field_psfs.SET_OVERSAMPLE``), their relative L2
   apart; the on-axis radial PSF for scale.
The off-axis estimate (``optics.field.estimate_field_psf``) beside each measurement.

Run alone (it times): python benchmarks/bench_field.py [--threads 2]
Rewrites its section (``field``) of docs/benchmarks.md.
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


def one_psf(design) -> list[str]:
    from metalens_cli.imaging.field_psfs import SET_OVERSAMPLE, corner_pixels
    from metalens_cli.optics.field import estimate_field_psf, field_psf
    from metalens_cli.optics.psf import compute_psf

    lens, rows = design.lens, []
    t = time.perf_counter()
    compute_psf(lens, [530e-9], [math.inf], 255, PITCH)
    rows.append(f"| on axis (radial path) | 0° | — | {time.perf_counter() - t:.2f} | — | — | — |")
    for label, height in (("sensor edge", PIXELS // 2), ("sensor corner", corner_pixels(PIXELS))):
        angle = math.atan2(height * PITCH, 4e-3)
        results = {}
        for oversample in (1.0, SET_OVERSAMPLE):
            t = time.perf_counter()
            r = field_psf(lens, [530e-9], [math.inf], 255, PITCH, angle, oversample=oversample)
            results[oversample] = (r, time.perf_counter() - t)
        ref, fast = results[1.0][0].psf, results[SET_OVERSAMPLE][0].psf
        error = float((fast - ref).norm() / ref.norm())
        for oversample, (r, seconds) in results.items():
            margin = "doubled (default)" if oversample == 1.0 else "single (field sets)"
            estimate = estimate_field_psf(lens, [530e-9], [math.inf], 255, PITCH, angle, oversample=oversample)
            rows.append(
                f"| {label}, {margin} | {math.degrees(angle):.2f}° | {r.grid['fft_size']}² | {seconds:.2f} "
                f"| {r.timing_s['kernels']:.2f} / {r.timing_s['propagate']:.2f} | {estimate.seconds:.2f} "
                f"| {'—' if oversample == 1.0 else f'{error:.1e}'} |"
            )
            print(rows[-1], flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    psf_rows = one_psf(_design())
    lines = [
        "## One off-axis PSF, cpu (`python benchmarks/bench_field.py`)",
        "",
        f"The paper's lens (hyperbolic 532 nm, f 4 mm, D 2.516 mm, pitch 395 nm), sensor pixels of 1.85 µm "
        f"(a 512² sensor's edge at 6.75°, corner at 9.5°), {args.threads} threads, run alone. One PSF, 530 nm, ∞, "
        "255-pixel window (`optics.field.field_psf`): seconds in all, kernels (the shifted transfer function) / "
        "propagation, and `estimate_field_psf`'s forecast; the last column is the relative L2 of the single-margin "
        "PSF (what the field PSF sets use) against the doubled-margin one (`field_psf`'s default).",
        "",
        "| field | angle | FFT grid | s | kernels / propagate s | estimated s | rel. L2 |",
        "|---|---|---|---|---|---|---|",
        *psf_rows,
    ]
    write_section("field", "\n".join(lines))


if __name__ == "__main__":
    main()
