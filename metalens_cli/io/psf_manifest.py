"""Manifests of measured PSF frames (``metalens psf import``) and the reading of those frames.

A manifest says which file holds the PSF at which wavelength and source depth, and with what
exposure. Three forms, file paths relative to the manifest's folder:

- CSV, a header row naming the columns ``file``, ``wavelength``, ``depth`` and optionally
  ``exposure`` (any order), one frame per row;
- TOML, ``[[frame]]`` tables with the same keys, and optional top-level defaults of the
  command's options: ``pixel_pitch``, ``magnification``, ``dark``, ``saturation``, ``design``;
- a folder and a file-name pattern such as ``psf_{wavelength}_{depth}.png`` (``{exposure}``
  optional; ``{wavelength:nm}`` gives the unit of bare numbers in the names).

Values carry units: ``530nm``, ``45mm``, ``inf`` (a source at infinity); exposures ``10ms``,
``0.5s``, ``200us`` or a bare number of seconds. ``file`` may name frame K (from 0) of a
(F, H, W) ``.npy`` stack as ``stack.npy#K``. Frames sharing a wavelength and depth are repeats
(averaged by the importer); together the frames must fill the grid of every wavelength at
every depth.
"""

from __future__ import annotations

import csv
import io
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from metalens_cli.errors import InputError
from metalens_cli.io.image_files import read_image_codes
from metalens_cli.io.input_files import check_image_size, read_npy, read_text
from metalens_cli.io.tables import check_wavelengths
from metalens_cli.io.units import parse_length

COLUMNS = ("file", "wavelength", "depth", "exposure")
REQUIRED_COLUMNS = COLUMNS[:3]
TOML_SETTINGS = ("pixel_pitch", "magnification", "dark", "saturation", "design")
FRAME_SUFFIXES = (".png", ".tif", ".tiff", ".exr", ".npy")
MAX_FRAMES = 10_000
EXPOSURE_RANGE_S = (1e-9, 1e6)
MAGNIFICATION_RANGE = (1e-4, 1e4)  # the --magnification option's
SATURATION_MAX = 1e30  # the --saturation option's
_SECONDS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "ns": 1e-9}
_EXPOSURE = re.compile(r"\s*([0-9]*\.?[0-9]+(?:[eE][+-]?[0-9]+)?)\s*(s|ms|us|µs|ns)?\s*")
_PLACEHOLDER = re.compile(r"\{(wavelength|depth|exposure)(?::([a-zµ]+))?\}")
MANIFEST_FORM = (
    "a CSV with columns file,wavelength,depth[,exposure], a TOML with [[frame]] tables, or a folder with --pattern"
)


@dataclass(frozen=True)
class FrameEntry:
    """One frame: ``path`` (and ``index`` into a .npy stack, or None), wavelength and depth in
    metres (``inf`` for a source at infinity), exposure in seconds (None: not given), and
    ``where`` it was named (``psf.csv line 4``) for messages."""

    path: Path
    index: int | None
    wavelength_m: float
    depth_m: float
    exposure_s: float | None
    where: str

    @property
    def name(self) -> str:
        """The file name as the manifest gave it (with ``#K`` for a stack frame)."""
        return self.path.name + ("" if self.index is None else f"#{self.index}")


@dataclass(frozen=True)
class Manifest:
    """The frames of a manifest, the grid they fill, and the TOML's option defaults
    (``settings``: keys of ``TOML_SETTINGS``, ``dark`` resolved against the manifest's folder)."""

    source: str
    frames: list[FrameEntry]
    settings: dict = field(default_factory=dict)

    @property
    def wavelengths_m(self) -> list[float]:
        """The distinct wavelengths, ascending."""
        return sorted({f.wavelength_m for f in self.frames})

    @property
    def depths_m(self) -> list[float]:
        """The distinct depths, ascending (infinity last)."""
        return sorted({f.depth_m for f in self.frames})

    def cell(self, depth_m: float, wavelength_m: float) -> list[FrameEntry]:
        """The frames (repeats) at one depth and wavelength."""
        return [f for f in self.frames if f.depth_m == depth_m and f.wavelength_m == wavelength_m]


