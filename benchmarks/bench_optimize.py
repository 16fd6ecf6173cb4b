"""Benchmark: seconds per training step, for the quick preset as it is and at the paper's
resolution (presets/split-spectrum.toml: 512 × 512 sensor, 3 wavelengths per channel, batch 1),
radial θ(r) (one parameter per meta-atom ring) and 2-D θ(x, y) (one per site, 6369² as in the
paper).

Run: python benchmarks/bench_optimize.py [--device cpu|cuda] [--threads 2] [--steps 4]
[--steps-quick 40] [--steps-2d 1] [--parameterization quick radial 2d]
[--baseline DIR [--baseline-label NAME]] [--presets DIR] [--optimize KEY=VALUE ...].
Rewrites its section of docs/benchmarks.md (one per device type; with ``--optimize`` a section of
its own per set of keys). Every row runs in a fresh process (its own peak memory). ``--baseline DIR`` (a checkout
of an earlier commit, e.g. from ``git worktree add DIR HEAD``) measures each row again with DIR's
package right after, on the same presets, so that the before/after ratios come from one sitting.
Each step's PSF windows follow its light (``optics.channel_psf``), so the step's cost follows the
design: the quick rows run long enough for the learned lens to spread its light (and the kernels'
plan to grow, which costs seconds each time); the rows give the windows the last step needed. A 2-D
step at this size takes minutes and several GiB on 2 CPU cores; its backward pass runs the adjoint
propagation (see ``optics.psf``). ``--optimize KEY=VALUE`` (TOML values, repeatable): this
checkout's rows with those ``[optimize]`` keys set, e.g. ``scene_blocks=true`` (scenes and dirt at
the halo's blocks beyond the cores' reach) or ``radial_margin=0.1``; the baseline's rows as their
presets say.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import resource
import subprocess
import sys
import tomllib
from pathlib import Path

import torch

from metalens_cli.runtime import retain_freed_memory

STEP_STAGES = ("psf", "scenes", "formation_loss", "backward", "update")  # together, a whole step
ROOT = Path(__file__).resolve().parents[1]
PRESET = ROOT / "presets" / "split-spectrum.toml"
QUICK_PRESETS = {"quick": "quick-split-spectrum.toml", "joint": "quick-joint-filter.toml"}  # timed as they are
KINDS = ("quick", "joint", "radial", "2d")


def optimize_key(text: str) -> tuple[str, str]:
    """``KEY=VALUE`` of ``--optimize``: an ``[optimize]`` key and its TOML value."""
    key, sep, value = text.partition("=")
    if not sep or not key.strip() or not value.strip():
        raise argparse.ArgumentTypeError(f"{text!r}: expected KEY=VALUE, e.g. scene_blocks=true")
    try:
        tomllib.loads(f"v = {value.strip()}")
    except tomllib.TOMLDecodeError as error:
        raise argparse.ArgumentTypeError(f"{text!r}: the value is not TOML ({error})") from None
    return key.strip(), value.strip()


def measure(kind: str, presets: Path, device: str, threads: int, steps: int, optimize: dict | None = None) -> dict:
    """time_steps' report for one kind, plus this process's peak memory."""
    from metalens_cli.design.training import time_steps
    from metalens_cli.io.presets import load_preset

    torch.set_num_threads(threads)
    if kind in QUICK_PRESETS:
        preset = load_preset(presets / QUICK_PRESETS[kind])
    else:
        base = load_preset(presets / PRESET.name)
        preset = dataclasses.replace(
            base,
            lens=dataclasses.replace(base.lens, parameterization=kind),
            optimize=dataclasses.replace(base.optimize, design_grid=0),
        )
    if optimize:
        preset = dataclasses.replace(preset, optimize=dataclasses.replace(preset.optimize, **optimize))
    r = time_steps(preset, steps, torch.device(device))
    r["peak_bytes"] = r.get("peak_memory_bytes") or resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    r["kind"] = kind
    r["mean_seconds_per_step"] = sum(r["seconds_by_stage"].get(k, 0.0) for k in STEP_STAGES) / steps
    return r


def measure_in_subprocess(kind: str, args, steps: int, code: Path) -> dict:
    """``measure`` in a fresh process (its own peak memory) with the package of ``code``."""
    command = [
        sys.executable,
        __file__,
        "--emit-json",
        kind,
        "--presets",
        str(args.presets),
        "--device",
        args.device,
        "--threads",
        str(args.threads),
        "--steps",
        str(steps),
        *(f"--optimize={k}={v}" for k, v in (args.optimize if code == ROOT else [])),
    ]
    result = json.loads(
        subprocess.run(
            command,
            env={**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(code), os.environ.get("PYTHONPATH")]))},
            check=True,
            stdout=subprocess.PIPE,
            text=True,
        ).stdout
    )  # its errors reach stderr
    print(json.dumps({k: v for k, v in result.items() if k != "seconds_by_stage"}), file=sys.stderr, flush=True)
    return result


def row(r: dict, label: str) -> str:
    stages, steps = r["seconds_by_stage"], r["steps"]
    memory = "GPU" if "peak_memory_bytes" in r else "RSS"
    windows = r.get("windows_px")
    window_text = f"{windows['near']} / {windows['far']}" if windows and windows["near"] else "fixed"
    mean = r["mean_seconds_per_step"]
    cpu = r.get("cpu_seconds_per_step")  # a baseline's time_steps may not report it
    cpu_text = "—" if cpu is None else f"{cpu:.2f}"
    return (
        f"| {label} | {r['parameters']:,} | {'2-D ASM' if r['kind'] == '2d' else 'radial (Hankel)'} | {steps} | "
        f"{window_text} | {r['seconds_per_step']:.2f} | {cpu_text} | {mean:.2f} | {r['first_step_s']:.2f} | "
        f"{stages.get('psf_kernels', 0):.1f} | {stages.get('psf', 0) / steps:.2f} | "
        f"{stages.get('backward', 0) / steps:.2f} | {r['peak_bytes'] / 2**30:.1f} GiB ({memory}) |"
    )


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--steps", type=int, default=4, help="steps at paper size (radial)")
    parser.add_argument(
        "--steps-quick",
        type=int,
        default=40,
        help="quick-preset steps from θ_init: long enough for its light to spread and the plan to grow",
    )
    parser.add_argument("--steps-2d", type=int, default=1, help="2-D steps")
    parser.add_argument(
        "--parameterization",
        nargs="+",
        default=["quick", "radial", "2d"],
        choices=KINDS,
        help="quick: presets/quick-split-spectrum.toml as it is (128² crop); "
        "joint: presets/quick-joint-filter.toml (the filter learned with θ)",
    )
    parser.add_argument("--baseline", type=Path, help="a checkout of an earlier commit to measure right after")
    parser.add_argument("--baseline-label", help="the baseline's name in the table [its git commit]")
    parser.add_argument(
        "--baseline-parameterization",
        nargs="+",
        choices=KINDS,
        help="the rows measured with the baseline too (default: all)",
    )
    parser.add_argument(
        "--optimize",
        action="append",
        type=optimize_key,
        default=[],
        metavar="KEY=VALUE",
        help="this checkout's rows with this [optimize] key (a TOML value: scene_blocks=true, radial_margin=0.1)",
    )
    parser.add_argument("--emit-json", choices=KINDS, help=argparse.SUPPRESS)  # one kind, in a subprocess
    parser.add_argument(
        "--presets",
        type=Path,
        default=PRESET.parent,
        help="the folder of presets both trees time (default: this checkout's)",
    )
    args = parser.parse_args()
    retain_freed_memory()
    if args.emit_json:
        overrides = {k: tomllib.loads(f"v = {v}")["v"] for k, v in args.optimize}
        report = measure(args.emit_json, args.presets, args.device, args.threads, args.steps, overrides)
        print(json.dumps(report))
        return
    device = torch.device(args.device)
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else f"{args.threads} CPU threads"
    steps = {"quick": args.steps_quick, "joint": args.steps_quick, "radial": args.steps, "2d": args.steps_2d}
    trees = [ROOT] + ([args.baseline.resolve()] if args.baseline else [])
    compared = args.baseline_parameterization or args.parameterization
    results = {
        (tree, kind): measure_in_subprocess(kind, args, steps[kind], tree)
        for kind in args.parameterization
        for tree in trees
        if tree == ROOT or kind in compared
    }
    commit = (
        args.baseline_label
        or subprocess.run(
            ["git", "-C", str(args.baseline), "rev-parse", "--short", "HEAD"], capture_output=True, text=True
        ).stdout.strip()
        if args.baseline
        else ""
    )
    keys = "".join(f" --optimize {k}={v}" for k, v in args.optimize)
    lines = [
        f"## Training step, {device.type}{', ' + ', '.join(f'{k} = {v}' for k, v in args.optimize) if keys else ''} "
        f"(`python benchmarks/bench_optimize.py --device {args.device}{' --baseline DIR' if args.baseline else ''}"
        f"{keys}`)",
        "",
        ("" if args.presets.resolve() == PRESET.parent.resolve() else f"Presets from `{args.presets}`. ")
        + f"The quick preset (`quick-split-spectrum.toml`, 128² crop, batch 2; `quick-joint-filter.toml` learns the "
        f"filter with θ, 4 wavelengths per band): {args.steps_quick} steps from θ_init, "
        f"long enough for the light to spread and the plan to grow; `split-spectrum.toml` (512² sensor, 3 wavelengths "
        f"per channel, batch 1): {args.steps} steps (radial), {args.steps_2d} (2-D); on {name}, each row a fresh "
        "process. Median: over the steps after the first; mean: over all steps, kernel builds included; kernels: their "
        "total seconds (Hankel kernel and output rows); CPU s/step: the process's CPU time (every thread) over the "
        "median's steps, their median: on a CPU no step is shorter than it over the threads' cores. Windows: what the "
        "last step's light needed (near / far, px)."
        + (
            " Rows without a baseline label: this checkout with `[optimize]` "
            + ", ".join(f"`{k} = {v}`" for k, v in args.optimize)
            + "."
            if keys
            else ""
        )
        + (
            f" Baseline rows ({commit}): {'' if args.baseline_label else 'that commit, '}the same presets, each "
            "measured right after the row above it, on the same machine."
            if args.baseline
            else ""
        ),
        "",
        "| θ | parameters | propagator | steps | windows px | median s/step | CPU s/step | mean s/step | first step s "
        "| kernels s | PSFs s/step | backward s/step | peak memory |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    labels = {
        "quick": "radial, quick preset",
        "joint": "radial, quick preset, filter learned",
        "radial": "radial",
        "2d": "2-D",
    }
    for kind in args.parameterization:
        for tree in trees:
            if (tree, kind) in results:
                lines.append(row(results[tree, kind], labels[kind] + ("" if tree == ROOT else f" ({commit})")))
    if args.baseline:
        lines += [
            "",
            "| θ | median s/step now / baseline | mean s/step now / baseline | peak memory now / baseline |",
            "|---|---|---|---|",
        ]
        for kind in (k for k in args.parameterization if k in compared):
            r, b = results[ROOT, kind], results[trees[1], kind]
            lines.append(
                f"| {labels[kind]} | {r['seconds_per_step'] / b['seconds_per_step']:.2f} | "
                f"{r['mean_seconds_per_step'] / b['mean_seconds_per_step']:.2f} | "
                f"{r['peak_bytes'] / b['peak_bytes']:.2f} |"
            )
    print("\n".join(lines), flush=True)
    from report import write_section

    section = "".join(f"-{k.replace('_', '-')}" for k, _ in args.optimize)  # e.g. optimize-cpu-scene-blocks
    write_section(f"optimize-{device.type}{section}", "\n".join(lines))


if __name__ == "__main__":
    main()
