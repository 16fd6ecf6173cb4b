"""Benchmark: the two-scale PSF (``optics.two_scale``) against today's single-scale path: the
error of its captures and what it saves, for evaluation (``simulate``/``evaluate``: the PSFs at
the sensor's pixels, the halo summed into blocks) and for training (radial halos computed at
their own sampling, ``optics.channel_psf``).

Evaluation: every photograph of the evaluation set behind dirt and behind a fence, the design's
PSFs at the preset's depths; the relative L2 of the obstructed captures against the single-scale
ones, the change in the set's mean PSNR (captures against the clean photographs, ``score``), the
grey wall's largest deviation from grey and the opaque cover's largest light, and the median
seconds of one capture (transforms made once). Training: the PSF stack of training step draws
(the quick preset's depths and wavelength samples) computed both ways; the relative L2 of the
captures of the steps' procedural scenes and obstructions and the seconds of the stack.

With ``--window-rule PRESET ...``: only the window rule (``[optimize] halo_window_blocks``): each
preset's θ_init, its training draws under each rule of ``--rules`` (200, the default, and 130),
the scales its PSFs take and the captures' error against one scale.

Run: python benchmarks/bench_two_scale.py [--designs D ...] [--pixels 512] [--steps 4]
[--window-rule PRESET ... [--rules 200 130]]
Rewrites its section of docs/benchmarks.md (with ``--window-rule``, the window rule's).
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
EVALUATION = ((3, 33), (5, 45), (5, 65), (7, 63), (9, 99))  # (s, K)
TRAINING = ((5, 45, 1), (5, 45, 2), (5, 65, 2), (5, 65, 4), (7, 63, 2), (9, 99, 2))  # (s, K, radial step)


def _located(spec: str) -> str:
    """A run directory named from the repository's root, wherever the script runs from."""
    return str(ROOT / spec) if (ROOT / spec).exists() else spec


def evaluation_rows(design_spec: str, preset, pixels: int, limit: int | None) -> tuple[str, list[dict]]:
    """The PSF windows, and one row per (s, K): the captures' error and the seconds of one capture."""
    from metalens_cli.imaging.formation import form_image
    from metalens_cli.imaging.images import load_images
    from metalens_cli.imaging.pipeline import capture_psfs, score, simulate_captures
    from metalens_cli.io.designs import resolve_design
    from metalens_cli.optics.spectra import wavelength_grid
    from metalens_cli.optics.two_scale import TwoScale

    design = resolve_design(_located(design_spec), preset)
    z_near, z_far = (float(np.mean(preset.scene.z_near_m)), 1.0)
    pitch, f = preset.sensor.pixel_pitch_m, design.focal_length_m
    waves = wavelength_grid()
    reference = capture_psfs(design, z_near, z_far, waves, pitch, pixels)
    windows = f"{reference.near.shape[-1]} / {reference.far.shape[-1]}"
    configs = [
        capture_psfs(design, z_near, z_far, waves, pitch, pixels, two_scale=TwoScale(s, k, 1, 1))
        for s, k in ((1, 1), *EVALUATION)
    ]
    for psfs in configs:
        psfs.near, psfs.far = reference.near, reference.far  # the same PSFs (and obstructions: one canvas)
    images = load_images("photos", (pixels, pixels), limit, max(p.margin for p in configs))
    rows = []
    base = None
    for psfs in configs:
        s, k = psfs.two_scale.scale, psfs.two_scale.core_pixels
        captures = {
            kind: simulate_captures(images, kind, psfs, f, pitch, 0, params=preset.obstruction)
            for kind in ("dirt", "fence")
        }
        psnr = statistics.mean(
            score(c.obstructed, image.sensor)["psnr_db"]
            for kind in captures
            for c, image in zip(captures[kind], images)
        )
        margin = psfs.margin
        canvas = pixels + 2 * margin
        grey = torch.full((3, canvas, canvas), 0.37)
        ones = torch.ones(1, canvas, canvas)
        forms = psfs.capture_forms()
        wall = form_image(grey, torch.zeros_like(grey), torch.zeros_like(ones), *forms, margin).obstructed
        cover = form_image(grey, torch.zeros_like(grey), ones, *forms, margin).obstructed
        seconds = statistics.median(psfs.formation_seconds[2:] or psfs.formation_seconds)
        obstructed = np.stack([c.obstructed for kind in captures for c in captures[kind]])
        if base is None:
            base = obstructed, psnr
        rows.append(
            {
                "s": s,
                "K": k,
                "margin": margin,
                "rel_l2": float(np.linalg.norm(obstructed - base[0]) / np.linalg.norm(base[0])),
                "psnr_db": psnr,
                "d_psnr_db": psnr - base[1],
                "grey": float((wall - 0.37).abs().max()),
                "cover": float(cover.abs().max()),
                "ms": 1e3 * seconds,
            }
        )
    return windows, rows


