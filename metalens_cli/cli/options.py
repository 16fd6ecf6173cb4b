"""Click parameter types (lengths with units, finite numbers, devices, output paths), the
command class that checks outputs against inputs, and the shared --preset/--json options.

Each type converts to SI metres through :mod:`metalens_cli.io.units`; a bad value becomes a
Click usage error naming the option and the accepted form (rendered as one line, exit 2).
Output paths are checked while the command line is parsed, before any work.
"""

from __future__ import annotations

import itertools
import math
import os
import re

import click

from metalens_cli.constants import LPIPS_WEIGHTS_ENV
from metalens_cli.errors import InputError
from metalens_cli.io import units
from metalens_cli.io.atomic import check_folder_unused, check_output_file, check_output_folder, same_file
from metalens_cli.io.tables import check_wavelengths


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
        """The length in metres (float), ``math.inf`` for ``inf`` when ``allow_inf``; a bad value
        raises an :class:`InputError` naming ``field`` and the accepted form."""
        return units.parse_length(text, field, allow_inf=self.allow_inf)


class Angle(_UnitType):
    """One angle: ``25deg`` or ``0.4rad`` → radians in [0, π/2)."""

    name = "angle"

    def parse(self, text, field):
        """The angle in radians (float), in [0, π/2); a bad value raises an :class:`InputError`
        naming ``field`` and the accepted form."""
        return units.parse_angle(text, field)


class AngleList(_UnitType):
    """Angles and ranges: ``0deg,3deg,6.75deg`` or ``0:6:1.5deg`` → list of radians in [0, π/2)."""

    name = "angles"

    def parse(self, text, field):
        """The angles in radians (list of floats in [0, π/2)), in the order given with ranges
        expanded, at most 100; a bad value raises an :class:`InputError` naming ``field`` and the
        accepted form."""
        return units.parse_angle_list(text, field)


class HeightList(_UnitType):
    """Lengths ≥ 0 and ranges: ``0um,250um`` → list of metres (sensor heights; 0 is the axis)."""

    name = "heights"

    def parse(self, text, field):
        """The heights in metres (list of floats ≥ 0; 0 is the axis), in the order given, ranges
        expanded; a bad value raises an :class:`InputError` naming ``field`` and the accepted form."""
        return units.parse_height_list(text, field)


class Azimuth(_UnitType):
    """One azimuth: ``90deg`` → radians in [0, 2π)."""

    name = "azimuth"

    def parse(self, text, field):
        """The azimuth in radians (float), in [0, 2π); a bad value raises an :class:`InputError`
        naming ``field`` and the accepted form."""
        return units.parse_angle(text, field, full_circle=True)


class LengthList(_UnitType):
    """Lengths and ranges: ``45mm,inf`` or ``430:645:5nm`` → list of metres."""

    name = "lengths"

    def parse(self, text, field):
        """The lengths in metres (list of floats; ``math.inf`` for ``inf`` items when
        ``allow_inf``), in the order given with ranges expanded; a bad value raises an
        :class:`InputError` naming ``field`` and the accepted form."""
        return units.parse_length_list(text, field, allow_inf=self.allow_inf)


class Interval(_UnitType):
    """``40mm:50mm`` or one length ``45mm`` → (lo, hi) in metres."""

    name = "interval"

    def parse(self, text, field):
        """The interval (lo, hi) in metres; one length gives (length, length); a bad value raises an
        :class:`InputError` naming ``field`` and the accepted form."""
        return units.parse_interval(text, field)


class _Optical:
    """Mixin of a length type: every value parsed must be an optical wavelength (100 nm-10 µm)."""

    def parse(self, text, field):
        value = super().parse(text, field)
        check_wavelengths(value if isinstance(value, (list, tuple)) else [value], field)
        return value


class Wavelength(_Optical, Length):
    """One optical wavelength: ``532nm``."""

    name = "wavelength"


class WavelengthList(_Optical, LengthList):
    """Optical wavelengths and ranges: ``457nm,530nm`` or ``430:645:5nm``."""

    name = "wavelengths"


class WavelengthInterval(_Optical, Interval):
    """An interval of optical wavelengths: ``400nm:700nm``."""


