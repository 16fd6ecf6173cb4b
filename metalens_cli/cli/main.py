"""The `metalens` Click app: a lazy group, so `metalens --help` imports no subcommand's deps.

Error contract: bad input (a Click usage error or a :class:`MetalensError`) prints one line
``metalens: error: …`` on stderr and exits 2, without a traceback.
"""

from __future__ import annotations

import importlib
import sys

import click

from metalens_cli import __version__
from metalens_cli.errors import MetalensError
from metalens_cli.runtime import retain_freed_memory


class LazyGroup(click.Group):
    """A group whose subcommands live in modules imported only when invoked (or listed in help)."""

    def __init__(self, *args, lazy: dict[str, tuple[str, str]] | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.lazy = lazy or {}

    def list_commands(self, ctx):
        return sorted(set(super().list_commands(ctx)) | set(self.lazy))

    def get_command(self, ctx, name):
        if name in self.lazy:
            module, _ = self.lazy[name]
            return getattr(importlib.import_module(f"metalens_cli.cli.{module}"), name.replace("-", "_"))
        return super().get_command(ctx, name)

    def format_commands(self, ctx, formatter):
        """List commands from their one-line help without importing them."""
        rows = [(name, help_text) for name, (_, help_text) in sorted(self.lazy.items())]
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)


COMMANDS = {
    "symmetry": ("symmetry", "Depth-wavelength symmetry: the depth each wavelength focuses from, and back."),
    "bands": ("bands", "Multi-band filter checks (bands check)."),
    "preset": ("preset", "Inspect presets (preset show)."),
    "obstruction": ("obstruction", "Obstruction generators (obstruction preview)."),
    "export-gds": ("export_gds", "Nanofin layout of a design as GDSII or OASIS for e-beam lithography."),
    "psf-scan": ("psf_scan", "PSF cubes over wavelength and depth of a design, written as EXR."),
    "mtf": ("mtf", "MTFs of a PSF cube (EXR) or the slanted-edge SFR of an image."),
    "simulate": ("simulate", "Simulated captures of images through a design with a near obstruction."),
    "evaluate": ("evaluate", "PSNR/SSIM of obstructed and unobstructed captures, design against design."),
    "optimize": ("optimize", "Learn the rotation map end to end from a preset into a run directory."),
    "reconstruct": ("reconstruct", "The reconstruction network of a design: train, apply, export."),
}


@click.group(cls=LazyGroup, lazy=COMMANDS, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="metalens")
def app():
    """Design and analyse learned split-spectrum metalenses.

    Lengths take units: 4mm, 450nm, 1.85um, inf. Results go to stdout (--json for
    machines), messages to stderr. Exit codes: 0 success, 1 a check failed, 2 bad input.
    """


def run(argv: list[str] | None = None) -> int:
    """Run the app on ``argv`` and return the exit code (errors rendered as one line)."""
    try:
        code = app.main(args=argv, prog_name="metalens", standalone_mode=False)
    except click.exceptions.Abort:
        click.echo("metalens: aborted", err=True)
        return 130
    except click.ClickException as exc:
        click.echo(f"metalens: error: {exc.format_message()}", err=True)
        return 2
    except MetalensError as exc:
        click.echo(f"metalens: error: {exc}", err=True)
        return 2
    return code if isinstance(code, int) else 0


def cli() -> None:
    """Console-script entry point: the process is ours, so keep freed FFT work arrays (see
    :mod:`metalens_cli.runtime`), then run."""
    retain_freed_memory()
    sys.exit(run(sys.argv[1:]))