def training_rows(design_spec: str, preset, steps: int, samplings: dict | None = None) -> list[dict]:
    """One row per sampling (label → ``TwoScale``; default: each (s, K, radial step) of ``TRAINING``
    with its blocks forced): the training captures' error against one scale, the stack's seconds
    and the halo scales the draws' near and far PSFs took."""
    from metalens_cli.design.step import draw_step, plan_windows, spectral_source, step_batch
    from metalens_cli.imaging.canvas import sensor_crop
    from metalens_cli.imaging.formation import form_image, psf_margin
    from metalens_cli.io.designs import resolve_design
    from metalens_cli.optics.channel_psf import channel_psf_stack
    from metalens_cli.optics.two_scale import TwoScale

    lens = resolve_design(_located(design_spec), preset).lens
    sens = spectral_source(preset)
    win = plan_windows(preset, sens)
    pitch, d = preset.sensor.pixel_pitch_m, preset.lens.focal_length_m

    def stack(draw, scales, caps):
        return channel_psf_stack(
            lens, draw.wavelengths_m, [draw.z_near_m, draw.z_far_m], draw.weights, caps, pitch, d,
            plan_pixels=win.plan, two_scale=scales,
        )  # fmt: skip

    samplings = {"one scale": TwoScale(), **(samplings or {c: TwoScale(*c, 1) for c in TRAINING})}
    errors = {c: [] for c in samplings}
    seconds = {c: [] for c in samplings}
    taken = {c: set() for c in samplings}
    windows = set()
    for step in range(steps):
        draw = draw_step(preset, sens, 0, step)
        caps = (win.near, win.far)
        stacks = {}
        for label, scales in samplings.items():
            stack(draw, scales, caps)  # warm: kernels and operators built
            t0 = time.perf_counter()
            stacks[label] = stack(draw, scales, caps)
            seconds[label].append(time.perf_counter() - t0)
            taken[label].add(tuple(getattr(p, "scale", 1) for p in stacks[label].psfs))
        windows.add(tuple(max(w) for w in stacks["one scale"].windows))
        big = max(psf_margin(*st.psfs) for st in stacks.values())
        batch = step_batch(preset, 0, step, [0, 1], draw.z_near_m, None, big, "cpu")
        captures = {}
        for label, result in stacks.items():
            margin = psf_margin(*result.psfs)
            clean, colour, mask = (sensor_crop(x, big - margin) for x in batch)
            captures[label] = form_image(clean, colour, mask, *result.psfs, margin).obstructed.detach()
        ref = captures["one scale"]
        for label in samplings:
            errors[label].append(float((captures[label] - ref).norm() / ref.norm()))
    return [
        {
            "label": label,
            "s": scales.scale,
            "K": scales.core_pixels,
            "radial_step": scales.radial_step,
            "rel_l2": max(errors[label]),
            "stack_s": statistics.median(seconds[label]),
            "scales_taken": sorted(taken[label]),
            "windows": sorted(windows),
        }
        for label, scales in samplings.items()
    ]


def rule_rows(preset_paths: list[str], steps: int, rules: list[int]) -> list[tuple[str, list[dict]]]:
    """For each preset, θ_init's training draws under the window rule N/b of each b in ``rules``
    (``[optimize] halo_window_blocks``; the preset's halo scale, core and radial step)."""
    from metalens_cli.design.step import psf_scales
    from metalens_cli.io.presets import load_preset

    out = []
    for path in preset_paths:
        preset = load_preset(path)
        base = psf_scales(preset)
        spec = f"hyperbolic:{preset.lens.design_wavelength_m * 1e9:.0f}nm"
        samplings = {f"N/{b}": dataclasses.replace(base, window_blocks=b) for b in rules}
        out.append((Path(path).name, training_rows(spec, preset, steps, samplings)))
    return out


