"""Progress bars on stderr for long work; silent when stderr is not a terminal or with --quiet."""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from metalens_cli.cli import render


@contextmanager
def progress_bar(description: str, quiet: bool = False) -> Iterator[Callable[[int, int], None]]:
    """Yield ``update(done, total)``; draws a rich bar with ETA on an interactive stderr."""
    if quiet or not sys.stderr.isatty():
        yield lambda done, total: None
        return
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    columns = (
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    )
    with Progress(*columns, transient=True, console=_stderr_console()) as bar:
        task = bar.add_task(description, total=None)

        def update(done: int, total: int) -> None:
            bar.update(task, completed=done, total=total)

        yield update


def efficiency_used(preset, quiet: bool = False, bands_m: list[tuple[float, float]] | None = None) -> dict:
    """The JSON saying which nanofin η(λ) a preset's results use (``efficiency_report``); computes
    and caches it first, under a progress bar, when the preset asks for RCWA and the cache lacks
    it. Without a preset, S^c has no η factor: ``{"source": "none"}`` (ideal conversion)."""
    if preset is None:
        return {"source": "none"}
    from metalens_cli.io.preset_spectra import efficiency_report, preset_efficiency

    with progress_bar("nanofin η(λ) by RCWA (cached after)", quiet) as update:
        efficiency = preset_efficiency(preset.nanofin, preset.sensor.wavelength_range_m, update)
    return efficiency_report(preset, bands_m, efficiency)


class TrainingProgress:
    """Progress of a training loop: a rich bar with the running loss and ETA on an interactive
    stderr, otherwise a line every 10 % of the steps; ``stage(text)`` names the setup stages."""

    def __init__(self, name: str, quiet: bool):
        self.name, self.quiet, self.bar, self.recent = name, quiet, None, []

    def __enter__(self) -> TrainingProgress:
        if not self.quiet and sys.stderr.isatty():
            from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

            self.bar = Progress(
                TextColumn("{task.description}"),
                BarColumn(),
                TextColumn("{task.completed}/{task.total}"),
                TextColumn("loss {task.fields[loss]}"),
                TimeElapsedColumn(),
                TimeRemainingColumn(),
                console=_stderr_console(),
                transient=True,
            )
            self.bar.__enter__()
            self.task = self.bar.add_task(self.name, total=None, loss="—")
        return self

    def stage(self, text: str) -> None:
        """Name the setup stage ``text``: in the bar's description, else as a ``NAME: text`` line on
        stderr (nothing when quiet)."""
        if self.bar is not None:
            self.bar.update(self.task, description=f"{self.name}: {text}")
        elif not self.quiet:
            print(f"{self.name}: {text}", file=sys.stderr, flush=True)

    def step(self, done: int, total: int, row: dict) -> None:
        """Show step ``done`` of ``total``, ``row`` being its loss.csv row (``total`` loss,
        ``seconds``): the bar shows the mean total loss of the last 20 steps; without a bar a line
        on stderr every tenth of the steps and at the end (nothing when quiet)."""
        self.recent = (self.recent + [row["total"]])[-20:]
        mean = sum(self.recent) / len(self.recent)
        if self.bar is not None:
            self.bar.update(self.task, completed=done, total=total, loss=f"{mean:.4f}", description=self.name)
        elif not self.quiet and (done == total or done % max(total // 10, 1) == 0):
            print(
                f"{self.name}: step {done}/{total} loss {mean:.4f} ({row['seconds']:.2f} s/step)",
                file=sys.stderr,
                flush=True,
            )

    def __exit__(self, *exc) -> bool:
        if self.bar is not None:
            self.bar.__exit__(*exc)
        return False


def run_training(
    name: str, quiet: bool, resume_command: str, start: Callable[[TrainingProgress], object]
) -> dict | None:
    """Run ``start(progress)`` (a training call returning an object with ``report``) under a
    :class:`TrainingProgress` shown by rank 0 only; print its notes. Ctrl-C: the checkpoint and
    ``resume_command`` on stderr, exit 130 (143 after SIGTERM). Returns the report on rank 0, None on other ranks."""
    import os

    import click

    from metalens_cli.design.train_loop import TrainingInterrupted
    from metalens_cli.errors import Terminated

    rank0 = int(os.environ.get("RANK", "0")) == 0
    with TrainingProgress(name, quiet or not rank0) as progress:
        try:
            summary = start(progress)
        except TrainingInterrupted as stop:
            terminated = isinstance(stop.__context__, Terminated)
            if rank0:
                click.echo(
                    f"metalens: {'terminated' if terminated else 'interrupted'} after step {stop.step}; "
                    f"checkpoint {stop.checkpoint}; continue with: {resume_command}",
                    err=True,
                )
            sys.exit(143 if terminated else 130)
    if not rank0:
        return None
    render.say(summary.report.get("notes", []), "note")
    return summary.report


def _stderr_console():
    from rich.console import Console

    return Console(stderr=True)
