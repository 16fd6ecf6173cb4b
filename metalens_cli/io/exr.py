"""PSF cubes in OpenEXR files: the "metalens-psf-cube/1" contract of ``docs/formats.md``.

A cube holds D depths × W wavelengths of N × N float32 PSFs, one EXR channel each
(``psf.d{I:02d}.w{J:03d}``), optionally D × 3 channel PSFs (``rgb.d{I:02d}.R|G|B``), and a
string header attribute ``metalens`` with the JSON metadata. Pixel [i, j] of a channel is
array row i (EXR y), column j (EXR x); the optical axis is at the centre of pixel
(N//2, N//2). Files are written ZIP-compressed (lossless), atomically.

A *field cube* (off-axis PSFs) holds F fields of such a cube: field 0 under the channel names
above (so a reader that knows nothing of fields reads field 0), field K ≥ 1 under
``psf.f{K:02d}.d{I:02d}.w{J:03d}`` and ``rgb.f{K:02d}.d{I:02d}.C``; the header adds
``field_angles_rad``, ``field_azimuth_rad``, ``chief_ray_m``, ``window_centre_px`` and
optionally ``field_kept`` (:data:`FIELD_KEYS`). Field cubes are written as EXR only.

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

from metalens_cli import arguments
from metalens_cli.constants import __version__
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
FIELD_KEYS = ("field_angles_rad", "field_azimuth_rad", "chief_ray_m", "window_centre_px")  # a field cube's keys
FIELD_KEPT = "field_kept"  # optional in a field cube: (F, D, W) fractions of the aperture power
MAX_FIELDS = 100
MAX_WINDOW_CENTRE_PX = 2**31 - 1
_EXPECTED = "a PSF cube as described in docs/formats.md"


@dataclass(frozen=True)
class PsfCube:
    """A PSF cube as read from a cube file (EXR, or a format of ``psf_cube_files``).

    The layout is docs/formats.md's; properties give the pixel pitch (m) and, for a field cube,
    the field angles (rad), azimuth (rad), chief rays (m) and window centres (px).

    Attributes:
        psf: (D, W, N, N) float32 PSFs, the axis (or the field's window centre) at pixel
            (N//2, N//2).
        rgb: (D, 3, N, N) float32 channel PSFs, channels R, G, B, or None.
        wavelengths_m: (W,) wavelengths (m).
        depths_m: (D,) source depths (m), ``inf`` for a source at infinity.
        metadata: the whole header JSON (extra keys such as ``na`` included).
        field_psf: a field cube's (F, D, W, N, N) PSFs, of which ``psf`` is field 0; None on axis.
        field_rgb: a field cube's (F, D, 3, N, N) channel PSFs, of which ``rgb`` is field 0, or None;
            None on axis.
    """

    psf: np.ndarray
    rgb: np.ndarray | None
    wavelengths_m: np.ndarray
    depths_m: np.ndarray
    metadata: dict[str, Any]
    field_psf: np.ndarray | None = None
    field_rgb: np.ndarray | None = None

    @property
    def pixel_pitch_m(self) -> float:
        """Sensor pixel pitch in metres."""
        return float(self.metadata["pixel_pitch_m"])

    @property
    def is_field_cube(self) -> bool:
        """Whether the cube holds fields (the field keys), even a single one."""
        return self.field_psf is not None

    @property
    def field_count(self) -> int:
        """F, the number of fields; 1 for an on-axis cube."""
        return 1 if self.field_psf is None else self.field_psf.shape[0]

    @property
    def field_angles_rad(self) -> np.ndarray:
        """(F,) field angles α in radians; [0] for an on-axis cube."""
        return np.array(self.metadata["field_angles_rad"] if self.is_field_cube else [0.0], dtype=float)

    @property
    def field_azimuth_rad(self) -> float:
        """Azimuth ψ of the fields in radians, counter-clockwise from the sensor's +x axis; 0 on axis."""
        return float(self.metadata["field_azimuth_rad"]) if self.is_field_cube else 0.0

    @property
    def chief_ray_m(self) -> np.ndarray:
        """(F, 2) sensor position [x, y] in metres where each field's chief ray lands; [[0, 0]] on axis."""
        return np.array(self.metadata["chief_ray_m"] if self.is_field_cube else [[0.0, 0.0]], dtype=float)

    @property
    def window_centre_px(self) -> np.ndarray:
        """(F, 2) int64 [column, row]: each field's window centre pixel (N//2, N//2) counted in sensor
        pixels from the optical-axis pixel; [[0, 0]] on axis."""
        return np.array(self.metadata["window_centre_px"] if self.is_field_cube else [[0, 0]], dtype=np.int64)

    @property
    def psf_by_field(self) -> np.ndarray:
        """(F, D, W, N, N): ``field_psf``, or ``psf`` as one field."""
        return self.psf[None] if self.field_psf is None else self.field_psf

    @property
    def rgb_by_field(self) -> np.ndarray | None:
        """(F, D, 3, N, N) or None: ``field_rgb``, or ``rgb`` as one field."""
        if self.rgb is None:
            return None
        return self.rgb[None] if self.field_rgb is None else self.field_rgb


def psf_channel_name(depth_index: int, wavelength_index: int, field_index: int = 0) -> str:
    """EXR channel name of the PSF at depth index I and wavelength index J: ``psf.dII.wJJJ`` for
    field 0 (and an on-axis cube), ``psf.fKK.dII.wJJJ`` for field K ≥ 1."""
    return f"psf.{_field_part(field_index)}d{depth_index:02d}.w{wavelength_index:03d}"


def rgb_channel_name(depth_index: int, channel: str, field_index: int = 0) -> str:
    """EXR channel name of colour channel ``channel`` (R, G or B) at depth index I: ``rgb.dII.C``
    for field 0 (and an on-axis cube), ``rgb.fKK.dII.C`` for field K ≥ 1."""
    return f"rgb.{_field_part(field_index)}d{depth_index:02d}.{channel}"


def _field_part(field_index: int) -> str:
    return f"f{field_index:02d}." if field_index else ""


def write_exr_cube(
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

    Arguments as :func:`prepare_cube`, which validates them exactly as ``read_exr_cube`` would,
    so an invalid cube raises InputError and writes nothing. ``metalens_cli.io.psf_cube_files``
    writes the same cube as ``.npz``, ``.mat`` or ``.tif`` (an on-axis one: field cubes are EXR only).
    """
    cube, text = prepare_cube(
        path, psf, wavelengths_m, depths_m, pixel_pitch_m, design, rgb=rgb, normalization=normalization, extra=extra
    )
    _write_exr(Path(path), text, channel_planes(str(path), cube.psf_by_field, cube.rgb_by_field))


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

    A field cube: ``extra`` holds the :data:`FIELD_KEYS` (and optionally ``field_kept``) for F
    fields (numpy arrays are taken as their lists), ``psf`` is (F, D, W, N, N) and ``rgb``
    (F, D, 3, N, N) or None; (D, W, N, N) and (D, 3, N, N) are one field.
    """
    field = arguments.path(path, "path", "a PSF cube file path")
    arguments.array(psf, "psf", ndim=(4, 5), form="PSFs (D, W, N, N) or (F, D, W, N, N)")
    if rgb is not None:
        arguments.array(rgb, "rgb", ndim=(4, 5), form="channel PSFs (D, 3, N, N) or (F, D, 3, N, N)")
    arguments.lengths(wavelengths_m, "wavelengths_m")
    arguments.lengths(depths_m, "depths_m", allow_inf=True)
    arguments.positive(pixel_pitch_m, "pixel_pitch_m")
    clash = sorted(set(extra or {}) & set(WRITTEN_KEYS))
    if clash:
        raise InputError(field, f"extra metadata overrides the keys {clash}", "other key names")
    extra = {
        key: value.tolist()
        if key in (*FIELD_KEYS, FIELD_KEPT) and isinstance(value, np.ndarray | np.generic)
        else value
        for key, value in (extra or {}).items()
    }
    metadata = {
        "format": FORMAT,
        "wavelengths_m": [float(value) for value in np.asarray(wavelengths_m, dtype=float).ravel()],
        "depths_m": [
            None if value == math.inf else float(value) for value in np.asarray(depths_m, dtype=float).ravel()
        ],
        "pixel_pitch_m": float(pixel_pitch_m),
        "normalization": normalization,
        "design": design,
        "version": __version__,
        **extra,
    }
    psf = np.asarray(psf, dtype=np.float32)
    rgb = None if rgb is None else np.asarray(rgb, dtype=np.float32)
    depth_count, wavelength_count = check_metadata(field, metadata)
    fields = field_count(metadata)
    if fields is not None and psf.ndim == 4:  # one field
        psf, rgb = psf[None], None if rgb is None else rgb[None]
    counts = (depth_count, wavelength_count) if fields is None else (fields, depth_count, wavelength_count)
    if psf.shape[:-2] != counts:
        expected = (
            "psf (D, W, N, N), or (F, D, W, N, N) with field_angles_rad and the other field keys in extra"
            if fields is None
            else "psf (F, D, W, N, N), or (D, W, N, N) for one field"
        )
        cube = _cube_words(depth_count, wavelength_count, fields)
        raise InputError(field, f"psf of shape {psf.shape} for {cube}", expected)
    _check_cube(field, metadata, channel_planes(field, psf, rgb))
    try:
        text = json.dumps(metadata, allow_nan=False)
    except (TypeError, ValueError) as error:
        raise InputError(field, f"metadata is not strict JSON: {error}", "JSON-able values, no NaN or inf") from error
    return _cube(metadata, psf, rgb), text


def channel_planes(field: str, psf: np.ndarray, rgb: np.ndarray | None) -> dict[str, np.ndarray]:
    """Channel name -> contiguous (N, N) plane (views of contiguous arrays), from psf (D, W, N, N)
    and rgb (D, 3, N, N) or None, or a field cube's psf (F, D, W, N, N) and rgb (F, D, 3, N, N) or
    None: the EXR channels, and the names under which every format's PSFs are checked."""
    fields_psf = psf if psf.ndim == 5 else psf[None]
    channels = {
        psf_channel_name(i, j, k): fields_psf[k, i, j]
        for k in range(fields_psf.shape[0])
        for i in range(fields_psf.shape[1])
        for j in range(fields_psf.shape[2])
    }
    if rgb is not None:
        if rgb.ndim != psf.ndim or rgb.shape[:-3] != psf.shape[:-3] or rgb.shape[-3] != len(RGB_CHANNELS):
            raise InputError(
                field,
                f"rgb of shape {rgb.shape} beside psf {psf.shape}",
                "rgb (D, 3, N, N), or (F, D, 3, N, N) beside psf (F, D, W, N, N)",
            )
        fields_rgb = rgb if rgb.ndim == 5 else rgb[None]
        channels.update(
            {
                rgb_channel_name(i, c, k): fields_rgb[k, i, m]
                for k in range(fields_rgb.shape[0])
                for i in range(fields_rgb.shape[1])
                for m, c in enumerate(RGB_CHANNELS)
            }
        )
    return {name: np.ascontiguousarray(plane) for name, plane in channels.items()}


def _write_exr(path: Path, header_text: str, channels: dict[str, np.ndarray]) -> None:
    """Single-part scanline EXR, ZIP compression, through a temporary file."""
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage, HEADER_ATTRIBUTE: header_text}
    with atomic_write(path) as temporary:
        OpenEXR.File(header, channels).write(str(temporary))


def read_exr_cube(path: str | os.PathLike[str]) -> PsfCube:
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
    _check_channel_names(field, channels, depth_count, wavelength_count, field_count(metadata))
    _check_pixels(field, channels)


def check_metadata(field: str, metadata: dict[str, Any]) -> tuple[int, int]:
    """Refuse metadata that breaks the contract (a field cube's keys included); return (D, W),
    the counts of depths and wavelengths. ``design`` and ``version`` are optional (a measured cube
    from another program may lack them)."""
    missing = [key for key in REQUIRED_KEYS if key not in metadata]
    if missing:
        raise InputError(field, f"metadata JSON lacks {', '.join(missing)}", _EXPECTED)
    wavelengths = _positive_list(field, metadata, "wavelengths_m", allow_null=False, limit=MAX_WAVELENGTHS)
    depths = _positive_list(field, metadata, "depths_m", allow_null=True, limit=MAX_DEPTHS)
    _check_scalars(field, metadata)
    _check_fields(field, metadata, len(depths), len(wavelengths))
    return len(depths), len(wavelengths)


def field_count(metadata: dict[str, Any]) -> int | None:
    """F of checked metadata (:func:`check_metadata`) of a field cube; None for an on-axis cube."""
    return len(metadata["field_angles_rad"]) if "field_angles_rad" in metadata else None


def _check_fields(field: str, metadata: dict[str, Any], depth_count: int, wavelength_count: int) -> None:
    """A field cube's keys (none, or all of FIELD_KEYS): angles in [0, π/2), distinct; a finite
    azimuth; F chief rays [x, y] (finite metres) and F window centres [column, row] (integers);
    field_kept, if present, F × D × W numbers ≥ 0."""
    present = [key for key in (*FIELD_KEYS, FIELD_KEPT) if key in metadata]
    if not present:
        return
    missing = [key for key in FIELD_KEYS if key not in metadata]
    if missing:
        raise InputError(
            field, f"metadata JSON has {present[0]} but lacks {', '.join(missing)}", f"all of {', '.join(FIELD_KEYS)}"
        )
    angles = metadata["field_angles_rad"]
    if not isinstance(angles, list) or not 1 <= len(angles) <= MAX_FIELDS:
        raise InputError(field, f"field_angles_rad is not a list of 1 to {MAX_FIELDS} numbers", "a JSON list")
    for value in angles:
        if not _is_number(value) or not 0 <= value < math.pi / 2:
            raise InputError(field, f"field_angles_rad holds {value!r}", "angles in radians, ≥ 0 and < π/2")
    repeated = next((value for k, value in enumerate(angles) if value in angles[:k]), None)
    if repeated is not None:
        raise InputError(field, f"field_angles_rad holds {repeated!r} twice", "distinct values")
    azimuth = metadata["field_azimuth_rad"]
    if not _is_finite(azimuth):
        raise InputError(field, f"field_azimuth_rad is {azimuth!r}", "a finite number of radians")
    count = len(angles)
    _check_pairs(field, metadata, "chief_ray_m", count, "[x, y] in finite metres")
    _check_pairs(field, metadata, "window_centre_px", count, "[column, row] of integers")
    if FIELD_KEPT in metadata:
        _check_kept(field, metadata[FIELD_KEPT], (count, depth_count, wavelength_count))


def _check_pairs(field: str, metadata: dict[str, Any], key: str, count: int, form: str) -> None:
    """``key`` a list of ``count`` pairs: finite numbers, or (window_centre_px) integers below 2³¹."""
    values = metadata[key]
    if not isinstance(values, list) or len(values) != count:
        size = len(values) if isinstance(values, list) else "not a list"
        raise InputError(field, f"{key} holds {size} entries for {count} field angles", f"{count} pairs {form}")
    integer = key == "window_centre_px"
    for pair in values:
        good = isinstance(pair, list) and len(pair) == 2 and all(_is_finite(v) for v in pair)
        if good and integer:
            good = all(isinstance(v, int) and abs(v) <= MAX_WINDOW_CENTRE_PX for v in pair)
        if not good:
            raise InputError(field, f"{key} holds {pair!r}", f"{count} pairs {form}")


def _check_kept(field: str, values: Any, shape: tuple[int, int, int]) -> None:
    """``field_kept``: nested lists of ``shape`` (F, D, W) holding finite numbers ≥ 0."""
    form = f"{shape[0]} × {shape[1]} × {shape[2]} numbers ≥ 0 (fields × depths × wavelengths)"
    nested = (
        isinstance(values, list)
        and len(values) == shape[0]
        and all(
            isinstance(rows, list)
            and len(rows) == shape[1]
            and all(isinstance(row, list) and len(row) == shape[2] for row in rows)
            for rows in values
        )
    )
    if not nested:
        raise InputError(field, "field_kept is not F × D × W nested lists", form)
    for value in (value for rows in values for row in rows for value in row):
        if not _is_finite(value) or value < 0:
            raise InputError(field, f"field_kept holds {value!r}", form)


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


def _is_finite(value: Any) -> bool:
    """True for finite JSON numbers that a float holds (an integer of 400 digits is not one)."""
    return _is_number(value) and -1e300 < value < 1e300


_CHANNEL = re.compile(r"(psf|rgb)\.(f\d{2}\.)?d\d{2}\.(w\d{3}|[RGB])")
_FIELD_CHANNEL = re.compile(r"(psf|rgb)\.f\d{2}\.")


def _check_channel_names(
    field: str, channels: dict[str, np.ndarray], depth_count: int, wavelength_count: int, fields: int | None = None
) -> None:
    """Exactly the D × W psf channels of each field (one for an on-axis cube, ``fields`` None), and
    either no rgb channels or all D × 3 of each field."""
    indices = range(fields or 1)
    expected = {psf_channel_name(i, j, k) for k in indices for i in range(depth_count) for j in range(wavelength_count)}
    rgb = {rgb_channel_name(i, c, k) for k in indices for i in range(depth_count) for c in RGB_CHANNELS}
    present = set(channels)
    if present & rgb:
        expected |= rgb
    missing, extra = sorted(expected - present), sorted(present - expected)
    if missing:
        cube = _cube_words(depth_count, wavelength_count, fields)
        raise InputError(field, f"missing channels {_listing(missing)} for {cube}", _EXPECTED)
    if extra:
        if not all(_CHANNEL.fullmatch(name) for name in extra):
            raise InputError(field, f"foreign channels {_listing(extra)}", _EXPECTED)
        if fields is not None:
            where = f" for {_cube_words(depth_count, wavelength_count, fields)}"
        elif any(_FIELD_CHANNEL.match(name) for name in extra):
            where = " (field channels need field_angles_rad and the other field keys)"
        else:
            where = ""
        raise InputError(field, f"unexpected channels {_listing(extra)}{where}", _EXPECTED)


def _cube_words(depth_count: int, wavelength_count: int, fields: int | None) -> str:
    """ "2 depths × 3 wavelengths", with "3 fields × " before it for a field cube."""
    return ("" if fields is None else f"{fields} fields × ") + f"{depth_count} depths × {wavelength_count} wavelengths"


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
    indices = range(field_count(metadata) or 1)
    psf = np.stack(
        [
            [[channels[psf_channel_name(i, j, k)] for j in range(wavelengths.size)] for i in range(depths.size)]
            for k in indices
        ]
    )
    rgb = None
    if rgb_channel_name(0, "R") in channels:
        rgb = np.stack(
            [[[channels[rgb_channel_name(i, c, k)] for c in RGB_CHANNELS] for i in range(depths.size)] for k in indices]
        )
    return _cube(metadata, psf, rgb)


def _cube(metadata: dict[str, Any], psf: np.ndarray, rgb: np.ndarray | None) -> PsfCube:
    """The PsfCube of validated ``metadata`` and psf (F, D, W, N, N) or, on axis, (D, W, N, N);
    rgb likewise (F, D, 3, N, N), (D, 3, N, N) or None."""
    if psf.ndim == 4:
        return PsfCube(psf, rgb, *_axes(metadata), metadata)
    if field_count(metadata) is None:  # an on-axis cube stacked as one field
        return PsfCube(psf[0], None if rgb is None else rgb[0], *_axes(metadata), metadata)
    return PsfCube(psf[0], None if rgb is None else rgb[0], *_axes(metadata), metadata, psf, rgb)