def rule_markdown(results: list, args) -> str:
    """The window rule's section of docs/benchmarks.md."""
    import platform

    lines = [
        "## The window rule: which PSF windows take halo blocks (`python benchmarks/bench_two_scale.py "
        "--window-rule PRESET ...`)",
        "",
        f"Machine: {platform.machine()}, {args.threads} CPU thread(s), torch {torch.__version__}. A training "
        "step's PSF window of N px takes halo blocks of at most N/b px, odd, at most `halo_scale` "
        "(`[optimize] halo_window_blocks` b, 200 by default; `optics.two_scale.TwoScale.at`). Each preset's "
        f"θ_init, {args.steps} training draws: the windows (near / far, px, the largest channel's), the "
        "scales the near and far PSFs took, the largest relative L2 of the draws' captures of their "
        "procedural scenes and obstructions against one scale, and the median seconds of the PSF stack.",
        "",
        "| preset | windows near / far px | rule | scales taken | PSF stack s | × faster | rel. L2 of captures |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, rows in results:
        base = rows[0]["stack_s"]
        windows = ", ".join(f"{n} / {f}" for n, f in rows[0]["windows"])
        for r in rows:
            scales = ", ".join(" / ".join(map(str, t)) for t in r["scales_taken"])
            lines.append(
                f"| {name} | {windows} | {r['label']} | {scales} | {r['stack_s']:.3f} | "
                f"{base / r['stack_s']:.2f} | {r['rel_l2']:.1e} |"
            )
    return "\n".join(lines)


def markdown(results: dict, args) -> str:
    """The section of docs/benchmarks.md: one evaluation table and one training table."""
    import platform

    lines = [
        "## Two-scale PSFs against the single-scale path (`python benchmarks/bench_two_scale.py`)",
        "",
        f"Machine: {platform.machine()}, {args.threads} CPU thread(s), torch {torch.__version__}. "
        "s: the halo's block side (pixels), K: the core's side; s = 1 is today's single-scale path, the "
        "reference of every error. Blocks are forced to s here (`TwoScale(..., window_blocks=1)`); a run "
        "takes at most N/200 for a window of N px (`optics.two_scale.TwoScale.at`).",
        "",
        f"**Evaluation** (`simulate`/`evaluate --halo-scale`): the evaluation photographs"
        f"{'' if args.limit is None else f' (first {args.limit})'} on a {args.pixels}² sensor behind dirt "
        "and behind a fence, the preset's mean near depth and 1 m, the PSFs at the sensor's pixels "
        "split into core and halo; relative L2 of the obstructed captures, the change of the set's mean "
        "PSNR, the grey wall's largest deviation from 0.37 and the opaque cover's largest value, and the "
        "median seconds of one obstructed + unobstructed capture (transforms made once).",
        "",
        "| design | windows near / far px | s | K | margin px | capture ms | × faster | rel. L2 | ΔPSNR dB "
        "| grey wall | opaque cover |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for spec, (windows, rows) in results["evaluation"].items():
        base = rows[0]["ms"]
        for r in rows:
            lines.append(
                f"| {spec} | {windows} | {r['s']} | {r['K'] if r['s'] > 1 else '—'} | {r['margin']} | "
                f"{r['ms']:.1f} | {base / r['ms']:.1f} | {r['rel_l2']:.1e} | {r['d_psnr_db']:+.4f} | "
                f"{r['grey']:.0e} | {r['cover']:.0e} |"
            )
    lines += [
        "",
        f"**Training** (`[optimize] halo_scale`, `core_pixels`, `halo_radial_step`): the PSF stack of "
        f"{args.steps} training draws of the quick preset (its depths and wavelength samples, the planned "
        "capacities) computed both ways, the radial halo from samples `halo_radial_step` times coarser; "
        "the largest relative L2 of the draws' captures of their procedural scenes and obstructions, and "
        "the median seconds of the stack (kernels built).",
        "",
        "| design | s | K | radial step | PSF stack s | × faster | rel. L2 of captures |",
        "|---|---|---|---|---|---|---|",
    ]
    for spec, rows in results["training"].items():
        base = rows[0]["stack_s"]
        for r in rows:
            lines.append(
                f"| {spec} | {r['s']} | {r['K'] if r['s'] > 1 else '—'} | {r['radial_step']} | "
                f"{r['stack_s']:.3f} | {base / r['stack_s']:.2f} | {r['rel_l2']:.1e} |"
            )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--designs", nargs="+", default=None)
    parser.add_argument("--preset", default=str(ROOT / "presets" / "quick-split-spectrum.toml"))
    parser.add_argument("--pixels", type=int, default=512)
    parser.add_argument("--limit", type=int, default=None, help="photographs (default: the whole set)")
    parser.add_argument("--steps", type=int, default=4)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument(
        "--window-rule", nargs="+", metavar="PRESET", help="only the window rule's table, for these presets"
    )
    parser.add_argument("--rules", nargs="+", type=int, default=[200, 130], help="halo_window_blocks values")
    args = parser.parse_args()

    from metalens_cli.io.presets import load_preset

    torch.set_num_threads(args.threads)
    sys.path.insert(0, str(Path(__file__).parent))
    from report import write_section

    if args.window_rule:
        results = rule_rows(args.window_rule, args.steps, args.rules)
        print(results, flush=True)
        write_section("window-rule", rule_markdown(results, args))
        return
    preset = load_preset(args.preset)
    learned = ROOT / "runs" / "quick-split-spectrum"
    designs = args.designs or ["hyperbolic:532nm"] + (["runs/quick-split-spectrum"] if learned.exists() else [])
    results = {"evaluation": {}, "training": {}}
    for spec in designs:
        results["evaluation"][spec] = evaluation_rows(spec, preset, args.pixels, args.limit)
        print(spec, results["evaluation"][spec], flush=True)
        if not spec.startswith("hyperbolic"):
            results["training"][spec] = training_rows(spec, preset, args.steps)
            print(spec, results["training"][spec], flush=True)
    write_section("two-scale", markdown(results, args))


if __name__ == "__main__":
    main()
