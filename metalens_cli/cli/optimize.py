"""`metalens optimize`: learn θ end to end from a preset into a run directory."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import click

from metalens_cli.cli import render
from metalens_cli.cli.options import (
    MetalensCommand,
    OutputFolder,
    announce,
    hold_folder,
    max_memory_option,
    torch_device,
    training_options,
)
from metalens_cli.cli.progress import efficiency_used, run_training


@click.command("optimize", cls=MetalensCommand)
@click.argument("preset_path", metavar="PRESET.toml", type=click.Path(dir_okay=False))
@click.option("-o", "--output", type=OutputFolder(), help="Run directory [runs/PRESET-NAME].")
@training_options("optimize")
@max_memory_option
def optimize(preset_path, output, steps, seed, device, resume, threads, quiet, as_json, max_memory):
    """Learn the rotation map of PRESET.toml (the paper's Eq. 4) and write a run directory.

    The run directory holds the resolved preset, theta.npy, psf.exr, loss.csv/png, sample
    captures, checkpoints and run.json, and is a design spec for psf-scan, simulate, evaluate
    and export-gds. Ctrl-C writes a checkpoint; --resume continues exactly. Under
    `torchrun --nproc-per-node N -m metalens_cli optimize ...` the batch is split over ranks.
    """
    import torch

    from metalens_cli.design.rundir import RunDirectory
    from metalens_cli.design.training import estimate_training, train
    from metalens_cli.io.presets import load_preset
    from metalens_cli.io.resources import Estimate

    if threads:
        torch.set_num_threads(threads)
    preset = load_preset(preset_path)
    run_dir = Path(output) if output else Path("runs") / preset.name
    hold_folder(run_dir, "--output")  # -o is held already; the default run directory here
    run = RunDirectory(run_dir)
    if not resume:
        run.check_fresh()
    planned = (
        run.load_preset() if resume and run.preset_path.is_file() else preset
    )  # a resumed run goes on with its own
    planned = dataclasses.replace(
        planned,
        optimize=dataclasses.replace(
            planned.optimize, **{k: v for k, v in (("steps", steps), ("seed", seed)) if v is not None}
        ),
    )
    efficiency_used(planned, quiet)  # RCWA η, when the preset asks for it, before the estimate and the run
    run_device = torch_device(device)  # auto resolved; a CUDA run's estimate is checked against the GPU's memory
    memory, seconds = estimate_training(planned)
    announce(
        Estimate(
            f"optimize of {planned.optimize.steps} steps, batch {planned.optimize.batch_size}",
            memory,
            "optimize.batch_size" if seconds is not None else "lens.aperture (its 2-D θ grid)",
            seconds,
        ),
        max_memory,
        device=run_device,
    )
    report = run_training(
        "optimize",
        quiet,
        f"metalens optimize {preset_path} -o {run_dir} --resume",
        lambda progress: train(
            preset, run_dir, steps=steps, seed=seed, device=run_device, resume=resume, on_step=progress.step
        ),
    )
    if report is None:
        return
    if as_json:
        render.emit_json({"run_dir": str(run_dir), **report})
        return
    _render(run_dir, report)


def _render(run_dir: Path, report: dict) -> None:
    con = render.console()
    cost, psf = report["cost"], report["psf"]
    window = next(k for k in psf if k.startswith("energy_center_"))
    rows = []
    for d, depth in enumerate(psf["depths_m"]):
        label = "far (∞)" if depth is None or depth == float("inf") else f"near ({depth * 1e3:g} mm)"
        for c, channel in enumerate(psf["channels"]):
            rows.append([label, channel, f"{psf['energy_in_window'][d][c]:.4f}", f"{psf[window][d][c]:.4f}"])
    con.print(
        render.table(
            f"Channel PSFs of {run_dir}", ["depth", "channel", "in window", window.replace("energy_", "")], rows
        )
    )
    final = report["final_loss"]
    per_step = cost["seconds_per_step_median"]
    con.print(
        f"{report['settings']['steps']} steps"
        + (f", {per_step:.3f} s/step (median)" if per_step else "")
        + (f", final loss {final['total']:.4f} (mean of the last steps)" if final else "")
    )
    con.print(f"wrote {run_dir}/ (theta.npy, psf.exr, loss.csv, run.json, …)")
