"""η of the paper's nanofin against Fourier harmonics, and η(λ) over 24 wavelengths: writes its
section of docs/benchmarks.md.

Run: python benchmarks/bench_nanofin.py
Fin 305 × 125 × 700 nm, period 395 nm, Si3N4 (Luke) on fused silica, normal incidence from the
substrate (metalens_cli.optics.nanofin). The reference is N = 29 harmonics per axis. Timed: one
wavelength per N at 530 nm; the 24 wavelengths 430:660:10nm at N = 15 and at N = 17 (what
`--harmonics auto` picks for this fin), with their largest η error against N = 29 at three wavelengths.
"""

from __future__ import annotations

import os
import platform
import time

import numpy as np

from metalens_cli.optics.materials import FUSED_SILICA, SINX
from metalens_cli.optics.nanofin import Fin, fin_response

from report import write_section

FIN = Fin(395e-9, 700e-9, 305e-9, 125e-9)
REFERENCE = 29


def eta(wavelengths_m, harmonics):
    w = np.asarray(wavelengths_m)
    return fin_response(FIN, SINX.index(w), FUSED_SILICA.index(w), w, harmonics)


def main() -> None:
    load = os.getloadavg()[0]
    reference = eta([530e-9], REFERENCE)
    rows = []
    for n in (5, 7, 9, 11, 13, 15, 17, 19, 21, 25):
        r = eta([530e-9], n)
        rows.append(f"| {n} | {r.conversion[0]:.5f} | {abs(r.conversion[0] - reference.conversion[0]):.1e} | {r.seconds[0]:.2f} |")
    rows.append(f"| {REFERENCE} | {reference.conversion[0]:.5f} | (reference) | {reference.seconds[0]:.2f} |")
    wavelengths = np.arange(430, 661, 10) * 1e-9
    check = [0, 10, 23]
    references = eta(wavelengths[check], REFERENCE)
    sweeps = {}
    for n in (15, 17):
        start = time.perf_counter()
        sweep = eta(wavelengths, n)
        sweeps[n] = (sweep, time.perf_counter() - start, np.abs(sweep.conversion[check] - references.conversion).max())
    lines = [
        "## Nanofin conversion efficiency (`metalens nanofin efficiency`, RCWA through meent)",
        "",
        f"Command: `python benchmarks/bench_nanofin.py`; {os.cpu_count()} CPUs (1-min load average {load:.1f} when started), "
        f"Python {platform.python_version()}, numpy {np.__version__}. Fin 305 × 125 × 700 nm, period 395 nm, Si3N4 (Luke 2015) on "
        "fused silica (Malitson 1965); η at 530 nm against N harmonics per axis (N × N orders), reference N = 29.",
        "",
        "| N | η at 530 nm | error vs N = 29 | seconds |",
        "|---|---|---|---|",
        *rows,
        "",
        *[f"24 wavelengths 430:660:10nm at N = {n}: {seconds:.1f} s (target ≤ 30 s); largest η error against N = 29 at 430, 530 "
          f"and 660 nm: {error:.1e} (target 1e-3)." for n, (_, seconds, error) in sweeps.items()],
        "",
        "η at 457/530/628 nm (N = 17): "
        + " / ".join(f"{np.interp(w, wavelengths, sweeps[17][0].conversion):.3f}" for w in (457e-9, 530e-9, 628e-9))
        + " (interpolated; the paper's PECVD SiNx fin: 0.784 / 0.729 / 0.669).",
    ]
    write_section("nanofin", "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
