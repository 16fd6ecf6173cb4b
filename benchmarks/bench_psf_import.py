"""Time `metalens psf import` of 88 bench frames of 2048² 16-bit: writes its section of docs/benchmarks.md.

Run: python benchmarks/bench_psf_import.py [--repeat 3] [--format png|tif]
The frames (2 depths × 44 wavelengths) hold Gaussian spots (σ 1.5-6 px) at random sub-pixel
places with Poisson photons, a dark offset and read noise, plus a dark frame; the target is
the whole import (reading, first pass, hot pixels, centring, crop) ≤ 10 s on 2 cores. Timed:
the core (`import_psfs`, frames read from disk), with the window given and automatic, and the
command end to end (process start, manifest, import, EXR write).
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
from report import write_section

from metalens_cli.analysis.measured_psf import ImportSettings, import_psfs
from metalens_cli.io.psf_manifest import read_manifest

ROOT = Path(__file__).resolve().parents[1]
SIDE, DEPTHS, WAVELENGTHS = 2048, ("45mm", "inf"), np.linspace(430, 645, 44)
sys.path.insert(0, str(ROOT / "tests"))
from synthetic import bench_frame, gaussian_spot  # noqa: E402


def write_frames(folder: Path, suffix: str) -> Path:
    """88 frames and their manifest; returns the manifest."""
    rng = np.random.default_rng(0)
    rows = ["file,wavelength,depth,exposure"]
    sigmas = iter(np.linspace(1.5, 6, len(DEPTHS) * WAVELENGTHS.size))
    for depth in DEPTHS:
        for wavelength in WAVELENGTHS:
            sigma = next(sigmas)
            centre = SIDE / 2 + rng.uniform(-100, 100, 2)
            spot = np.zeros((SIDE, SIDE))
            top, left = int(centre[0]) - 64, int(centre[1]) - 64
            spot[top : top + 128, left : left + 128] = gaussian_spot(
                128, 128, (centre[0] - top, centre[1] - left), sigma
            )
            name = f"psf_{depth}_{wavelength:.0f}nm{suffix}"
            cv2.imwrite(str(folder / name), bench_frame(spot, rng, photons=2e5 * sigma**2))
            rows.append(f"{name},{wavelength:.3f}nm,{depth},10ms")
    (folder / "psf.csv").write_text("\n".join(rows) + "\n")
    return folder / "psf.csv"


def timed(function, repeat: int) -> list[float]:
    wall = []
    for _ in range(repeat):
        start = time.perf_counter()
        function()
        wall.append(time.perf_counter() - start)
    return wall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--format", choices=("png", "tif"), default="png")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        manifest_path = write_frames(folder, f".{args.format}")
        manifest = read_manifest(manifest_path)
        size = sum(p.stat().st_size for p in folder.iterdir()) / 2**20
        load = os.getloadavg()[0]
        command = [
            sys.executable,
            "-m",
            "metalens_cli",
            "psf",
            "import",
            str(manifest_path),
            "--pixel-pitch",
            "1.85um",
            "--pixels",
            "128",
            "-o",
            str(folder / "cube.exr"),
            "--quiet",
            "--json",
        ]
        cases = {
            "`import_psfs`, window given (128²)": lambda: import_psfs(manifest, ImportSettings(1.85e-6, pixels=128)),
            "`import_psfs`, automatic window": lambda: import_psfs(manifest, ImportSettings(1.85e-6)),
            "`metalens psf import … --pixels 128` (end to end, EXR written)": lambda: subprocess.run(
                command, check=True, capture_output=True
            ),
        }
        rows = [(name, timed(function, args.repeat)) for name, function in cases.items()]
    lines = [
        "## Import of measured PSF frames (`metalens psf import`)",
        "",
        f"Command: `python benchmarks/bench_psf_import.py --repeat {args.repeat} --format {args.format}`; "
        f"{os.cpu_count()} CPUs (1-min load average {load:.1f} when started), Python {platform.python_version()}, "
        f"numpy {np.__version__}, OpenCV {cv2.__version__}. 88 frames (2 depths × 44 wavelengths) of {SIDE} × {SIDE} "
        f"16-bit {args.format.upper()} ({size:.0f} MiB on disk), read in one thread while 2 threads process. "
        "Target: ≤ 10 s.",
        "",
        "| step | wall median (s) | wall min (s) | per frame (ms) |",
        "|---|---|---|---|",
        *[
            f"| {name} | {statistics.median(wall):.2f} | {min(wall):.2f} | {1e3 * statistics.median(wall) / 88:.0f} |"
            for name, wall in rows
        ],
    ]
    write_section(f"psf-import-{args.format}", "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
