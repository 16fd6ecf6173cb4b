"""Time the MTFs of an 88-channel 512² PSF cube (2 depths × 44 wavelengths): writes its section of docs/benchmarks.md.

Run: python benchmarks/bench_mtf.py [--repeat 5]
The cube holds Gaussians (σ 1-5 px); the MTF's cost does not depend on the PSFs' shape. Timed:
``cube_mtf`` on the cube in memory (the target: ≤ 1 s), its parts, and reading the EXR file.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from report import write_section

from metalens_cli.analysis.mtf import cube_mtf, diffraction_limited_mtf, psf_mtf, radial_grid
from metalens_cli.io.exr import PsfCube, read_exr_cube, write_exr_cube

ROOT = Path(__file__).resolve().parents[1]
N, PITCH = 512, 1.85e-6
WAVELENGTHS = np.linspace(430e-9, 645e-9, 44)
DEPTHS = np.array([0.045, math.inf])


def gaussian_cube() -> np.ndarray:
    """(2, 44, 512, 512) float32 Gaussians, σ from 1 to 5 pixels."""
    y, x = np.mgrid[:N, :N] - N // 2
    r2 = (x * x + y * y).astype(np.float32)
    sigmas = np.linspace(1, 5, DEPTHS.size * WAVELENGTHS.size, dtype=np.float32).reshape(DEPTHS.size, -1)
    return np.exp(-r2 / (2 * sigmas[..., None, None] ** 2))


def timed(function, repeat: int) -> tuple[list[float], list[float]]:
    """Wall-clock and CPU seconds (this process, all threads) of each of ``repeat`` calls."""
    wall, cpu = [], []
    for _ in range(repeat):
        start, start_cpu = time.perf_counter(), time.process_time()
        function()
        wall.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    return wall, cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    psf = gaussian_cube()
    cube = PsfCube(psf, None, WAVELENGTHS, DEPTHS, {"pixel_pitch_m": PITCH, "na": 0.3})
    grid = radial_grid(N, PITCH)
    cases = {
        "`cube_mtf` (all: grid, 88 MTFs, MTF50, diffraction references)": lambda: cube_mtf(cube, at_lpmm=[50.0, 100.0]),
        "`radial_grid(512)` (ring operator)": lambda: radial_grid(N, PITCH),
        "`psf_mtf` (one batched rfft2 + sparse ring average)": lambda: psf_mtf(psf, grid),
        "`psf_mtf(remove_pixel_mtf=True)`": lambda: psf_mtf(psf, grid, remove_pixel_mtf=True),
        "`diffraction_limited_mtf` (44 wavelengths)": lambda: diffraction_limited_mtf(grid, 0.3, WAVELENGTHS),
    }
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "cube.exr"
        write_exr_cube(
            path,
            psf,
            WAVELENGTHS,
            DEPTHS,
            PITCH,
            "gaussian benchmark cube",
            normalization="peak-one",
            extra={"na": 0.3},
        )
        cases["`read_exr_cube` (88 × 512² ZIP EXR, not part of the target)"] = lambda: read_exr_cube(path)
        load = os.getloadavg()[0]
        rows = [(name, *timed(function, args.repeat)) for name, function in cases.items()]
    lines = [
        "## MTF of a PSF cube",
        "",
        f"Command: `python benchmarks/bench_mtf.py --repeat {args.repeat}`; {os.cpu_count()} CPUs (1-min load "
        f"average {load:.1f} when started: other work shares them), Python {platform.python_version()}, numpy "
        f"{np.__version__}. Cube: 2 depths × 44 wavelengths = 88 PSFs of {N} × {N} float32. Target: `cube_mtf` ≤ 1 s.",
        "CPU time counts this process's threads (scipy.fft uses all cores).",
        "",
        "| step | wall median (s) | wall min (s) | CPU median (s) |",
        "|---|---|---|---|",
        *[
            f"| {name} | {statistics.median(wall):.3f} | {min(wall):.3f} | {statistics.median(cpu):.3f} |"
            for name, wall, cpu in rows
        ],
    ]
    write_section("mtf", "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