def read_manifest(path: str | Path, pattern: str | None = None) -> Manifest:
    """The manifest at ``path`` (CSV, TOML, or a folder read with ``pattern``), checked: values
    with their units, files present, every (depth, wavelength) of the grid covered. Errors are
    one-line :class:`InputError` naming the manifest and line."""
    path = Path(path)
    if path.is_dir():
        if pattern is None:
            raise InputError(
                "MANIFEST",
                f"{str(path)!r} is a folder and no --pattern was given",
                "--pattern NAME such as psf_{wavelength}_{depth}.png for a folder of frames",
            )
        frames, settings = _from_pattern(path, pattern), {}
    elif pattern is not None:
        raise InputError("--pattern", "only applies to a folder of frames", "MANIFEST a folder, or no --pattern")
    elif path.suffix.lower() == ".toml":
        frames, settings = _from_toml(path)
    else:
        frames, settings = _from_csv(path), {}
    if not frames:
        raise InputError(str(path), "lists no frames", MANIFEST_FORM)
    if len(frames) > MAX_FRAMES:
        raise InputError(str(path), f"lists {len(frames)} frames", f"at most {MAX_FRAMES}")
    manifest = Manifest(str(path), frames, settings)
    _check_grid(manifest)
    return manifest


def _from_csv(path: Path) -> list[FrameEntry]:
    text = read_text(path, str(path), MANIFEST_FORM)
    try:
        rows = list(csv.reader(io.StringIO(text)))
    except csv.Error as exc:
        raise InputError(str(path), f"is not valid CSV ({exc})", MANIFEST_FORM) from None
    rows = [(number, row) for number, row in enumerate(rows, 1) if any(cell.strip() for cell in row)]
    if not rows:
        raise InputError(str(path), "is empty", MANIFEST_FORM)
    header = [cell.strip().lower() for cell in rows[0][1]]
    missing = [c for c in REQUIRED_COLUMNS if c not in header]
    unknown = [c for c in header if c not in COLUMNS]
    if missing or unknown or len(set(header)) != len(header):
        what = (
            f"lacks the column(s) {', '.join(missing)}"
            if missing
            else (f"has unknown column(s) {', '.join(unknown)}" if unknown else "repeats a column")
        )
        raise InputError(
            f"{path.name} line {rows[0][0]}",
            f"header {','.join(header)!r} {what}",
            "a header naming file, wavelength, depth and optionally exposure",
        )
    frames = []
    for number, row in rows[1:]:
        where = f"{path.name} line {number}"
        if len(row) != len(header):
            raise InputError(where, f"{len(row)} values for {len(header)} columns", "one value per header column")
        values = dict(zip(header, (cell.strip() for cell in row)))
        frames.append(_entry(path.parent, values, where))
    return frames


def _from_toml(path: Path) -> tuple[list[FrameEntry], dict]:
    try:
        data = tomllib.loads(read_text(path, str(path), MANIFEST_FORM))
    except tomllib.TOMLDecodeError as exc:
        raise InputError(str(path), f"is not valid TOML ({exc})", MANIFEST_FORM) from None
    unknown = sorted(set(data) - {"frame", *TOML_SETTINGS})
    if unknown:
        raise InputError(
            path.name, f"unknown key(s) {', '.join(unknown)}", f"frame tables and {', '.join(TOML_SETTINGS)}"
        )
    tables = data.get("frame", [])
    if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
        raise InputError(f"{path.name}: frame", "is not an array of tables", "[[frame]] tables")
    frames = []
    for k, table in enumerate(tables):
        where = f"{path.name} frame {k + 1}"
        extra = sorted(set(table) - set(COLUMNS))
        if extra:
            raise InputError(where, f"unknown key(s) {', '.join(extra)}", "file, wavelength, depth, exposure")
        frames.append(_entry(path.parent, {key: str(value) for key, value in table.items()}, where))
    return frames, _toml_settings(path, data)


