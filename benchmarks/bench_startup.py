"""Wall time of closed-form commands (they must not import torch): writes its section of docs/benchmarks.md.

Run: python benchmarks/bench_startup.py [--repeat 7]
Uses the `metalens` console script next to the running interpreter.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

from report import write_section

ROOT = Path(__file__).resolve().parents[1]
COMMANDS = [
    ["--help"],
    ["symmetry", "--f", "4mm", "--lambda-d", "450nm"],
    ["symmetry", "--f", "4mm", "--lambda-d", "450nm", "--json"],
    ["bands", "check", "--preset", "presets/split-spectrum.toml"],
    ["bands", "check", "--preset", "presets/split-spectrum.toml", "--json"],
]


def time_command(exe: str, args: list[str], repeat: int) -> list[float]:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        subprocess.run([exe, *args], cwd=ROOT, capture_output=True, check=False)
        times.append(time.perf_counter() - start)
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeat", type=int, default=7)
    args = parser.parse_args()
    exe = str(Path(sys.executable).with_name("metalens"))
    lines = [
        "## Startup time of closed-form commands",
        "",
        f"Command: `python benchmarks/bench_startup.py --repeat {args.repeat}`; "
        f"{os.cpu_count()} CPUs, Python {platform.python_version()}. Target: < 0.3 s wall.",
        "",
        "| command | median (s) | min (s) |",
        "|---|---|---|",
    ]
    for command in COMMANDS:
        times = time_command(exe, command, args.repeat)
        lines.append(f"| `metalens {' '.join(command)}` | {statistics.median(times):.3f} | {min(times):.3f} |")
    write_section("startup", "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
