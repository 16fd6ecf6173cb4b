"""Benchmark: a training step's radial angle margin (``[optimize] radial_margin``) against its cost
and its error.

For training draws of the quick preset (its depths and wavelength samples) and each design, the
step's channel PSFs (``design.step.step_psfs``, one scale, so that they compare pixel by pixel) in
fixed capacities, with the radial propagator keeping ``radial_margin`` of sin-angle past the
field's steepest ray: the Hankel plan (frequencies, pupil nodes, support radius), the warm seconds
of the stack, the windows its light needs, and the relative L2 of each channel PSF (the largest
over channels and depths, over the step's own windows) against the mix of ``compute_psf``'s
monochromatic PSFs at doubled sampling (every margin and density × 2: the slow reference), and
the light each channel's window keeps below the default margin's (the edge diffraction a narrower
margin no longer counts).

Run: python benchmarks/bench_radial_margin.py [--designs D ...] [--margins 0.2 0.1 0.05]
[--steps 2] [--capacity 987] [--threads 2]. Rewrites its section of docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import platform
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]


def rows(spec: str, preset, margins: list[float], steps: int, capacity: int) -> list[dict]:
    """One row per (training draw, margin)."""
    from metalens_cli.design.step import Windows, draw_step, spectral_source, step_psfs
    from metalens_cli.io.designs import resolve_design
    from metalens_cli.optics.psf import compute_psf
    from metalens_cli.optics.sampling import PsfGrid
    from metalens_cli.optics.spectra import mix_channels
    from metalens_cli.optics.window import crop_window

    lens = resolve_design(spec, preset).lens
    one_scale = dataclasses.replace(preset.optimize, halo_scale=1)
    windows = Windows.fitted(capacity, capacity, capacity)
    out = []
    for step in range(steps):
        draw = draw_step(preset, spectral_source(preset), preset.optimize.seed, step)
        lams, zs = [float(x) for x in draw.wavelengths_m], [draw.z_near_m, draw.z_far_m]
        stacks = {}
        with torch.no_grad():
            for margin in margins:
                p = dataclasses.replace(preset, optimize=dataclasses.replace(one_scale, radial_margin=margin))
                step_psfs(lens, p, draw, windows, "cpu")  # builds (and caches) this margin's kernels
                start = time.perf_counter()
                stacks[margin] = step_psfs(lens, p, draw, windows, "cpu")[0], time.perf_counter() - start
            n = max(psf.shape[-1] for stack, _ in stacks.values() for psf in stack.psfs)  # windows grow past caps
            grid = PsfGrid(lams, zs, n, preset.sensor.pixel_pitch_m, preset.lens.focal_length_m)
            fine = compute_psf(lens, grid, oversample=2.0).psf.double()
        weights = torch.as_tensor(draw.weights, dtype=torch.float64)
        default = stacks[margins[0]][0]
        for margin, (stack, seconds) in stacks.items():
            errors = []
            for i, psf in enumerate(stack.psfs):
                reference = crop_window(mix_channels(fine[i], weights), psf.shape[-1])
                diff = (psf.double() - reference).flatten(1).norm(dim=1) / reference.flatten(1).norm(dim=1)
                errors.append(float(diff.max()))
            out.append(
                {
                    "design": spec,
                    "step": step,
                    "margin": margin,
                    "grid": stack.grid,
                    "seconds": seconds,
                    "windows": [max(w) for w in stack.windows],
                    "error": max(errors),
                    "dropped": float((default.kept - stack.kept).max()),
                }
            )
            print(out[-1], file=sys.stderr, flush=True)
    return out


def markdown(results: list[dict], args) -> str:
    lines = [
        "## A training step's radial angle margin (`python benchmarks/bench_radial_margin.py`)",
        "",
        f"Machine: {platform.machine()}, {args.threads} CPU thread(s), torch {torch.__version__}. Training draws "
        f"0..{args.steps - 1} of `presets/quick-split-spectrum.toml`, the step's channel PSFs at one scale in "
        f"capacities of {args.capacity} px (a learned lens's far window in training), with `[optimize] radial_margin` "
        "(sin-angle past the steepest ray; the first margin listed is the reference of *dropped*). Seconds: the "
        "warm stack (kernels cached). Error: the largest relative L2 of a channel PSF over its window against the "
        "mix of `compute_psf` at doubled sampling (margins and densities × 2). Dropped: the most light a channel's "
        "window keeps below the first margin's (fractions of the aperture's power).",
        "",
        "| design | draw | radial_margin | Hankel frequencies | pupil nodes | R mm | windows px (near, far) | warm s "
        "| error | dropped |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        g = r["grid"]
        lines.append(
            f"| {r['design']} | {r['step']} | {r['margin']:g} | {g['hankel_samples_used']} of {g['hankel_samples']} | "
            f"{g['pupil_nodes']} | {g['support_radius_m'] * 1e3:.2f} | {r['windows'][0]}, {r['windows'][1]} | "
            f"{r['seconds']:.2f} | {r['error']:.1e} | {r['dropped']:.1e} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--designs", nargs="+", default=["hyperbolic:532nm", "runs/quick-split-spectrum"])
    parser.add_argument("--preset", type=Path, default=ROOT / "presets" / "quick-split-spectrum.toml")
    parser.add_argument("--margins", nargs="+", type=float, default=[0.2, 0.1, 0.05])
    parser.add_argument("--steps", type=int, default=2)
    parser.add_argument("--capacity", type=int, default=987)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from report import write_section

    from metalens_cli.io.presets import load_preset

    preset = load_preset(args.preset)
    results = [r for spec in args.designs for r in rows(spec, preset, args.margins, args.steps, args.capacity)]
    text = markdown(results, args)
    print(text)
    write_section("radial-margin", text)


if __name__ == "__main__":
    main()