def _toml_settings(path: Path, data: dict) -> dict:
    """Top-level option defaults with units parsed (metres, a number, a path)."""
    settings = {}
    if "pixel_pitch" in data:
        settings["pixel_pitch_m"] = parse_length(str(data["pixel_pitch"]), f"{path.name}: pixel_pitch")
    for key, (lo, hi) in (("magnification", MAGNIFICATION_RANGE), ("saturation", (0, SATURATION_MAX))):
        if key in data:
            value = data[key]
            if isinstance(value, bool) or not isinstance(value, int | float) or not lo < value <= hi:
                raise InputError(f"{path.name}: {key}", repr(value), f"a number above {lo:g}, at most {hi:g}")
            settings[key] = float(value)
    for key in ("dark", "design"):
        if key in data:
            if not isinstance(data[key], str) or not data[key]:
                raise InputError(f"{path.name}: {key}", repr(data[key]), "a non-empty string")
            settings[key] = path.parent / data[key] if key == "dark" else data[key]
    return settings


def _from_pattern(folder: Path, pattern: str) -> list[FrameEntry]:
    """Frames of ``folder`` whose names match ``pattern`` (its placeholders as values)."""
    keys = [m.group(1) for m in _PLACEHOLDER.finditer(pattern)]
    if sorted(set(keys)) != sorted(keys) or not {"wavelength", "depth"} <= set(keys) or "/" in pattern:
        raise InputError(
            "--pattern",
            repr(pattern),
            "a file name with {wavelength} and {depth} once each, e.g. psf_{wavelength}_{depth}.png",
        )
    units = {m.group(1): m.group(2) or "" for m in _PLACEHOLDER.finditer(pattern)}
    regex, last = "", 0
    for m in _PLACEHOLDER.finditer(pattern):
        regex += re.escape(pattern[last : m.start()]) + f"(?P<{m.group(1)}>.+?)"
        last = m.end()
    regex = re.compile(regex + re.escape(pattern[last:]))
    frames = []
    for path in sorted(folder.iterdir()):
        match = regex.fullmatch(path.name)
        if match is None or not path.is_file() or path.name.startswith("."):
            continue
        values = {key: text + ("" if text.lower() == "inf" else units[key]) for key, text in match.groupdict().items()}
        frames.append(_entry(folder, {"file": path.name, **values}, path.name))
    if not frames:
        raise InputError(
            "--pattern", f"no file in {str(folder)!r} matches {pattern!r}", "a pattern matching the frames' names"
        )
    return frames


def _entry(folder: Path, values: dict[str, str], where: str) -> FrameEntry:
    """One checked frame entry from its text values."""
    name = values.get("file", "")
    if not name:
        raise InputError(where, "file is empty", "a frame file name relative to the manifest")
    index = None
    stack = re.fullmatch(r"(.+\.npy)#(\d+)", name)
    if stack:
        name, index = stack.group(1), int(stack.group(2))
    path = folder / name
    if path.suffix.lower() not in FRAME_SUFFIXES:
        raise InputError(
            where,
            f"file {name!r} is not a frame format",
            f"a {', '.join(FRAME_SUFFIXES)} file (stack.npy#K for a stack frame)",
        )
    if not path.is_file():
        raise InputError(where, f"no such file {str(path)!r}", "frame paths relative to the manifest's folder")
    for key in REQUIRED_COLUMNS[1:]:
        if not values.get(key):
            raise InputError(where, f"{key} is missing", "file, wavelength and depth for every frame")
    wavelength = parse_length(values["wavelength"], f"{where}: wavelength")
    check_wavelengths([wavelength], f"{where}: wavelength")
    depth = parse_length(values["depth"], f"{where}: depth", allow_inf=True)
    exposure = _exposure(values["exposure"], where) if values.get("exposure") else None
    return FrameEntry(path, index, wavelength, depth, exposure, where)


def _exposure(text: str, where: str) -> float:
    """``10ms``, ``0.5s``, ``200us`` or a bare number: seconds, from 1 ns to 1e6 s."""
    m = _EXPOSURE.fullmatch(text)
    value = float(m.group(1)) * _SECONDS[m.group(2) or "s"] if m else 0.0
    if not EXPOSURE_RANGE_S[0] <= value <= EXPOSURE_RANGE_S[1]:
        raise InputError(
            f"{where}: exposure",
            repr(text),
            "a time from 1ns to 1e6s such as 10ms, 0.5s, 200us (bare numbers are seconds)",
        )
    return value


