"""The nanofin RCWA: η error against Fourier harmonics and time for both solvers, the 24-wavelength
target, the paper's 31 × 31-fin sweep coarse to fine, a preset's η(λ), and which film index
reproduces the paper's efficiencies. Writes its section of docs/benchmarks.md.

Run: python benchmarks/bench_nanofin.py [--skip-sweep]
Fin 305 × 125 × 700 nm, period 395 nm, Si3N4 (Luke) on fused silica, light from the substrate
(metalens_cli.optics.nanofin). The reference is fin_modes at N = 41 harmonics per axis. Targets
(issue 17): 24 wavelengths within 1e-3 of converged in ≤ 30 s; the sweep (31 × 31 fins ×
24 wavelengths) in ≤ 20 min; on 2 cores.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from report import write_section

from metalens_cli.optics.fin import Fin
from metalens_cli.optics.materials import FUSED_SILICA, SINX
from metalens_cli.optics.nanofin import converge, convergence_seconds, estimate_seconds, fin_response

FIN = Fin(395e-9, 700e-9, 305e-9, 125e-9)
REFERENCE = 41
WAVELENGTHS = np.arange(430, 661, 10) * 1e-9
PAPER = {457e-9: 0.784, 530e-9: 0.729, 628e-9: 0.669}


def eta(wavelengths_m, harmonics, solver="modes"):
    w = np.asarray(wavelengths_m)
    return fin_response(FIN, SINX.index(w), FUSED_SILICA.index(w), w, harmonics, solver=solver)


def timed(function, *args, **kwargs):
    start = time.perf_counter()
    value = function(*args, **kwargs)
    return value, time.perf_counter() - start


def harmonics_table() -> list[str]:
    w = WAVELENGTHS
    reference = eta(w, REFERENCE)
    rows = []
    for n in (5, 7, 9, 11, 13, 15, 17, 19, 21, 23, 25, 29, 33):
        r, seconds = timed(eta, w, n)
        error = np.abs(r.conversion - reference.conversion)
        meent = ""
        if n <= 21:
            m, meent_seconds = timed(eta, [530e-9], n, "meent")
            meent = f"{abs(m.conversion[0] - reference.conversion[10]):.1e} | {meent_seconds:.2f}"
        else:
            meent = "— | —"
        rows.append(
            f"| {n} | {error[10]:.1e} | {error.max():.1e} | {seconds:.2f} | {estimate_seconds(n, w.size):.2f} | "
            f"{meent} |"
        )
    return rows


def target_rows() -> list[str]:
    w = WAVELENGTHS
    reference = eta(w, REFERENCE)
    (chosen, table, r), seconds = timed(converge, FIN, SINX.index(w), FUSED_SILICA.index(w), w)
    fixed, fixed_seconds = timed(eta, w, 25)
    return [
        "- `--harmonics auto` (N = 5, 7, … until η moves < 1e-3 at every wavelength from N − 2 and N − 4): chose N = "
        f"{chosen} in {seconds:.1f} s for all of it (estimated {convergence_seconds(chosen, w.size):.1f} s); largest η "
        f"error over the 24 wavelengths against N = {REFERENCE}: "
        f"{np.abs(r.conversion - reference.conversion).max():.1e}.",
        f"- `--harmonics 25`: {fixed_seconds:.1f} s; largest error "
        f"{np.abs(fixed.conversion - reference.conversion).max():.1e}.",
    ]


def sweep_rows() -> list[str]:
    with tempfile.TemporaryDirectory() as folder:
        env = {**os.environ, "METALENS_CACHE": str(Path(folder) / "cache")}
        command = [
            "nanofin",
            "sweep",
            "--width",
            "210:360:5nm",
            "--length",
            "40:190:5nm",
            "--quiet",
            "-o",
            str(Path(folder) / "sweep"),
            "--json",
        ]
        start = time.perf_counter()
        out = subprocess.run(
            [sys.executable, "-m", "metalens_cli", *command], capture_output=True, text=True, env=env, check=True
        )
        wall = time.perf_counter() - start
        report = json.loads(out.stdout)
        estimate = out.stderr.strip().splitlines()[0].split(": ")[-1]  # announce's line: about …, (up to …)
        start = time.perf_counter()
        again = subprocess.run(
            [sys.executable, "-m", "metalens_cli", *command[:-3], "-o", str(Path(folder) / "again"), "--json"],
            capture_output=True,
            text=True,
            env=env,
            check=True,
        )
        cached_wall = time.perf_counter() - start
    c = report["recommended"]
    f = c["converged"]
    return [
        f"- `metalens {' '.join(command[:-4])} -o DIR` (31 × 31 fins × 24 wavelengths, 8 per band, map at N = 9): "
        f"{wall:.0f} s wall (target ≤ 20 min): map {report['seconds']:.0f} s, the chosen fin converged (N = "
        f"{f['harmonics']}) with its {f['fins']} neighbours {f['seconds']:.0f} s; the command's estimate said "
        f"{estimate}. Again, the map and the refinement read from the cache: {cached_wall:.0f} s.",
        f"- Recommended: {c['width_m'] * 1e9:g} × {c['length_m'] * 1e9:g} nm, mean η {c['score']:.3f} at N = 9, "
        f"converged {f['score']:.3f} (per band "
        + " / ".join(f"{v:.3f}" for v in f["eta_per_band"])
        + f"), worst neighbour {f['worst_neighbour']:.3f}"
        f" ({'keeps' if f['robust'] else 'does not keep'} 95 %).",
        f"- Cached: {json.loads(again.stdout)['cached']}.",
    ]


def paper_rows() -> list[str]:
    w = np.array(list(PAPER))
    rows = [
        f"| Si3N4, Luke 2015 (n = {SINX.index(w)[0].real:.3f} … {SINX.index(w)[-1].real:.3f}) | "
        + " | ".join(f"{v:.3f}" for v in eta(w, 25).conversion)
        + " |"
    ]
    for n in (2.0, 2.1, 2.15, 2.17, 2.2):
        r = fin_response(FIN, np.full(3, n), FUSED_SILICA.index(w), w, 25)
        rows.append(f"| constant n = {n:g} | " + " | ".join(f"{v:.3f}" for v in r.conversion) + " |")
    rows.append("| the paper (PECVD SiNx) | " + " | ".join(f"{v:.3f}" for v in PAPER.values()) + " |")
    return rows


def main() -> None:
    load = os.getloadavg()[0]
    table = harmonics_table()
    target = target_rows()
    sweep = [] if "--skip-sweep" in sys.argv else sweep_rows()
    lines = [
        "## Nanofin conversion efficiency (`metalens nanofin efficiency`, `nanofin sweep`)",
        "",
        f"Command: `python benchmarks/bench_nanofin.py`; {os.cpu_count()} CPUs (1-min load average {load:.1f} when "
        f"started), Python {platform.python_version()}, torch {torch.__version__}, numpy {np.__version__}. Fin 305 × "
        "125 × 700 nm, period 395 nm, Si3N4 (Luke 2015) on fused silica (Malitson 1965), 24 wavelengths 430:660:10nm. "
        f"Reference: fin_modes at N = {REFERENCE}. fin_modes batches the 24 wavelengths in one call; meent solves one "
        "wavelength (530 nm) per call.",
        "",
        "| N | fin_modes: η error at 530 nm | fin_modes: largest error, 24 λ | fin_modes: seconds, 24 λ "
        "| estimated seconds | meent: η error at 530 nm | meent: seconds, 1 λ |",
        "|---|---|---|---|---|---|---|",
        *table,
        "",
        "Target: 24 wavelengths within 1e-3 of converged in ≤ 30 s.",
        *target,
        "",
        *(["Sweep (coarse to fine):", *sweep, ""] if sweep else []),
        "Which film reproduces the paper's efficiencies (η at 457 / 530 / 628 nm, N = 25):",
        "",
        "| fin material | 457 nm | 530 nm | 628 nm |",
        "|---|---|---|---|",
        *paper_rows(),
    ]
    write_section("nanofin", "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
