"""Benchmark: seconds per training step at the paper's resolution (presets/split-spectrum.toml:
512 × 512 sensor, 3 wavelengths per channel, batch 1), for the radial θ(r) (one parameter per
meta-atom ring) and the 2-D θ(x, y) (one per meta-atom site, 6369² as in the paper).

Run: python benchmarks/bench_optimize.py [--device cpu|cuda] [--threads 2] [--steps 3] [--steps-2d 1]
[--parameterization radial 2d]. Rewrites its section of docs/benchmarks.md (one per device type).
A 2-D step at this size takes minutes and several GiB on 2 CPU cores; its backward pass runs the
adjoint propagation, so each PSF holds only its window field between the passes (see
``optics.psf``).
"""

from __future__ import annotations

import argparse
import dataclasses
import resource
from pathlib import Path

import torch

from metalens_cli.design.training import time_steps
from metalens_cli.io.presets import load_preset
from metalens_cli.runtime import retain_freed_memory

PRESET = Path(__file__).resolve().parents[1] / "presets" / "split-spectrum.toml"


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--steps", type=int, default=3, help="radial steps")
    parser.add_argument("--steps-2d", type=int, default=1, help="2-D steps")
    parser.add_argument("--parameterization", nargs="+", default=["quick", "radial", "2d"], choices=["quick", "radial", "2d"],
                        help="quick: presets/quick-split-spectrum.toml as it is (128² crop, 400 radial samples)")
    args = parser.parse_args()
    retain_freed_memory()
    torch.set_num_threads(args.threads)
    base = load_preset(PRESET)
    device = torch.device(args.device)
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else f"{args.threads} CPU threads"
    rows = [
        f"## Training step at the paper's resolution, {device.type} (`python benchmarks/bench_optimize.py --device {args.device}`)",
        "",
        f"`presets/split-spectrum.toml` (512² sensor, 3 wavelengths per channel, batch 1) on {name}, and the quick "
        "preset as it is (128² crop, 400 radial design samples, batch 2); "
        f"Radial: {args.steps} steps, the median of those after the first (which builds the kernels); "
        f"2-D: {args.steps_2d} step(s), the median likewise (one step: that step).",
        "",
        "| θ | parameters | propagator | s/step | first step s | PSFs s/step (mean) | backward s/step (mean) | peak memory |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for kind in args.parameterization:
        if kind == "quick":
            preset = load_preset(PRESET.with_name("quick-split-spectrum.toml"))
        else:
            preset = dataclasses.replace(base, lens=dataclasses.replace(base.lens, parameterization=kind),
                                         optimize=dataclasses.replace(base.optimize, design_grid=0))
        steps = args.steps_2d if kind == "2d" else args.steps
        r = time_steps(preset, steps, device)
        stages = r["seconds_by_stage"]
        peak = (r["peak_memory_bytes"] if "peak_memory_bytes" in r
                else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024)  # CPU: the process's peak RSS so far
        memory = "GPU" if "peak_memory_bytes" in r else "RSS"
        label = {"quick": "radial, quick preset", "radial": "radial", "2d": "2-D"}[kind]
        rows.append(f"| {label} | {r['parameters']:,} | {'2-D ASM' if kind == '2d' else 'radial (Hankel)'} | "
                    f"{r['seconds_per_step']:.2f} | {r['first_step_s']:.2f} | {stages.get('psf', 0) / steps:.2f} | "
                    f"{stages.get('backward', 0) / steps:.2f} | {peak / 2**30:.1f} GiB ({memory}) |")
        print(rows[-1], flush=True)
    from report import write_section

    write_section(f"optimize-{device.type}", "\n".join(rows))


if __name__ == "__main__":
    main()