class BandSpec(_UnitType):
    """``CENTER:WIDTH`` with units, e.g. ``457nm:22nm`` → (centre, width) in metres."""

    name = "band"

    def parse(self, text, field):
        """The band's (centre, width) in metres, the whole band [c − w/2, c + w/2] optical; a bad
        value raises an :class:`InputError` naming ``field`` and the accepted form."""
        parts = text.split(":")
        if len(parts) != 2:
            raise InputError(field, f"{text!r} is not CENTER:WIDTH", "CENTER:WIDTH with units, e.g. 457nm:22nm")
        centre, width = (units.parse_length(part, field) for part in parts)
        check_wavelengths([centre - width / 2, centre, centre + width / 2], field)  # the whole band is optical
        return centre, width


MAX_SEEDS = 1000


class SeedList(click.ParamType):
    """``0``, ``0,1,2`` or an inclusive range ``0:2`` → list of non-negative integers."""

    name = "seeds"

    def convert(self, value, param, ctx):
        """The seeds as a list of ints ≥ 0, in the order given with inclusive ranges expanded
        (repeats kept), at most ``MAX_SEEDS``; a bad value fails with the accepted form."""
        if isinstance(value, list):
            return value
        bounds = []
        try:
            for part in str(value).split(","):
                lo, _, hi = part.strip().partition(":")
                bounds.append((int(lo), int(hi or lo)))
        except ValueError:
            bounds = []
        if not bounds or min(lo for lo, _ in bounds) < 0 or any(hi < lo for lo, hi in bounds):
            self.fail(f"{value!r} (expected seeds like 0, 0,1,2 or 0:2)", param, ctx)
        count = sum(hi - lo + 1 for lo, hi in bounds)  # before any list is built
        if count > MAX_SEEDS:
            self.fail(f"{value!r} holds {count} seeds (expected at most {MAX_SEEDS})", param, ctx)
        return [seed for lo, hi in bounds for seed in range(lo, hi + 1)]


class CommaChoice(click.ParamType):
    """Comma-separated names, each one of ``choices`` → a tuple of them (repeats dropped)."""

    name = "names"

    def __init__(self, choices) -> None:
        self.choices = tuple(choices)

    def convert(self, value, param, ctx):
        """The names given, in order, each once; an unknown one fails naming the choices."""
        if isinstance(value, tuple):
            return value
        names = tuple(dict.fromkeys(part.strip() for part in str(value).split(",")))
        unknown = [n for n in names if n not in self.choices]
        if unknown:
            self.fail(f"{unknown[0]!r} (expected {', '.join(self.choices)}, comma-separated)", param, ctx)
        return names


class LightLevels(click.ParamType):
    """Light levels (``imaging.camera``): electrons at full scale before the filter, or a name
    (dim, indoor, daylight), or ``none`` (noise-free), comma-separated → sorted floats, None first."""

    name = "light"

    def convert(self, value, param, ctx):
        """The light levels as a list: None (noise-free) first, then the electrons at full scale
        ascending (numbers > 0, names resolved by ``LIGHT_NAMES``), repeats dropped; a bad value
        fails with the accepted form."""
        from metalens_cli.constants import LIGHT_NAMES

        if isinstance(value, list):
            return value
        levels = []
        for part in str(value).split(","):
            word = part.strip().lower()
            try:
                level = None if word in ("none", "noise-free") else LIGHT_NAMES.get(word) or float(word)
            except ValueError:
                level = -1.0
            if level is not None and not (math.isfinite(level) and level > 0):
                names = ", ".join(f"{k} ({v:g})" for k, v in LIGHT_NAMES.items())
                self.fail(
                    f"{part!r} (expected electrons > 0, none, or one of {names}; e.g. 250,2000,20000)", param, ctx
                )
            if level not in levels:
                levels.append(level)
        return sorted(levels, key=lambda v: -1.0 if v is None else v)


class Number(click.FloatRange):
    """A finite float in a range: ``click.FloatRange`` lets ``nan`` and ``inf`` through."""

    def convert(self, value, param, ctx):
        """The value as a float within the range and finite; ``nan``, ``inf`` or a value out of
        range fails with the accepted form."""
        number = super().convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return number


DEVICE_FORM = "auto, cpu, cuda, cuda:N or mps"
DEVICE_PATTERN = r"auto|cpu|cuda(:\d{1,3})?|mps"


class Device(click.ParamType):
    """A torch device name or ``auto``, checked for form without importing torch
    (:func:`torch_device` resolves ``auto`` and checks that the machine has the device)."""

    name = "device"

    def convert(self, value, param, ctx):
        """The device name as given (auto, cpu, cuda, cuda:N or mps), checked for its form only; a
        bad value fails with the accepted form."""
        if not re.fullmatch(DEVICE_PATTERN, str(value)):
            self.fail(f"unknown device {value!r} (expected {DEVICE_FORM})", param, ctx)
        return value

    def shell_complete(self, ctx, param, incomplete):
        """Completions: the device names auto, cpu, cuda and mps that start with ``incomplete``."""
        from click.shell_completion import CompletionItem

        return [CompletionItem(name) for name in ("auto", "cpu", "cuda", "mps") if name.startswith(incomplete)]


