"""PSF cubes in OpenEXR files: the "metalens-psf-cube/1" contract of ``docs/formats.md``.

A cube holds D depths × W wavelengths of N × N float32 PSFs, one EXR channel each
(``psf.d{I:02d}.w{J:03d}``), optionally D × 3 channel PSFs (``rgb.d{I:02d}.R|G|B``), and a
string header attribute ``metalens`` with the JSON metadata. Pixel [i, j] of a channel is
array row i (EXR y), column j (EXR x); the optical axis is at the centre of pixel
(N//2, N//2). Files are written ZIP-compressed (lossless), atomically.

The contract's metadata and checks (:func:`prepare_cube`, :func:`parse_metadata`,
:func:`cube_from_channels`) are shared by the ``.npz``, ``.mat`` and ``.tif`` cubes of
``metalens_cli.io.psf_cube_files``, which also picks the format by suffix.
"""

from __future__ import annotations

import json
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

import metalens_cli
from metalens_cli.errors import InputError
from metalens_cli.io.atomic import atomic_write
from metalens_cli.io.input_files import open_exr

FORMAT = "metalens-psf-cube/1"
HEADER_ATTRIBUTE = "metalens"
DEFAULT_NORMALIZATION = "fraction-of-aperture-power"
REQUIRED_KEYS = ("format", "wavelengths_m", "depths_m", "pixel_pitch_m", "normalization")  # what a reader needs
WRITTEN_KEYS = (*REQUIRED_KEYS, "design", "version")  # what this writer always adds
RGB_CHANNELS = ("R", "G", "B")
LOSSLESS_COMPRESSIONS = ("NO_COMPRESSION", "RLE_COMPRESSION", "ZIPS_COMPRESSION", "ZIP_COMPRESSION", "PIZ_COMPRESSION")
MAX_DEPTHS = 100
MAX_WAVELENGTHS = 1000
_EXPECTED = "a PSF cube as described in docs/formats.md"


@dataclass(frozen=True)
class PsfCube:
    """A PSF cube as read from a cube file (EXR, or a format of ``psf_cube_files``).

    ``psf``: (D, W, N, N) float32. ``rgb``: (D, 3, N, N) float32, channels R, G, B, or None.
    ``wavelengths_m``: (W,) metres. ``depths_m``: (D,) metres, ``inf`` for a source at
    infinity. ``metadata``: the whole header JSON (extra keys such as ``na`` included).
    """

    psf: np.ndarray
    rgb: np.ndarray | None
    wavelengths_m: np.ndarray
    depths_m: np.ndarray
    metadata: dict[str, Any]

    @property
    def pixel_pitch_m(self) -> float:
        """Sensor pixel pitch in metres."""
        return float(self.metadata["pixel_pitch_m"])


def psf_channel_name(depth_index: int, wavelength_index: int) -> str:
    """EXR channel name of the PSF at depth index I and wavelength index J: ``psf.dII.wJJJ``."""
    return f"psf.d{depth_index:02d}.w{wavelength_index:03d}"


def rgb_channel_name(depth_index: int, channel: str) -> str:
    """EXR channel name of colour channel ``channel`` (R, G or B) at depth index I: ``rgb.dII.C``."""
    return f"rgb.d{depth_index:02d}.{channel}"


def write_psf_cube(
    path: str | os.PathLike[str],
    psf: np.ndarray,
    wavelengths_m: np.ndarray,
    depths_m: np.ndarray,
    pixel_pitch_m: float,
    design: str | dict[str, Any],
    *,
    rgb: np.ndarray | None = None,
    normalization: str = DEFAULT_NORMALIZATION,
    extra: dict[str, Any] | None = None,
) -> None:
    """Write a PSF cube to ``path`` as EXR, atomically (temporary file beside it, then ``os.replace``).

    Arguments as :func:`prepare_cube`, which validates them exactly as ``read_psf_cube`` would,
    so an invalid cube raises InputError and writes nothing. ``metalens_cli.io.psf_cube_files``
    writes the same cube as ``.npz``, ``.mat`` or ``.tif``.
    """
    cube, text = prepare_cube(
        path, psf, wavelengths_m, depths_m, pixel_pitch_m, design, rgb=rgb, normalization=normalization, extra=extra
    )
    _write_exr(Path(path), text, channel_planes(str(path), cube.psf, cube.rgb))


