"""The `metalens` Click app: a lazy group, so `metalens --help` imports no subcommand's deps.

Error contract (docs/failures.md): every failure prints one line ``metalens: error: …`` on
stderr, never a traceback. Exit codes: 2 bad input (a Click usage error, a
:class:`MetalensError`, an output path that cannot be written), 1 the environment failed (disk
full, file-size limit, out of memory, standard output closed) or an internal error, 130 Ctrl-C,
143 SIGTERM; outputs being written are removed (see :mod:`metalens_cli.io.atomic`).
"""

from __future__ import annotations

import errno
import importlib
import os
import signal
import sys
import warnings
from contextlib import suppress

import click

from metalens_cli.constants import __version__
from metalens_cli.errors import MetalensError, ResultFailed, Terminated
from metalens_cli.runtime import retain_freed_memory

OUT_OF_MEMORY = "out of memory; ask for less (fewer pixels, wavelengths or a smaller batch) or set --max-memory"
BAD_PATH_ERRNOS = {
    errno.ENOENT,
    errno.EACCES,
    errno.EPERM,
    errno.EROFS,
    errno.ENOTDIR,
    errno.EISDIR,
    errno.ENAMETOOLONG,
    errno.ELOOP,
    errno.EEXIST,
}


class LazyGroup(click.Group):
    """A group whose subcommands live in modules imported only when invoked (or listed in help)."""

    def __init__(
        self,
        *args,
        lazy: dict[str, tuple[str, str]] | None = None,
        environment: dict[str, str] | None = None,
        **kwargs,
    ):
        super().__init__(*args, **kwargs)
        self.lazy = lazy or {}
        self.environment = environment or {}

    def list_commands(self, ctx):
        """The names of the registered and the lazy subcommands, sorted."""
        return sorted(set(super().list_commands(ctx)) | set(self.lazy))

    def get_command(self, ctx, name):
        """The command ``name``: a lazy one imported now from ``metalens_cli.cli.<module>`` (the
        attribute named ``name`` with '-' as '_'), else Click's own lookup (None when unknown)."""
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

    def format_epilog(self, ctx, formatter):
        """The environment variables the app reads (``environment``: name → what it sets), then the epilog."""
        if self.environment:
            with formatter.section("Environment"):
                formatter.write_dl(list(self.environment.items()))
        super().format_epilog(ctx, formatter)


COMMANDS = {
    "symmetry": ("symmetry", "Depth-wavelength symmetry: the depth each wavelength focuses from, and back."),
    "bands": ("bands", "Multi-band filter checks (bands check)."),
    "preset": ("preset", "Inspect presets (preset show)."),
    "nanofin": ("nanofin", "The meta-atom: conversion efficiency η(λ) by RCWA (nanofin efficiency)."),
    "obstruction": ("obstruction", "Obstruction generators (obstruction preview)."),
    "align": ("align", "Register captured photographs onto a reference (homography, then a smooth refinement)."),
    "tolerance": ("tolerance", "Fabrication tolerance of a design: sensitivity, Monte Carlo, budgets, photographs."),
    "export-gds": ("export_gds", "Nanofin layout of a design as GDSII or OASIS for e-beam lithography."),
    "export-phase": (
        "export_phase",
        "A design's phase as a lens-design surface: Zemax Binary 2 (.zmx), JSON or CSV.",
    ),
    "psf": (
        "psf",
        "Measured PSFs: psf import (bench frames to a PSF cube), psf compare (measured against simulated), "
        "psf retrieve (the lens's phase from them).",
    ),
    "psf-scan": ("psf_scan", "PSF cubes over wavelength and depth of a design, written as EXR, .npz, .mat or TIFF."),
    "mtf": ("mtf", "MTFs of a PSF cube (EXR, .npz, .mat, TIFF) or the slanted-edge SFR of an image."),
    "simulate": ("simulate", "Simulated captures of images through a design with a near obstruction."),
    "evaluate": ("evaluate", "PSNR/SSIM of obstructed and unobstructed captures, design against design."),
    "board": (
        "board",
        "A printable board of ArUco markers and QR codes and its layout file, for evaluate --pairs --task.",
    ),
    "optimize": ("optimize", "Learn the rotation map end to end from a preset into a run directory."),
    "reconstruct": ("reconstruct", "The reconstruction network of a design: train, apply, export."),
}