def _check_grid(manifest: Manifest) -> None:
    """Every wavelength at every depth at least once, within a cube's limits; exposures for
    every frame or for none (repeats are weighted by them)."""
    from metalens_cli.io.exr import MAX_DEPTHS, MAX_WAVELENGTHS

    for what, values, limit in (
        ("wavelengths", manifest.wavelengths_m, MAX_WAVELENGTHS),
        ("depths", manifest.depths_m, MAX_DEPTHS),
    ):
        if len(values) > limit:
            raise InputError(
                manifest.source,
                f"names {len(values)} {what}; a PSF cube holds at most {limit}",
                f"at most {limit} {what}",
            )
    given = [f.exposure_s is not None for f in manifest.frames]
    if any(given) and not all(given):
        missing = next(f for f in manifest.frames if f.exposure_s is None)
        raise InputError(
            missing.where, "has no exposure while other frames have one", "an exposure for every frame, or for none"
        )
    present = {(f.depth_m, f.wavelength_m) for f in manifest.frames}
    missing = [(d, w) for d in manifest.depths_m for w in manifest.wavelengths_m if (d, w) not in present]
    if missing:
        d, w = missing[0]
        more = f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""
        raise InputError(
            manifest.source,
            f"has no frame at {w * 1e9:g} nm, depth {'inf' if d == math.inf else f'{d * 1e3:g} mm'}{more}",
            "a frame for every wavelength at every depth (the cube is a full grid)",
        )


def read_frame(entry: FrameEntry) -> tuple[np.ndarray, float | None]:
    """One frame as (H, W, C) float32 values as stored (integer codes, or floats) and its
    full-scale code (65535.0 for 16-bit files, an integer .npy's dtype maximum; None for floats)."""
    return read_frame_file(entry.path, entry.index, entry.where, stack_mean=False)


def read_frame_file(
    path: Path, index: int | None, field: str, stack_mean: bool = True
) -> tuple[np.ndarray, float | None]:
    """A frame file (image or .npy, a stack's frame ``index``) as in :func:`read_frame`; a .npy
    stack without an index is averaged over its frames when ``stack_mean`` (a stack of dark
    frames), else refused."""
    if path.suffix.lower() != ".npy":
        if index is not None:
            raise InputError(field, f"{path.name}#{index}: only .npy stacks have frames", "name#K for a .npy stack")
        pixels, _, full_scale = read_image_codes(path, field)
        return pixels, full_scale
    array = read_npy(path, field, "a (H, W) frame or a (F, H, W) stack of frames")
    if array.ndim not in (2, 3) or min(array.shape) < 1:
        raise InputError(field, f"{path.name} has shape {array.shape}", "a (H, W) frame or a (F, H, W) stack")
    full_scale = float(np.iinfo(array.dtype).max) if array.dtype.kind in "iu" else None
    if array.ndim == 3:
        if index is None and not stack_mean:
            raise InputError(
                field, f"{path.name} is a stack of {array.shape[0]} frames", f"{path.name}#K for its frame K"
            )
        if index is None:
            array = array.mean(axis=0)
        elif index >= array.shape[0]:
            raise InputError(
                field,
                f"{path.name}#{index}: the stack has {array.shape[0]} frames",
                f"an index from 0 to {array.shape[0] - 1}",
            )
        else:
            array = array[index]
    elif index is not None:
        raise InputError(
            field, f"{path.name}#{index}: {path.name} is a single (H, W) frame", "name#K only for a (F, H, W) stack"
        )
    values = array.astype(np.float32)
    if not np.all(np.isfinite(values)) or values.min() < 0:
        raise InputError(
            field, f"{path.name} holds NaN, infinite or negative values", "finite, non-negative frame values"
        )
    return values[:, :, None], full_scale


def frame_shape(entry: FrameEntry) -> tuple[int, int]:
    """(height, width) of a frame from its header alone, for cost estimates; (0, 0) when the
    header cannot tell (the frame reader then says why)."""
    try:
        if entry.path.suffix.lower() == ".npy":
            shape = np.load(entry.path, mmap_mode="r", allow_pickle=False).shape
            return (int(shape[-2]), int(shape[-1])) if len(shape) >= 2 else (0, 0)
        return check_image_size(entry.path, entry.where)
    except (OSError, ValueError):
        return 0, 0