def prepare_cube(
    path: str | os.PathLike[str],
    psf: np.ndarray,
    wavelengths_m: np.ndarray,
    depths_m: np.ndarray,
    pixel_pitch_m: float,
    design: str | dict[str, Any],
    *,
    rgb: np.ndarray | None = None,
    normalization: str = DEFAULT_NORMALIZATION,
    extra: dict[str, Any] | None = None,
) -> tuple[PsfCube, str]:
    """The validated cube every format's writer stores, and its metadata as strict JSON text.

    ``psf`` (D, W, N, N) and ``rgb`` (D, 3, N, N) or None are stored as float32 (exactly, if
    already float32); ``depths_m`` may hold ``inf`` (written as JSON null). ``design`` is a
    design spec string or a JSON-able object; ``extra`` adds JSON keys (e.g. ``na``, ``f_m``,
    ``aperture_m``, ``accuracy``) and may not override the keys the writer sets. Whatever a
    reader would refuse is an InputError naming ``path``.
    """
    field = str(path)
    clash = sorted(set(extra or {}) & set(WRITTEN_KEYS))
    if clash:
        raise InputError(field, f"extra metadata overrides the keys {clash}", "other key names")
    metadata = {
        "format": FORMAT,
        "wavelengths_m": [float(value) for value in np.asarray(wavelengths_m, dtype=float).ravel()],
        "depths_m": [
            None if value == math.inf else float(value) for value in np.asarray(depths_m, dtype=float).ravel()
        ],
        "pixel_pitch_m": float(pixel_pitch_m),
        "normalization": normalization,
        "design": design,
        "version": metalens_cli.__version__,
        **(extra or {}),
    }
    psf = np.asarray(psf, dtype=np.float32)
    rgb = None if rgb is None else np.asarray(rgb, dtype=np.float32)
    counts = (len(metadata["depths_m"]), len(metadata["wavelengths_m"]))
    if psf.ndim != 4 or psf.shape[:2] != counts:
        raise InputError(
            field, f"psf of shape {psf.shape} for {counts[0]} depths × {counts[1]} wavelengths", "psf (D, W, N, N)"
        )
    _check_cube(field, metadata, channel_planes(field, psf, rgb))
    try:
        text = json.dumps(metadata, allow_nan=False)
    except (TypeError, ValueError) as error:
        raise InputError(field, f"metadata is not strict JSON: {error}", "JSON-able values, no NaN or inf") from error
    return PsfCube(psf, rgb, *_axes(metadata), metadata), text


def channel_planes(field: str, psf: np.ndarray, rgb: np.ndarray | None) -> dict[str, np.ndarray]:
    """Channel name -> contiguous (N, N) plane (views of contiguous arrays), from psf (D, W, N, N)
    and rgb (D, 3, N, N) or None: the EXR channels, and the names under which every format's
    PSFs are checked."""
    channels = {psf_channel_name(i, j): psf[i, j] for i in range(psf.shape[0]) for j in range(psf.shape[1])}
    if rgb is not None:
        if rgb.ndim != 4 or rgb.shape[:2] != (psf.shape[0], 3):
            raise InputError(field, f"rgb of shape {rgb.shape} beside psf {psf.shape}", "rgb (D, 3, N, N)")
        channels.update(
            {rgb_channel_name(i, c): rgb[i, k] for i in range(rgb.shape[0]) for k, c in enumerate(RGB_CHANNELS)}
        )
    return {name: np.ascontiguousarray(plane) for name, plane in channels.items()}


def _write_exr(path: Path, header_text: str, channels: dict[str, np.ndarray]) -> None:
    """Single-part scanline EXR, ZIP compression, through a temporary file."""
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage, HEADER_ATTRIBUTE: header_text}
    with atomic_write(path) as temporary:
        OpenEXR.File(header, channels).write(str(temporary))