class MemorySize(click.ParamType):
    """A memory size: ``8GiB``, ``500MB``, ``2e9`` (bytes) → int bytes."""

    name = "size"
    UNITS = {
        "": 1,
        "b": 1,
        "kb": 10**3,
        "mb": 10**6,
        "gb": 10**9,
        "tb": 10**12,
        "kib": 2**10,
        "mib": 2**20,
        "gib": 2**30,
        "tib": 2**40,
    }

    def convert(self, value, param, ctx):
        """The size in bytes (int ≥ 1) of a number with an optional unit, any case: B, decimal kB …
        TB (10³ …) or binary KiB … TiB (2¹⁰ …); an int passes as it is; a bad value fails with the
        accepted form."""
        if isinstance(value, int):
            return value
        match = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][+-]?[0-9]+)?)\s*([A-Za-z]*)\s*", str(value))
        unit = match.group(2).lower() if match else ""
        if not match or unit not in self.UNITS or not 0 < float(match.group(1)) < 1e18:
            self.fail(f"{value!r} is not a memory size (expected e.g. 8GiB, 500MB or bytes)", param, ctx)
        size = int(float(match.group(1)) * self.UNITS[unit])
        if size < 1:
            self.fail(f"{value!r} is less than one byte (expected e.g. 8GiB, 500MB or bytes)", param, ctx)
        return size


class Duration(_UnitType):
    """A run time: ``90s``, ``30min``, ``2h``, ``1d``, ``inf`` → seconds."""

    name = "duration"

    def parse(self, text, field):
        """The duration in seconds (float ≥ 1 ms), ``math.inf`` for ``inf``; a bad value raises an
        :class:`InputError` naming ``field`` and the accepted form."""
        return units.parse_duration(text, field)


def _remember_max_time(ctx, param, value):
    ctx.meta["metalens.max_time"] = value
    return value


def max_memory_option(function):
    """``--max-memory`` (passed to the command) and ``--max-time`` (kept in the context for
    :func:`announce`): the limits every command that estimates its cost accepts."""
    function = click.option(
        "--max-time",
        type=Duration(),
        default="24h",
        expose_value=False,
        callback=_remember_max_time,
        show_default=True,
        help="Refuse to start when the estimated run time (its longest) exceeds this, e.g. 30min or 2h; "
        "inf for no limit.",
    )(function)
    return click.option(
        "--max-memory",
        type=MemorySize(),
        help="Refuse to start when the estimated memory exceeds this, e.g. 8GiB "
        "[90 % of the free memory: a CUDA device's own, else the host's RAM].",
    )(function)


def announce(estimate, max_memory: int | None, output=None, device=None) -> None:
    """Check ``estimate`` (:func:`metalens_cli.io.resources.check`) against ``max_memory``, the
    free memory of ``device`` (a CUDA device's own, else the host's RAM) and the command's
    ``--max-time`` and, for a long job, say it on stderr before starting (also under --quiet: a
    pipeline's log should show why it waits)."""
    from metalens_cli.io import resources

    ctx = click.get_current_context(silent=True)
    max_time = ctx.meta.get("metalens.max_time", resources.MAX_SECONDS) if ctx is not None else resources.MAX_SECONDS
    resources.check(estimate, max_memory, output, max_seconds=max_time, device=device)
    if resources.is_long(estimate):
        click.echo(f"metalens: {estimate.describe()}", err=True)


PLOT_SUFFIXES = (".png", ".pdf", ".svg", ".jpg", ".jpeg", ".tif", ".tiff", ".webp", ".eps", ".ps")


class OutputFile(click.ParamType):
    """A file the command will write: checked at once (:func:`check_output_file`), optionally
    for its suffix; ``MetalensCommand`` also refuses one that is among the inputs."""

    name = "file"

    def __init__(self, suffixes: tuple[str, ...] | None = None):
        self.suffixes = suffixes

    def convert(self, value, param, ctx):
        """The output path (str), checked by :func:`check_output_file` (and for ``suffixes`` when
        given); a bad path fails with the accepted form."""
        try:
            return str(check_output_file(value, _option_name(param), suffixes=self.suffixes))
        except InputError as exc:
            self.fail(f"{exc.message} (expected {exc.expected})", param, ctx)