# Environment variables that no option stands for (an option that reads one, such as
# --lpips-weights and METALENS_LPIPS_WEIGHTS, shows it in its command's --help).
ENVIRONMENT = {
    "METALENS_CACHE": "folder of the on-disk cache of computed η(λ) [the platform's user cache folder, "
    "e.g. ~/.cache/metalens]",
    "METALENS_DEEPLAB_WEIGHTS": "DeepLabv3+ checkpoint for optimize's domain-adaptation loss "
    "(the preset's loss.domain_adaptation_weights wins)",
    "METALENS_TRACEBACK": "1: an internal error shows its traceback",
}
EPILOG = (
    "Options that read an environment variable name it in their command's --help. Shell completion: "
    'eval "$(_METALENS_COMPLETE=bash_source metalens)" (or zsh_source, fish_source); see README.md.'
)


@click.group(
    cls=LazyGroup,
    lazy=COMMANDS,
    environment=ENVIRONMENT,
    invoke_without_command=True,
    epilog=EPILOG,
    context_settings={"help_option_names": ["-h", "--help"]},
)
@click.version_option(__version__, prog_name="metalens")
@click.pass_context
def app(ctx):
    """Design and analyse learned split-spectrum metalenses.

    Lengths take units: 4mm, 450nm, 1.85um, inf. Results go to stdout (--json for
    machines), messages to stderr. Exit codes: 0 success, 1 a check failed or the environment
    failed (disk full, out of memory), 2 bad input; see docs/failures.md.
    """
    if ctx.invoked_subcommand is None:
        click.echo(ctx.get_help())


def run(argv: list[str] | None = None) -> int:
    """Run the app on ``argv`` and return the exit code (every error rendered as one line)."""
    try:
        code = app.main(args=argv, prog_name="metalens", standalone_mode=False)
    except click.exceptions.Abort:
        return _fail("aborted", 130, prefix="metalens: ")
    except Terminated:
        return _fail("terminated", 143, prefix="metalens: ")
    except click.exceptions.NoArgsIsHelpError as exc:  # a command group alone (metalens bands): its help
        click.echo(exc.ctx.get_help())
        return 0
    except click.ClickException as exc:
        return _fail(exc.format_message(), 2)
    except ResultFailed as exc:
        return _fail(str(exc), 1)
    except MetalensError as exc:
        return _fail(str(exc), 2)
    except OSError as exc:
        return _fail(os_error_line(exc), 2 if exc.errno in BAD_PATH_ERRNOS else 1)
    except MemoryError:
        return _fail(OUT_OF_MEMORY, 1)
    except Exception as exc:  # a bug: still one line; the traceback on request
        if os.environ.get("METALENS_TRACEBACK"):
            raise
        if "allocate" in str(exc) and "memory" in str(exc):  # torch's allocator refusing
            return _fail(OUT_OF_MEMORY, 1)
        first_line = (str(exc).strip().splitlines() or [""])[0]
        return _fail(
            f"internal error: {type(exc).__name__}: {first_line} (METALENS_TRACEBACK=1 shows where; please report it)",
            1,
        )
    return code if isinstance(code, int) else 0


def os_error_line(exc: OSError) -> str:
    """``PATH: reason`` for an OSError, with a hint for full disks and size limits."""
    where = exc.filename if exc.filename is not None else "standard output"
    reason = exc.strerror or str(exc)
    hint = {
        errno.ENOSPC: " (free space on that disk or write elsewhere)",
        errno.EFBIG: " (the file-size limit, ulimit -f, is reached)",
    }.get(exc.errno, "")
    return f"{where}: {reason}{hint}"


def _fail(message: str, code: int, prefix: str = "metalens: error: ") -> int:
    with suppress(OSError):  # stderr itself gone: the exit code still tells
        click.echo(prefix + message, err=True)
    return code


def _raise_terminated(signum, frame):
    raise Terminated()


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Python and numpy warnings as one line each, like every other message."""
    with suppress(OSError):  # stderr itself gone: the exit code still tells
        click.echo(
            f"metalens: warning: {category.__name__}: "
            f"{str(message).strip().splitlines()[0] if str(message).strip() else ''}",
            err=True,
        )


def cli() -> None:
    """Console-script entry point: the process is ours, so keep freed FFT work arrays (see
    :mod:`metalens_cli.runtime`), turn SIGTERM into :class:`Terminated` (outputs being written
    are cleaned up as on Ctrl-C), print warnings as single lines, run, and report a standard
    output that cannot take the results (a full device, a closed pipe) as one line, exit 1."""
    retain_freed_memory()
    for name in ("stdout", "stderr"):  # closed by the caller (>&-): what would go there is dropped
        if getattr(sys, name) is None:
            setattr(sys, name, open(os.devnull, "w", encoding="utf-8"))
    signal.signal(signal.SIGTERM, _raise_terminated)
    warnings.showwarning = _show_warning
    code = run(sys.argv[1:])
    try:
        sys.stdout.flush()
    except OSError as exc:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # nothing left to flush at exit
        code = _fail(os_error_line(exc), 1)
    sys.exit(code)