def read_psf_cube(path: str | os.PathLike[str]) -> PsfCube:
    """Read and validate a PSF cube; InputError with a one-line reason if it breaks the contract."""
    field = str(path)
    exr = open_exr(Path(path), field, _EXPECTED)
    header = exr.header()
    compression = getattr(header.get("compression"), "name", str(header.get("compression")))
    if compression not in LOSSLESS_COMPRESSIONS:
        raise InputError(
            field, f"compression {compression} is lossy or not supported", ", ".join(LOSSLESS_COMPRESSIONS)
        )
    metadata = parse_metadata(field, header.get(HEADER_ATTRIBUTE), f"'{HEADER_ATTRIBUTE}' header attribute")
    channels = {name: channel.pixels for name, channel in exr.channels().items()}
    return cube_from_channels(field, metadata, channels)


def parse_metadata(field: str, text: Any, where: str) -> dict[str, Any]:
    """The JSON object in ``text``, read from ``where`` (e.g. "'metalens' header attribute"; None:
    the file has none), with its format string checked."""
    if text is None:
        raise InputError(field, f"no {where} (not a metalens PSF cube)", _EXPECTED)
    if not isinstance(text, str):
        raise InputError(field, f"{where} is not a string", "a string holding JSON")
    try:
        metadata = json.loads(text)
    except json.JSONDecodeError as error:
        raise InputError(field, f"{where} is not valid JSON ({error.msg})", "a JSON object") from None
    except RecursionError:
        raise InputError(field, f"{where} nests too deeply", "a flat JSON object") from None
    if not isinstance(metadata, dict):
        raise InputError(field, f"{where} is not a JSON object", "a JSON object")
    if metadata.get("format") != FORMAT:
        raise InputError(field, f"format is {metadata.get('format')!r}", repr(FORMAT))
    return metadata


def cube_from_channels(field: str, metadata: dict[str, Any], channels: dict[str, np.ndarray]) -> PsfCube:
    """The cube of parsed ``metadata`` and planes named as the EXR channels (:func:`channel_planes`),
    after every check of the contract: the one validation all formats' readers share."""
    _check_cube(field, metadata, channels)
    return _assemble(metadata, channels)


def _check_cube(field: str, metadata: dict[str, Any], channels: dict[str, np.ndarray]) -> None:
    """Refuse metadata or channels that break the contract (shared by writing and reading)."""
    depth_count, wavelength_count = check_metadata(field, metadata)
    _check_channel_names(field, channels, depth_count, wavelength_count)
    _check_pixels(field, channels)


def check_metadata(field: str, metadata: dict[str, Any]) -> tuple[int, int]:
    """Refuse metadata that breaks the contract; return (D, W), the counts of depths and
    wavelengths. ``design`` and ``version`` are optional (a measured cube from another program
    may lack them)."""
    missing = [key for key in REQUIRED_KEYS if key not in metadata]
    if missing:
        raise InputError(field, f"metadata JSON lacks {', '.join(missing)}", _EXPECTED)
    wavelengths = _positive_list(field, metadata, "wavelengths_m", allow_null=False, limit=MAX_WAVELENGTHS)
    depths = _positive_list(field, metadata, "depths_m", allow_null=True, limit=MAX_DEPTHS)
    _check_scalars(field, metadata)
    return len(depths), len(wavelengths)


def _positive_list(
    field: str, metadata: dict[str, Any], key: str, *, allow_null: bool, limit: int
) -> list[float | None]:
    """A non-empty JSON list of positive finite numbers (and nulls where allowed)."""
    values = metadata[key]
    if not isinstance(values, list) or not 1 <= len(values) <= limit:
        raise InputError(field, f"{key} is not a list of 1 to {limit} numbers", "a JSON list")
    for value in values:
        if value is None and allow_null:
            continue
        if not _is_number(value) or not 0 < value < math.inf:
            raise InputError(
                field, f"{key} holds {value!r}", "positive finite metres" + (" or null" if allow_null else "")
            )
    repeated = next((value for k, value in enumerate(values) if value in values[:k]), False)
    if repeated is not False:
        raise InputError(field, f"{key} holds {'null' if repeated is None else repeated!r} twice", "distinct values")
    return values