class OutputFolder(click.ParamType):
    """A folder the command will create or write into: checked at once, created only when the
    command starts writing (:func:`check_output_folder`)."""

    name = "directory"

    def convert(self, value, param, ctx):
        """The output folder (str), checked by :func:`check_output_folder` (created only later, when
        the command writes); a bad path fails with the accepted form."""
        try:
            return str(check_output_folder(value, _option_name(param)))
        except InputError as exc:
            self.fail(f"{exc.message} (expected {exc.expected})", param, ctx)


class MetalensCommand(click.Command):
    """A command that, before running, refuses an output path naming one of its inputs (an
    output file equal to any existing file given as another parameter, or an output folder
    equal to an input folder or holding an input file it would write over), and whose core
    errors name the option (``--wavelengths``) where the core named its argument."""

    def invoke(self, ctx):
        """Refuse outputs that clash with one another or with an input (see the class), hold every
        output folder (:func:`hold_folder`), then run the command; a core :class:`InputError` is
        re-raised naming the option its field came from, and offering ``--force`` where the error is
        forceable and the command has that option."""
        outputs, inputs = [], []
        for param in self.params:
            value = ctx.params.get(param.name)
            values = value if isinstance(value, (list, tuple)) else [value]
            if isinstance(param.type, (OutputFile, OutputFolder)):
                outputs += [(param, v) for v in values if v is not None]
            else:  # paths, also inside lists such as --kinds dirt,file:mask.png
                texts = [v for v in values if isinstance(v, str)]
                inputs += [
                    p
                    for v in texts
                    for p in {v, *(part.strip().removeprefix("file:") for part in v.split(","))}
                    if p and os.path.exists(p)
                ]
        for (param, output), (other_param, other) in itertools.combinations(outputs, 2):
            if same_file(output, other):
                raise InputError(
                    _option_name(other_param),
                    f"{other!r} is also {_option_name(param)}'s output",
                    "a separate path for each output",
                )
        for param, output in outputs:
            for path in inputs:
                if same_file(output, path) or (
                    isinstance(param.type, OutputFolder)
                    and os.path.isfile(path)
                    and same_file(output, os.path.dirname(path) or ".")
                ):
                    raise InputError(
                        _option_name(param),
                        f"{output!r} is also an input ({path!r}); it would be overwritten",
                        "an output path apart from the inputs",
                    )
        for param, output in outputs:
            if isinstance(param.type, OutputFolder):
                hold_folder(output, _option_name(param))
        try:
            return super().invoke(ctx)
        except InputError as exc:  # the core names its argument (wavelengths): name the option (--wavelengths)
            param = next((p for p in self.params if p.name in (exc.field, f"{exc.field}_m") and p.opts), None)
            forced = getattr(exc, "forceable", False) and any(p.name == "force" for p in self.params)
            if param is None and not forced:
                raise
            expected = f"{exc.expected}; or --force to compute anyway" if forced else exc.expected
            raise InputError(exc.field if param is None else _option_name(param), exc.message, expected) from None


def refuse_overwriting(outputs: list[tuple[str, str | None]], inputs: list) -> None:
    """Refuse an output (option, path) naming one of ``inputs``: files a command reads that its
    command line does not show (frames of a manifest, images of a folder), which
    :class:`MetalensCommand` cannot check."""
    for option, path in outputs:
        clash = next((item for item in inputs if path is not None and same_file(path, item)), None)
        if clash is not None:
            raise InputError(
                option,
                f"{path!r} is also an input ({str(clash)!r}); it would be overwritten",
                "an output path apart from the inputs",
            )


class MetalensGroup(click.Group):
    """A subcommand group whose commands are :class:`MetalensCommand`."""

    command_class = MetalensCommand


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
    return apply_options(
        command,
        [
            preset_option,
            click.option("--f", "f_m", type=Length(), help="Lens-to-sensor distance (focal length)."),
            click.option("--aperture", "aperture_m", type=Length(), help="Lens diameter D."),
            click.option(
                "--pitch", "pitch_m", type=Length(), help="Meta-atom pitch [preset's; hyperbolic default 395nm]."
            ),
        ],
    )


def design_options(command):
    """--design SPEC (``spec``) followed by :func:`geometry_options`."""
    return click.option("--design", "spec", required=True, help=DESIGN_HELP)(geometry_options(command))


