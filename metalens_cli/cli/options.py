"""Click parameter types for lengths with units, and the shared --preset/--json options.

Each type converts to SI metres through :mod:`metalens_cli.io.units`; a bad value becomes a
Click usage error naming the option and the accepted form (rendered as one line, exit 2).
"""

from __future__ import annotations

import click

from metalens_cli.errors import InputError
from metalens_cli.io import units


def _option_name(param: click.Parameter | None) -> str:
    if param is None:
        return "value"
    return max(param.opts, key=len) if param.opts else param.name


class _UnitType(click.ParamType):
    """Base: call ``parse(text, field)`` and turn an :class:`InputError` into ``self.fail``.

    ``allow_inf`` lets the length types accept ``inf``.
    """

    def __init__(self, allow_inf: bool = False):
        self.allow_inf = allow_inf

    def parse(self, text: str, field: str):
        raise NotImplementedError

    def convert(self, value, param, ctx):
        if not isinstance(value, str):
            return value  # already converted (a default given in SI)
        try:
            return self.parse(value, _option_name(param))
        except InputError as exc:
            self.fail(f"{exc.message} (expected {exc.expected})" if exc.expected else exc.message, param, ctx)


class Length(_UnitType):
    """One length: ``4mm``; ``inf`` when ``allow_inf``."""

    name = "length"

    def parse(self, text, field):
        return units.parse_length(text, field, allow_inf=self.allow_inf)


class LengthList(_UnitType):
    """Lengths and ranges: ``45mm,inf`` or ``430:645:5nm`` → list of metres."""

    name = "lengths"

    def parse(self, text, field):
        return units.parse_length_list(text, field, allow_inf=self.allow_inf)


class Interval(_UnitType):
    """``40mm:50mm`` or one length ``45mm`` → (lo, hi) in metres."""

    name = "interval"

    def parse(self, text, field):
        return units.parse_interval(text, field)


class BandSpec(_UnitType):
    """``CENTER:WIDTH`` with units, e.g. ``457nm:22nm`` → (centre, width) in metres."""

    name = "band"

    def parse(self, text, field):
        parts = text.split(":")
        if len(parts) != 2:
            raise InputError(field, f"{text!r} is not CENTER:WIDTH", "CENTER:WIDTH with units, e.g. 457nm:22nm")
        return tuple(units.parse_length(part, field) for part in parts)


class SeedList(click.ParamType):
    """``0``, ``0,1,2`` or an inclusive range ``0:2`` → list of non-negative integers."""

    name = "seeds"

    def convert(self, value, param, ctx):
        if isinstance(value, list):
            return value
        seeds = []
        try:
            for part in str(value).split(","):
                lo, _, hi = part.strip().partition(":")
                seeds += list(range(int(lo), int(hi or lo) + 1))
        except ValueError:
            seeds = []
        if not seeds or min(seeds) < 0 or len(seeds) > 1000:
            self.fail(f"{value!r} (expected seeds like 0, 0,1,2 or 0:2)", param, ctx)
        return seeds


def flatten(values) -> list[float]:
    """Join the lists of a repeatable LengthList option."""
    return [v for group in values or () for v in group]


preset_option = click.option(
    "--preset",
    "preset_path",
    type=click.Path(dir_okay=False),
    help="Preset TOML file; explicit options override its values.",
)
DESIGN_HELP = "Design spec: hyperbolic:532nm, THETA.npy, PRESET.toml or a run directory."


def apply_options(command, options: list):
    """Decorate ``command`` with ``options`` so that they appear in --help in list order."""
    for option in reversed(options):
        command = option(command)
    return command


def geometry_options(command):
    """--preset and the lens geometry overrides (``preset_path``, ``f_m``, ``aperture_m``, ``pitch_m``)."""
    return apply_options(command, [
        preset_option,
        click.option("--f", "f_m", type=Length(), help="Lens-to-sensor distance (focal length)."),
        click.option("--aperture", "aperture_m", type=Length(), help="Lens diameter D."),
        click.option("--pitch", "pitch_m", type=Length(), help="Meta-atom pitch [preset's; hyperbolic default 395nm]."),
    ])


def design_options(command):
    """--design SPEC (``spec``) followed by :func:`geometry_options`."""
    return click.option("--design", "spec", required=True, help=DESIGN_HELP)(geometry_options(command))


def training_options(section: str):
    """--steps, --seed, --device, --resume, --threads, --quiet and --json of a training command whose
    preset holds steps and seed in ``[section]``."""
    def decorate(command):
        return apply_options(command, [
            click.option("--steps", type=click.IntRange(0), help=f"Training steps [the preset's {section}.steps]."),
            click.option("--seed", type=click.IntRange(0), help=f"Seed of every random draw [the preset's {section}.seed]."),
            click.option("--device", default="cpu", show_default=True, help="torch device: cpu, cuda, cuda:1, mps (under torchrun: each rank's)."),
            click.option("--resume", is_flag=True, help="Continue the run in --output from its newest checkpoint (with the preset saved there)."),
            click.option("--threads", type=click.IntRange(1), help="CPU threads for torch [torch's default]."),
            click.option("--quiet", is_flag=True, help="No progress bar or progress lines."),
            json_option,
        ])
    return decorate


json_option = click.option("--json", "as_json", is_flag=True, help="Print one JSON object on stdout and nothing else.")
plot_option = click.option(
    "--plot", "plot_path", type=click.Path(dir_okay=False), help="Write a figure (PNG) to this file."
)


def load_preset_option(path: str | None):
    """The preset named by --preset, or None."""
    if path is None:
        return None
    from metalens_cli.io.presets import load_preset

    return load_preset(path)


def pick(explicit, preset, getter, option: str, form: str):
    """An explicit option wins over the preset's value; neither → a one-line error naming ``option``."""
    if explicit is not None:
        return explicit
    value = getter(preset) if preset is not None else None
    if value is None:
        where = "" if preset is None else f" (preset {preset.name} has none)"
        raise InputError(option, f"missing{where}", f"{form}, or --preset FILE")
    return value


def torch_device(name: str):
    """A torch.device, refusing devices this machine does not have."""
    import torch

    try:
        device = torch.device(name)
    except RuntimeError:
        raise InputError("--device", f"unknown device {name!r}", "cpu, cuda, cuda:N or mps") from None
    if device.type == "cuda" and not torch.cuda.is_available():
        raise InputError("--device", "CUDA is not available on this machine", "cpu")
    if device.type == "mps" and not torch.backends.mps.is_available():
        raise InputError("--device", "MPS is not available on this machine", "cpu")
    return device
