"""`metalens optimize`: learn θ end to end from a preset into a run directory."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from metalens_cli.cli import render
from metalens_cli.cli.options import json_option, torch_device


@click.command("optimize")
@click.argument("preset_path", metavar="PRESET.toml", type=click.Path(dir_okay=False))
@click.option("-o", "--output", type=click.Path(file_okay=False), help="Run directory [runs/PRESET-NAME].")
@click.option("--steps", type=click.IntRange(0), help="Training steps [the preset's optimize.steps].")
@click.option("--seed", type=click.IntRange(0), help="Seed of every random draw [the preset's optimize.seed].")
@click.option("--device", default="cpu", show_default=True, help="torch device: cpu, cuda, cuda:1, mps (under torchrun: each rank's).")
@click.option("--resume", is_flag=True, help="Continue the run in --output from its newest checkpoint (with the preset saved there).")
@click.option("--threads", type=click.IntRange(1), help="CPU threads for torch [torch's default].")
@click.option("--quiet", is_flag=True, help="No progress bar or progress lines.")
@json_option
def optimize(preset_path, output, steps, seed, device, resume, threads, quiet, as_json):
    """Learn the rotation map of PRESET.toml (the paper's Eq. 4) and write a run directory.

    The run directory holds the resolved preset, theta.npy, psf.exr, loss.csv/png, sample
    captures, checkpoints and run.json, and is a design spec for psf-scan, simulate, evaluate
    and export-gds. Ctrl-C writes a checkpoint; --resume continues exactly. Under
    `torchrun --nproc-per-node N -m metalens_cli optimize ...` the batch is split over ranks.
    """
    import torch

    from metalens_cli.design.training import TrainingInterrupted, train
    from metalens_cli.io.presets import load_preset

    if threads:
        torch.set_num_threads(threads)
    preset = load_preset(preset_path)
    run_dir = Path(output) if output else Path("runs") / preset.name
    rank0 = int(__import__("os").environ.get("RANK", "0")) == 0
    with _progress(quiet or not rank0) as on_step:
        try:
            summary = train(preset, run_dir, steps=steps, seed=seed, device=torch_device(device), resume=resume, on_step=on_step)
        except TrainingInterrupted as stop:
            if rank0:
                click.echo(f"metalens: interrupted after step {stop.step}; checkpoint {stop.checkpoint}; "
                           f"continue with: metalens optimize {preset_path} -o {run_dir} --resume", err=True)
            sys.exit(130)
    if not rank0:
        return
    report = summary.report
    err = render.console(stderr=True)
    for note in report.get("notes", []):
        err.print(f"note: {note}")
    if as_json:
        render.emit_json({"run_dir": str(run_dir), **report})
        return
    _render(run_dir, report)


class _progress:
    """A rich bar with loss and ETA on an interactive stderr; otherwise a line every 10 %."""

    def __init__(self, quiet: bool):
        self.quiet = quiet
        self.bar = None
        self.recent: list[float] = []

    def __enter__(self):
        if not self.quiet and sys.stderr.isatty():
            from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

            self.bar = Progress(TextColumn("optimize"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                                TextColumn("loss {task.fields[loss]}"), TimeElapsedColumn(), TimeRemainingColumn(),
                                console=render.console(stderr=True), transient=True)
            self.bar.__enter__()
            self.task = self.bar.add_task("optimize", total=None, loss="—")
        return self.update

    def update(self, done: int, total: int, row: dict) -> None:
        self.recent = (self.recent + [row["total"]])[-20:]
        mean = sum(self.recent) / len(self.recent)
        if self.bar is not None:
            self.bar.update(self.task, completed=done, total=total, loss=f"{mean:.4f}")
        elif not self.quiet and (done == total or done % max(total // 10, 1) == 0):
            click.echo(f"optimize: step {done}/{total} loss {mean:.4f} ({row['seconds']:.2f} s/step)", err=True)

    def __exit__(self, *exc):
        if self.bar is not None:
            self.bar.__exit__(*exc)
        return False


def _render(run_dir: Path, report: dict) -> None:
    con = render.console()
    cost, psf = report["cost"], report["psf"]
    window = next(k for k in psf if k.startswith("energy_center_"))
    rows = []
    for d, depth in enumerate(psf["depths_m"]):
        label = "far (∞)" if depth is None or depth == float("inf") else f"near ({depth * 1e3:g} mm)"
        for c, channel in enumerate(psf["channels"]):
            rows.append([label, channel, f"{psf['energy_in_window'][d][c]:.4f}", f"{psf[window][d][c]:.4f}"])
    con.print(render.table(f"Channel PSFs of {run_dir}", ["depth", "channel", "in window", window.replace("energy_", "")], rows))
    final = report["final_loss"]
    per_step = cost["seconds_per_step_median"]
    con.print(f"{report['settings']['steps']} steps"
              + (f", {per_step:.3f} s/step (median)" if per_step else "")
              + (f", final loss {final['total']:.4f} (mean of the last steps)" if final else ""))
    con.print(f"wrote {run_dir}/ (theta.npy, psf.exr, loss.csv, run.json, …)")