def training_options(section: str):
    """--steps, --seed, --device, --resume, --threads, --quiet and --json of a training command whose
    preset holds steps and seed in ``[section]``."""

    def decorate(command):
        return apply_options(
            command,
            [
                click.option("--steps", type=click.IntRange(0), help=f"Training steps [the preset's {section}.steps]."),
                click.option(
                    "--seed", type=click.IntRange(0), help=f"Seed of every random draw [the preset's {section}.seed]."
                ),
                click.option(
                    "--device",
                    type=Device(),
                    default="cpu",
                    show_default=True,
                    help="torch device: cpu, cuda, cuda:1, mps, or auto (cuda if available, then mps, then cpu; "
                    "under torchrun: each rank's).",
                ),
                click.option(
                    "--resume",
                    is_flag=True,
                    help="Continue the run in --output from its newest checkpoint (with the preset saved there).",
                ),
                click.option(
                    "--threads",
                    type=click.IntRange(1),
                    callback=_usable_threads,
                    help="CPU threads for torch, at most the cores this process may use [torch's default].",
                ),
                quiet_option("No progress bar or progress lines."),
                json_option,
            ],
        )

    return decorate


def _usable_threads(ctx, param, threads: int | None) -> int | None:
    """``--threads`` no more than the CPU cores this process may run on: more torch threads than
    cores only contend (1024 on 2 cores stall a training step for minutes)."""
    if threads is None:
        return None
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    if threads > cores:
        raise InputError(
            "--threads", f"{threads} threads on the {cores} CPU core(s) this process may use", f"at most {cores}"
        )
    return threads


def quiet_option(help_text: str = "No progress bar."):
    """``--quiet``, declared once for every command; ``help_text`` says what else it silences."""
    return click.option("--quiet", is_flag=True, help=help_text)


overwrite_option = click.option(
    "--overwrite",
    is_flag=True,
    help="Write into an output folder that already holds files, replacing same-named ones "
    "(without it such a folder is refused).",
)


def hold_folder(path: str | os.PathLike[str], field: str) -> None:
    """Hold the output folder ``path`` until the command ends (``io.atomic.claim_folder``: a
    second run into it meanwhile is refused); once per folder; under torchrun by rank 0 only,
    the rank that writes."""
    from metalens_cli.io.atomic import claim_folder

    ctx = click.get_current_context()
    held = ctx.find_root().meta.setdefault("metalens.held_folders", set())
    key = os.path.realpath(path)
    if key not in held and os.environ.get("RANK", "0") == "0":
        ctx.with_resource(claim_folder(path, field))
        held.add(key)


def check_output_unused(output: str, overwrite: bool, field: str = "--output") -> None:
    """Refuse, before any work, an output folder (option ``field``) already holding files,
    unless ``overwrite``."""
    if not overwrite:
        check_folder_unused(output, field)


def lpips_weights_option(help_text: str):
    """``--lpips-weights DIR``, also read from ``$METALENS_LPIPS_WEIGHTS`` (shown in --help)."""
    return click.option(
        "--lpips-weights",
        "lpips_weights",
        type=click.Path(exists=True, file_okay=False),
        envvar=LPIPS_WEIGHTS_ENV,
        show_envvar=True,
        help=help_text,
    )


json_option = click.option("--json", "as_json", is_flag=True, help="Print one JSON object on stdout and nothing else.")
plot_option = click.option(
    "--plot",
    "plot_path",
    type=OutputFile(PLOT_SUFFIXES),
    help="Write a figure (PNG, PDF or SVG, by the suffix) to this file.",
)
device_option = click.option(
    "--device",
    type=Device(),
    default="cpu",
    show_default=True,
    help="torch device: cpu, cuda, cuda:1, mps, or auto (cuda if available, then mps, then cpu).",
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


def auto_device() -> str:
    """The device ``--device auto`` means on this machine: cuda if torch sees a CUDA device, then
    mps (Apple silicon), then cpu."""
    import torch

    if torch.cuda.is_available():
        return "cuda"
    mps = getattr(torch.backends, "mps", None)
    if mps is not None and mps.is_available():
        return "mps"
    return "cpu"


def torch_device(name: str):
    """A torch.device (``auto`` resolved by :func:`auto_device`), refusing devices this machine
    does not have (``metalens_cli.arguments.device``)."""
    from metalens_cli.arguments import device

    if not re.fullmatch(DEVICE_PATTERN, str(name)):
        raise InputError("--device", f"unknown device {name!r}", DEVICE_FORM)
    return device(auto_device() if name == "auto" else name, "--device")