def _check_scalars(field: str, metadata: dict[str, Any]) -> None:
    """pixel_pitch_m a positive number; normalization (and version, if present) non-empty strings;
    design (if present) a string or object."""
    pitch = metadata["pixel_pitch_m"]
    if not _is_number(pitch) or not 0 < pitch < math.inf:
        raise InputError(field, f"pixel_pitch_m is {pitch!r}", "a positive number of metres")
    for key in ("normalization", "version"):
        if key in metadata and (not isinstance(metadata[key], str) or not metadata[key]):
            raise InputError(field, f"{key} is {metadata[key]!r}", "a non-empty string")
    if "design" in metadata and not isinstance(metadata["design"], str | dict):
        raise InputError(field, f"design is {metadata['design']!r}", "a string or a JSON object")


def _is_number(value: Any) -> bool:
    """True for JSON numbers (int or float, not bool)."""
    return isinstance(value, int | float) and not isinstance(value, bool)


_CHANNEL = re.compile(r"psf\.d\d{2}\.w\d{3}|rgb\.d\d{2}\.[RGB]")


def _check_channel_names(field: str, channels: dict[str, np.ndarray], depth_count: int, wavelength_count: int) -> None:
    """Exactly the D × W psf channels, and either no rgb channels or all D × 3."""
    expected = {psf_channel_name(i, j) for i in range(depth_count) for j in range(wavelength_count)}
    rgb = {rgb_channel_name(i, c) for i in range(depth_count) for c in RGB_CHANNELS}
    present = set(channels)
    if present & rgb:
        expected |= rgb
    missing, extra = sorted(expected - present), sorted(present - expected)
    if missing:
        cube = f"{depth_count} depths × {wavelength_count} wavelengths"
        raise InputError(field, f"missing channels {_listing(missing)} for {cube}", _EXPECTED)
    if extra:
        reason = "unexpected channels" if all(_CHANNEL.fullmatch(name) for name in extra) else "foreign channels"
        raise InputError(field, f"{reason} {_listing(extra)}", _EXPECTED)


def _listing(names: list[str]) -> str:
    """At most three names, then a count."""
    shown = ", ".join(names[:3])
    return shown if len(names) <= 3 else f"{shown} (and {len(names) - 3} more)"


def _check_pixels(field: str, channels: dict[str, np.ndarray]) -> None:
    """Every channel float32, N × N with the same N, and finite."""
    shapes = {plane.shape for plane in channels.values()}
    if len(shapes) != 1:
        raise InputError(field, f"channels differ in shape: {sorted(shapes)}", "all channels N × N")
    shape = shapes.pop()
    if len(shape) != 2 or shape[0] != shape[1] or shape[0] < 1:
        raise InputError(field, f"channels of shape {shape}", "square N × N pixels")
    for name, plane in channels.items():
        if plane.dtype != np.float32:
            raise InputError(field, f"channel {name} is {plane.dtype}", "float32 (EXR FLOAT) channels")
        if not np.all(np.isfinite(plane)):
            raise InputError(field, f"channel {name} holds NaN or infinity", "finite values")


def _axes(metadata: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """(wavelengths_m, depths_m) as float64 arrays from validated metadata, null depths as ``inf``."""
    wavelengths = np.array(metadata["wavelengths_m"], dtype=float)
    depths = np.array([math.inf if depth is None else depth for depth in metadata["depths_m"]], dtype=float)
    return wavelengths, depths


def _assemble(metadata: dict[str, Any], channels: dict[str, np.ndarray]) -> PsfCube:
    """Stack the validated channels into arrays."""
    wavelengths, depths = _axes(metadata)
    psf = np.stack(
        [np.stack([channels[psf_channel_name(i, j)] for j in range(wavelengths.size)]) for i in range(depths.size)]
    )
    rgb = None
    if rgb_channel_name(0, "R") in channels:
        rgb = np.stack([np.stack([channels[rgb_channel_name(i, c)] for c in RGB_CHANNELS]) for i in range(depths.size)])
    return PsfCube(psf, rgb, wavelengths, depths, metadata)
