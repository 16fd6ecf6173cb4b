"""Benchmark: training scenes and dirt drawn at the halo's blocks beyond the cores' reach
(``[optimize] scene_blocks``, ``imaging.sample_grid``) against every pixel: what a step's batch
costs, and how far its captures move.

For training draws of the quick preset (its depths, wavelength samples and obstructions, batch 2),
a design's PSF stack at the training defaults (two scales), and the canvas margin those PSFs need
(or ``--margin``): the median seconds of the step's batch of scenes and dirt (``design.step.
step_batch``) drawn three ways, and the relative L2 of their obstructed captures:

- *pixels*: today's generator (every pixel; noise resized from its lattice grid);
- *s = 1*: every pixel through the sampled path (noise evaluated at each pixel and normalised on
  a uniform sample): a different draw of the same statistics, the reference of the blocks;
- *blocks*: the pixels within the cores' reach, s × s cells beyond (the same scene as s = 1 near
  the field, bit for bit; tests/design/test_scene_blocks.py).

Run: python benchmarks/bench_scene_blocks.py [--designs D ...] [--steps 4] [--threads 2] [--margin M]
Rewrites its section of docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import platform
import statistics
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]


def rows(spec: str, preset, steps: int, margin: int | None) -> list[dict]:
    """One row per training draw: margin, batch seconds three ways, the captures' errors."""
    import metalens_cli.design.step as step_module
    from metalens_cli.design.scenes import FINE_BAND_PX
    from metalens_cli.design.step import draw_step, plan_windows, psf_scales, spectral_source, step_batch
    from metalens_cli.imaging.formation import form_image, psf_margin
    from metalens_cli.imaging.sample_grid import SampleGrid
    from metalens_cli.io.designs import resolve_design
    from metalens_cli.optics.channel_psf import channel_psf_stack

    design = resolve_design(str(ROOT / spec) if (ROOT / spec).exists() else spec, preset)
    sens = spectral_source(preset)
    win = plan_windows(preset, sens)
    o = preset.optimize
    fine = max(o.core_pixels // 2, FINE_BAND_PX)
    grids = {
        "pixels": lambda p, canvas, m: None,
        "s = 1": lambda p, canvas, m: SampleGrid.blocks(canvas, m, 1, fine),
        "blocks": lambda p, canvas, m: SampleGrid.blocks(canvas, m, o.halo_scale, fine),
    }
    out = []
    for step in range(steps):
        draw = draw_step(preset, sens, 0, step)
        stack = channel_psf_stack(
            design.lens, draw.wavelengths_m, [draw.z_near_m, draw.z_far_m], draw.weights, (win.near, win.far),
            preset.sensor.pixel_pitch_m, preset.lens.focal_length_m, plan_pixels=win.plan,
            two_scale=psf_scales(preset),
        )  # fmt: skip
        m = max(margin or 0, psf_margin(*stack.psfs))
        seconds, captures = {}, {}
        for name, grid in grids.items():
            step_module.scene_grid = grid  # what step_batch draws on
            times = []
            for _ in range(3):
                t0 = time.perf_counter()
                batch = step_batch(preset, 0, step, [0, 1], draw.z_near_m, None, m, "cpu")
                times.append(time.perf_counter() - t0)
            seconds[name] = statistics.median(times)
            captures[name] = form_image(*batch, *stack.psfs, m).obstructed.detach()

        def error(a, b, captures=captures):
            return float((captures[a] - captures[b]).norm() / captures[b].norm())

        out.append(
            {
                "step": step,
                "margin": m,
                "samples": SampleGrid.blocks((128 + 2 * m,) * 2, m, o.halo_scale, fine).samples[0],
                "seconds": seconds,
                "blocks_vs_s1": error("blocks", "s = 1"),
                "s1_vs_pixels": error("s = 1", "pixels"),
            }
        )
    return out


def markdown(results: dict, args) -> str:
    lines = [
        "## Scenes at the halo's blocks (`python benchmarks/bench_scene_blocks.py`)",
        "",
        f"Machine: {platform.machine()}, {args.threads} CPU thread(s), torch {torch.__version__}. Training draws "
        "0.. of `presets/quick-split-spectrum.toml` (128² field, batch 2, dirt), the design's PSFs at the training "
        "defaults (s = 5, K = 65), on the canvas margin they need"
        + (f" (at least {args.margin} px: a learned lens's windows)" if args.margin else "")
        + ". Seconds: the median of 3 draws of the step's batch (scenes and dirt, `design.step.step_batch`, "
        "on the thread pool a step uses). Errors: relative L2 of the obstructed captures. *s = 1*: every pixel "
        "through the sampled path (noise evaluated at each pixel, normalised on a uniform sample): the same "
        "scene as the blocks within the cores' reach, a different draw of the same statistics than *pixels* "
        "(today's generator, noise resized from its lattice grid).",
        "",
        "| design | draw | margin px | samples per side (canvas) | pixels s | s = 1 s | blocks s | × faster "
        "| blocks vs s = 1 | s = 1 vs pixels |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for spec, found in results.items():
        for r in found:
            s = r["seconds"]
            lines.append(
                f"| {spec} | {r['step']} | {r['margin']} | {r['samples']} ({128 + 2 * r['margin']}) | "
                f"{s['pixels']:.3f} | {s['s = 1']:.3f} | {s['blocks']:.3f} | {s['pixels'] / s['blocks']:.1f} | "
                f"{r['blocks_vs_s1']:.1e} | {r['s1_vs_pixels']:.1e} |"
            )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--designs", nargs="+", default=None)
    parser.add_argument("--preset", default=str(ROOT / "presets" / "quick-split-spectrum.toml"))
    parser.add_argument("--steps", type=int, default=4)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--margin", type=int, default=None, help="at least this canvas margin (px)")
    args = parser.parse_args()

    from metalens_cli.io.presets import load_preset

    torch.set_num_threads(args.threads)
    preset = load_preset(args.preset)
    preset = dataclasses.replace(preset, optimize=dataclasses.replace(preset.optimize, scene_blocks=True))
    learned = ROOT / "runs" / "quick-split-spectrum"
    designs = args.designs or ["hyperbolic:532nm"] + (["runs/quick-split-spectrum"] if learned.exists() else [])
    results = {}
    for spec in designs:
        results[spec] = rows(spec, preset, args.steps, args.margin)
        print(spec, results[spec], flush=True)
    sys.path.insert(0, str(Path(__file__).parent))
    from report import write_section

    write_section("scene-blocks", markdown(results, args))


if __name__ == "__main__":
    main()
