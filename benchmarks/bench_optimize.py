"""Benchmark: seconds per training step, for the quick preset as it is and at the paper's
resolution (presets/split-spectrum.toml: 512 × 512 sensor, 3 wavelengths per channel, batch 1),
radial θ(r) (one parameter per meta-atom ring) and 2-D θ(x, y) (one per site, 6369² as in the
paper).

Run: python benchmarks/bench_optimize.py [--device cpu|cuda] [--threads 2] [--steps 3] [--steps-2d 1]
[--parameterization quick radial 2d] [--baseline DIR] [--presets DIR]. Rewrites its section of docs/benchmarks.md
(one per device type). ``--baseline DIR`` (a checkout of an earlier commit, e.g. from
``git worktree add DIR bfff46b``) measures the same rows with DIR's package and presets in a
subprocess right after, so that the before/after ratios come from one sitting (with
``--presets DIR/presets`` both time the baseline's presets: the code alone). Each step's PSF
windows follow its light (``optics.channel_psf``), so the step's cost follows the design: the
rows give the windows the last step needed. A 2-D step at this size takes minutes and several
GiB on 2 CPU cores; its backward pass runs the adjoint propagation (see ``optics.psf``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import resource
import subprocess
import sys
from pathlib import Path

import torch

from metalens_cli.runtime import retain_freed_memory

PRESET = Path(__file__).resolve().parents[1] / "presets" / "split-spectrum.toml"


def measure(kinds, presets: Path, device: str, threads: int, steps: int, steps_2d: int) -> list[dict]:
    """One result per kind: time_steps' report plus the peak memory."""
    from metalens_cli.design.training import time_steps
    from metalens_cli.io.presets import load_preset

    torch.set_num_threads(threads)
    base = load_preset(presets / PRESET.name)
    results = []
    for kind in kinds:
        if kind == "quick":
            preset = load_preset(presets / "quick-split-spectrum.toml")
        else:
            preset = dataclasses.replace(base, lens=dataclasses.replace(base.lens, parameterization=kind),
                                         optimize=dataclasses.replace(base.optimize, design_grid=0))
        r = time_steps(preset, steps_2d if kind == "2d" else steps, torch.device(device))
        r["peak_bytes"] = r.get("peak_memory_bytes") or resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
        r["kind"] = kind
        results.append(r)
        print(json.dumps({k: v for k, v in r.items() if k != "seconds_by_stage"}), file=sys.stderr, flush=True)
    return results


def row(r: dict, label: str) -> str:
    stages, steps = r["seconds_by_stage"], r["steps"]
    memory = "GPU" if "peak_memory_bytes" in r else "RSS"
    windows = r.get("windows_px")
    window_text = f"{windows['near']} / {windows['far']}" if windows else "533 / 467 (fixed)" if r["kind"] == "quick" else "fixed"
    return (f"| {label} | {r['parameters']:,} | {'2-D ASM' if r['kind'] == '2d' else 'radial (Hankel)'} | {window_text} | "
            f"{r['seconds_per_step']:.2f} | {r['first_step_s']:.2f} | {stages.get('psf', 0) / steps:.2f} | "
            f"{stages.get('backward', 0) / steps:.2f} | {r['peak_bytes'] / 2**30:.1f} GiB ({memory}) |")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--steps", type=int, default=3, help="radial steps")
    parser.add_argument("--steps-2d", type=int, default=1, help="2-D steps")
    parser.add_argument("--parameterization", nargs="+", default=["quick", "radial", "2d"], choices=["quick", "radial", "2d"],
                        help="quick: presets/quick-split-spectrum.toml as it is (128² crop)")
    parser.add_argument("--baseline", type=Path, help="a checkout of an earlier commit to measure right after")
    parser.add_argument("--emit-json", action="store_true", help=argparse.SUPPRESS)  # the baseline's subprocess
    parser.add_argument("--presets", type=Path, default=PRESET.parent,
                        help="the folder of presets to time (default: this checkout's; a baseline's for like-for-like code)")
    args = parser.parse_args()
    retain_freed_memory()
    if args.emit_json:
        print(json.dumps(measure(args.parameterization, args.presets, args.device, args.threads, args.steps, args.steps_2d)))
        return
    device = torch.device(args.device)
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else f"{args.threads} CPU threads"
    results = measure(args.parameterization, args.presets, args.device, args.threads, args.steps, args.steps_2d)
    baseline = []
    if args.baseline:
        command = [sys.executable, __file__, "--emit-json", "--presets", str(args.baseline / "presets"), "--device", args.device,
                   "--threads", str(args.threads), "--steps", str(args.steps), "--steps-2d", str(args.steps_2d),
                   "--parameterization", *args.parameterization]
        env = {**os.environ, "PYTHONPATH": str(args.baseline)}
        baseline = json.loads(subprocess.run(command, env=env, check=True, capture_output=True, text=True).stdout)
    commit = subprocess.run(["git", "-C", str(args.baseline), "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True).stdout.strip() if args.baseline else ""
    lines = [
        f"## Training step, {device.type} (`python benchmarks/bench_optimize.py --device {args.device}"
        f"{' --baseline DIR' if args.baseline else ''}`)",
        "",
        ("" if args.presets.resolve() == PRESET.parent.resolve() else
         f"Presets of {commit} for both rows of each θ (the code alone differs). "
         if args.baseline and args.presets.resolve() == (args.baseline / "presets").resolve()
         else f"Presets from `{args.presets}` for both rows of each θ. ")
        + f"The quick preset (`quick-split-spectrum.toml`, 128² crop, batch 2) and "
        f"`split-spectrum.toml` (512² sensor, 3 wavelengths per channel, batch 1) on {name}; radial: {args.steps} steps "
        f"from θ_init, the median of those after the first (which builds the kernels); 2-D: {args.steps_2d} step(s). "
        "Windows: what the last step's light needed (near / far, px)."
        + (f" Baseline rows: commit {commit}, measured in a subprocess right after, on the same machine." if baseline else ""),
        "",
        "| θ | parameters | propagator | windows px | s/step | first step s | PSFs s/step (mean) | backward s/step (mean) | peak memory |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    labels = {"quick": "radial, quick preset", "radial": "radial", "2d": "2-D"}
    for r in results:
        lines.append(row(r, labels[r["kind"]]))
    for b in baseline:
        lines.append(row(b, f"{labels[b['kind']]} ({commit})"))
    if baseline:
        lines += ["", "| θ | s/step now / baseline |", "|---|---|"]
        for r, b in zip(results, baseline):
            lines.append(f"| {labels[r['kind']]} | {r['seconds_per_step'] / b['seconds_per_step']:.2f} |")
    print("\n".join(lines), flush=True)
    from report import write_section

    write_section(f"optimize-{device.type}", "\n".join(lines))


if __name__ == "__main__":
    main()
