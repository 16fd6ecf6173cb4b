"""PSF cube files by suffix: ``.exr`` (``metalens_cli.io.exr``), ``.npz``, ``.mat`` and ``.tif``/``.tiff``.

Every format holds the same cube of the "metalens-psf-cube/1" contract (docs/formats.md): D
depths × W wavelengths of N × N float32 PSFs, optionally D × 3 colour-channel PSFs, and the
metadata JSON that EXR keeps in its ``metalens`` header attribute. Writers validate the cube
(:func:`metalens_cli.io.exr.prepare_cube`) and write atomically; readers check the file's
structure before loading its data, then run the one validation of the contract
(:func:`metalens_cli.io.exr.cube_from_channels`), so every format refuses what EXR refuses,
with a one-line :class:`InputError`. Values, axes and metadata round-trip exactly.

- ``.npz`` (``numpy.savez_compressed``) and ``.mat`` (MATLAB v5, ``scipy.io.savemat``): arrays
  ``psf`` (D, W, N, N) float32, ``rgb`` (D, 3, N, N) float32 (only with colour channels),
  ``wavelengths_m`` (W,) and ``depths_m`` (D,) float64 (``inf``: a source at infinity),
  ``pixel_pitch_m`` float64 and ``metadata`` (the JSON text), which the arrays must agree with.
  ``.npz`` members are read without pickle.
- ``.tif``/``.tiff``: one uncompressed float32 page per PSF, page I·W + J for depth I and
  wavelength J, then (with colour channels) page D·W + 3·I + C for channel C of R, G, B; the
  JSON in the first page's ImageDescription; each page's PageName is its EXR channel name.

A field cube (off-axis fields, ``docs/formats.md``) is written as ``.exr`` only: the other
writers refuse it. Their readers take any cube the contract allows in their layout, which holds
one field's channel names, so a field cube in them is refused for its missing field channels.
"""

from __future__ import annotations

import logging
import math
import os
import warnings
import zipfile
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from metalens_cli import arguments
from metalens_cli.constants import __version__
from metalens_cli.errors import InputError
from metalens_cli.io.atomic import atomic_write, check_suffix
from metalens_cli.io.exr import (
    DEFAULT_NORMALIZATION,
    RGB_CHANNELS,
    PsfCube,
    channel_planes,
    check_metadata,
    cube_from_channels,
    parse_metadata,
    prepare_cube,
    psf_channel_name,
    read_exr_cube,
    rgb_channel_name,
    write_exr_cube,
)
from metalens_cli.io.input_files import MAX_ARRAY_BYTES, regular_file

CUBE_SUFFIXES = (".exr", ".npz", ".mat", ".tif", ".tiff")
FORMAT_NAMES = {".exr": "OpenEXR", ".npz": ".npz", ".mat": "MATLAB v5 .mat", ".tif": "TIFF", ".tiff": "TIFF"}
AXES = ("wavelengths_m", "depths_m", "pixel_pitch_m")
MAT_MAX_VARIABLE_BYTES = 2**31 - 1  # MATLAB's limit for one variable in a v5 (or v7) file
TIFF_MAX_BYTES = 2**32 - 2**25  # above this (with room for tags), a BigTIFF file (as tifffile.imwrite)
TIFF_PAGE_NAME = 285  # the PageName tag
TIFF_LOSSLESS = ("NONE", "LZW", "ADOBE_DEFLATE", "DEFLATE", "PACKBITS", "ZSTD", "LZMA")
MAT_ITEM_BYTES = {"double": 8, "single": 4, "int64": 8, "uint64": 8, "int32": 4, "uint32": 4, "int16": 2}
MAT_ITEM_BYTES |= {"uint16": 2, "int8": 1, "uint8": 1, "logical": 1, "char": 4}  # char: loaded as UTF-32
_EXPECTED = "a PSF cube as described in docs/formats.md"


def cube_suffix(path: str | os.PathLike[str], field: str) -> str:
    """The lower-case suffix of a cube file, or an InputError naming ``field`` and the accepted suffixes."""
    return check_suffix(path, field, CUBE_SUFFIXES, "a PSF cube file")


def check_cube_size(
    path: str | os.PathLike[str],
    field: str,
    depth_count: int,
    wavelength_count: int,
    pixels: int,
    *,
    field_cube: bool = False,
):
    """Refuse, before any work, a cube that ``path``'s format cannot hold: a field cube
    (``field_cube``) in any format but ``.exr``, a ``.mat`` variable over MATLAB's 2 GiB (the psf
    array, or the rgb one when there are fewer than 3 wavelengths)."""
    suffix = cube_suffix(path, field)
    if field_cube and suffix != ".exr":
        raise _field_cube_refused(field, suffix)
    if suffix != ".mat":
        return
    largest = depth_count * max(wavelength_count, 3) * pixels * pixels * 4
    if largest > MAT_MAX_VARIABLE_BYTES:
        raise InputError(
            field,
            f"a .mat variable holds at most 2 GiB; this cube's PSFs take {largest / 2**30:.3g} GiB",
            "fewer --pixels, --wavelengths or --depths, or a .npz, .exr or .tif file",
        )


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
    """Write a PSF cube in the format of ``path``'s suffix (:data:`CUBE_SUFFIXES`), atomically.

    Arguments as :func:`metalens_cli.io.exr.prepare_cube`.

    Args:
        path: the file to write: .exr, .npz, .mat, .tif or .tiff.
        psf: PSFs (D, W, N, N), or a field cube's (F, D, W, N, N); stored as float32.
        wavelengths_m: (W,) wavelengths (m).
        depths_m: (D,) source depths (m); ``inf`` allowed (written as JSON null).
        pixel_pitch_m: sensor pixel pitch (m).
        design: a design spec string or a JSON-able object.
        rgb: channel PSFs (D, 3, N, N) (or (F, D, 3, N, N)), channels R, G, B, or None.
        normalization: what the PSF values are, written to the header.
        extra: more header keys (e.g. ``na``, ``f_m``, ``aperture_m``; a field cube's field keys),
            which may not override the keys the writer sets.

    Raises:
        InputError: naming ``path``, for an invalid cube, a suffix of no format, or a field cube in
            a format but ``.exr``; nothing is written.
    """
    suffix = cube_suffix(arguments.path(path, "path", "a PSF cube file path"), str(path))
    values = (psf, wavelengths_m, depths_m, pixel_pitch_m, design)
    if suffix == ".exr":
        write_exr_cube(path, *values, rgb=rgb, normalization=normalization, extra=extra)
        return
    cube, text = prepare_cube(path, *values, rgb=rgb, normalization=normalization, extra=extra)
    if cube.is_field_cube:
        raise _field_cube_refused(str(path), suffix)
    _WRITERS[suffix](Path(path), cube, text)


def _field_cube_refused(field: str, suffix: str) -> InputError:
    return InputError(field, f"a field cube is written as .exr, not {suffix}", "a file ending in .exr for a field cube")


def read_psf_cube(path: str | os.PathLike[str]) -> PsfCube:
    """Read and validate a PSF cube in the format of its suffix (:data:`CUBE_SUFFIXES`).

    Args:
        path: the cube file: .exr, .npz, .mat, .tif or .tiff.

    Returns:
        The :class:`~metalens_cli.io.exr.PsfCube` (PSFs float32, lengths in m).

    Raises:
        InputError: a file that breaks the contract (docs/formats.md), cannot be parsed or has
            another suffix, with a one-line reason naming ``path``.
    """
    field = arguments.path(path, "path", "a PSF cube file (.exr, .npz, .mat, .tif)")
    suffix = cube_suffix(path, field)
    if suffix == ".exr":
        return read_exr_cube(path)
    path = regular_file(path, field, _EXPECTED)
    try:
        with _libraries_quiet():
            return _READERS[suffix](path, field)
    except (InputError, MemoryError):
        raise
    except Exception as exc:  # the parsers' own errors on a corrupt or foreign file
        if suffix == ".mat" and isinstance(exc, NotImplementedError):  # scipy's answer to a v7.3 file
            raise InputError(field, "a MATLAB v7.3 (HDF5) file", "a MATLAB v5 or v7 file (MATLAB: save -v7)") from None
        raise InputError(field, f"not a readable {FORMAT_NAMES[suffix]} file ({_reason(exc)})", _EXPECTED) from None


def _reason(exc: BaseException) -> str:
    """A parser's error in one short line; its type where the message says little (a KeyError's 0)."""
    text = str(exc).strip().splitlines()[0][:160] if str(exc).strip() else ""
    return text if len(text) >= 8 else type(exc).__name__ + (f": {text}" if text else "")


@contextmanager
def _libraries_quiet():
    """No warnings from scipy or numpy, no log lines from tifffile, while a file is parsed: the
    verdict is the one-line error."""
    logger = logging.getLogger("tifffile")
    disabled = logger.disabled
    logger.disabled = True
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    finally:
        logger.disabled = disabled


# ---------------------------------------------------------------------------- .npz and .mat


def _arrays(cube: PsfCube, text: str) -> dict[str, Any]:
    """The named arrays of a ``.npz`` or ``.mat`` cube (module docstring)."""
    arrays = {"psf": cube.psf} | ({} if cube.rgb is None else {"rgb": cube.rgb})
    return arrays | {
        "wavelengths_m": cube.wavelengths_m,
        "depths_m": cube.depths_m,
        "pixel_pitch_m": np.float64(cube.pixel_pitch_m),
        "metadata": np.str_(text),
    }


def _write_npz(path: Path, cube: PsfCube, text: str) -> None:
    with atomic_write(path) as temporary, open(temporary, "wb") as handle:
        np.savez_compressed(handle, **_arrays(cube, text))


def _write_mat(path: Path, cube: PsfCube, text: str) -> None:
    import scipy.io

    depth_count, wavelength_count, pixels = cube.psf.shape[0], cube.psf.shape[1], cube.psf.shape[-1]
    check_cube_size(path, str(path), depth_count, wavelength_count, pixels)
    with atomic_write(path) as temporary:
        scipy.io.savemat(temporary, _arrays(cube, text), format="5", do_compression=False, oned_as="column")


def _cube_from_arrays(field: str, where: str, arrays: dict[str, Any]) -> PsfCube:
    """Validate named arrays (``where``: "member" or "variable") as a cube; the axes arrays must
    equal the metadata's values (null depths as inf)."""
    metadata = parse_metadata(field, arrays.get("metadata"), f"{where} 'metadata'")
    depth_count, wavelength_count = check_metadata(field, metadata)
    missing = [key for key in ("psf", *AXES) if arrays.get(key) is None]
    if missing:
        raise InputError(field, f"no {where} {', '.join(repr(key) for key in missing)}", _EXPECTED)
    stacks = {}
    for key, second in (("psf", wavelength_count), ("rgb", len(RGB_CHANNELS))):
        stack = arrays.get(key)
        if stack is None:
            continue
        if stack.dtype.kind != "f" or stack.dtype.itemsize != 4:
            raise InputError(field, f"{where} {key!r} is {stack.dtype}", f"float32 ({key} stored exactly)")
        if stack.ndim != 4 or stack.shape[:2] != (depth_count, second):
            raise InputError(
                field,
                f"{where} {key!r} has shape {stack.shape} for {depth_count} depths × {wavelength_count} wavelengths",
                f"{key} (D, {'W' if key == 'psf' else 3}, N, N)",
            )
        stacks[key] = stack.astype(np.float32, copy=False)  # native byte order
    cube = cube_from_channels(field, metadata, channel_planes(field, stacks["psf"], stacks.get("rgb")))
    for key, expected in zip(AXES, (cube.wavelengths_m, cube.depths_m, np.array([cube.pixel_pitch_m]))):
        values = arrays[key]
        if values.dtype.kind not in "fiu" or values.size != expected.size:
            raise InputError(
                field, f"{where} {key!r} is {values.dtype} of shape {values.shape}", f"{expected.size} numbers"
            )
        if not np.array_equal(values.astype(np.float64).ravel(), expected):
            raise InputError(
                field, f"{where} {key!r} disagrees with the metadata's {key}", "the same values (null depths as inf)"
            )
    return cube


def _read_npz(path: Path, field: str) -> PsfCube:
    budget = [MAX_ARRAY_BYTES]
    with zipfile.ZipFile(path) as archive:
        arrays = {key: _npz_member(archive, key, field, budget) for key in ("psf", "rgb", *AXES)}
        text = _npz_member(archive, "metadata", field, budget)
    if text is not None and text.dtype.kind == "U" and text.shape == ():
        text = str(text[()])
    return _cube_from_arrays(field, "member", {**arrays, "metadata": text})


def _npz_member(archive: zipfile.ZipFile, key: str, field: str, budget: list[int]) -> np.ndarray | None:
    """Member ``key`` (None if absent) after its header shows a plain dtype and a size within what
    is left of ``budget`` (bytes, updated): no pickle, no allocation a small file can blow up."""
    from numpy.lib import format as npy_format

    try:
        handle = archive.open(f"{key}.npy")
    except KeyError:
        return None
    with handle:
        version = npy_format.read_magic(handle)
        read_header = npy_format.read_array_header_1_0 if version == (1, 0) else npy_format.read_array_header_2_0
        shape, fortran, dtype = read_header(handle, max_header_size=10_000)
        if dtype.hasobject or dtype.kind not in "fiuU":
            raise InputError(field, f"member {key!r} holds {dtype}", _EXPECTED)
        count = math.prod(shape)
        size = count * dtype.itemsize
        if size > budget[0]:
            raise InputError(
                field,
                f"member {key!r} claims {size / 2**30:.3g} GiB; the limit is {MAX_ARRAY_BYTES / 2**30:g} GiB",
                _EXPECTED,
            )
        budget[0] -= size
        data = handle.read(size + 1)
    if len(data) != size:
        raise InputError(field, f"member {key!r} is truncated", _EXPECTED)
    return np.frombuffer(data, dtype=dtype, count=count).reshape(shape, order="F" if fortran else "C")


def _read_mat(path: Path, field: str) -> PsfCube:
    import scipy.io

    listed = {name: (shape, kind) for name, shape, kind in scipy.io.whosmat(str(path), appendmat=False)}
    wanted = [key for key in ("psf", "rgb", *AXES, "metadata") if key in listed]
    size = 0
    for key in wanted:
        shape, kind = listed[key]
        if kind not in MAT_ITEM_BYTES:
            raise InputError(field, f"variable {key!r} is a MATLAB {kind}", "numeric arrays and char metadata")
        size += math.prod(shape) * MAT_ITEM_BYTES[kind]
    if size > MAX_ARRAY_BYTES:
        raise InputError(
            field,
            f"the variables claim {size / 2**30:.3g} GiB; the limit is {MAX_ARRAY_BYTES / 2**30:g} GiB",
            _EXPECTED,
        )
    loaded = scipy.io.loadmat(str(path), appendmat=False, variable_names=wanted, mat_dtype=False, squeeze_me=False)
    arrays = {key: loaded.get(key) for key in ("psf", "rgb", *AXES)}
    for key in ("psf", "rgb"):  # MATLAB drops trailing singleton dimensions (N = 1)
        stack = arrays[key]
        if stack is not None and stack.ndim < 4:
            arrays[key] = stack.reshape(stack.shape + (1,) * (4 - stack.ndim))
    text = loaded.get("metadata")
    if text is not None and text.dtype.kind == "U" and text.shape == (1,):  # one row of char
        text = str(text[0])
    return _cube_from_arrays(field, "variable", {**arrays, "metadata": text})


# ---------------------------------------------------------------------------- TIFF


def _page_names(depth_count: int, wavelength_count: int, rgb: bool) -> list[str]:
    """The channel name of each TIFF page, in page order."""
    names = [psf_channel_name(i, j) for i in range(depth_count) for j in range(wavelength_count)]
    return names + ([rgb_channel_name(i, c) for i in range(depth_count) for c in RGB_CHANNELS] if rgb else [])


def _write_tiff(path: Path, cube: PsfCube, text: str) -> None:
    import tifffile

    planes = channel_planes(str(path), cube.psf, cube.rgb)  # psf pages, then rgb: the order of _page_names
    bigtiff = sum(plane.nbytes for plane in planes.values()) > TIFF_MAX_BYTES
    with atomic_write(path) as temporary, tifffile.TiffWriter(temporary, bigtiff=bigtiff, byteorder="<") as tiff:
        for k, (name, plane) in enumerate(planes.items()):
            tiff.write(
                plane,
                photometric="minisblack",
                compression=None,
                description=text if k == 0 else None,
                metadata=None,
                software=f"metalens {__version__}" if k == 0 else None,
                extratags=[(TIFF_PAGE_NAME, "s", 0, name, True)],
            )


def _read_tiff(path: Path, field: str) -> PsfCube:
    import tifffile

    with tifffile.TiffFile(path) as tiff:
        pages = tiff.pages
        first = pages.first if hasattr(pages, "first") else pages[0]
        text = first.description or None
        metadata = parse_metadata(field, text, "JSON ImageDescription on the first page")
        depth_count, wavelength_count = check_metadata(field, metadata)
        count, mono = len(pages), depth_count * wavelength_count
        if count not in (mono, mono + 3 * depth_count):
            raise InputError(
                field,
                f"{count} pages for {depth_count} depths × {wavelength_count} wavelengths",
                f"{mono} PSF pages, optionally then {3 * depth_count} colour-channel pages",
            )
        names = _page_names(depth_count, wavelength_count, count > mono)
        shapes = set()
        for k in range(count):
            page = pages[k]
            compression = getattr(page.compression, "name", str(page.compression))
            if page.dtype is None or page.dtype.kind != "f" or page.dtype.itemsize != 4 or len(page.shape) != 2:
                raise InputError(
                    field, f"page {k} is {page.dtype} of shape {page.shape}", "one float32 sample per pixel"
                )
            if compression not in TIFF_LOSSLESS:
                raise InputError(field, f"page {k} has compression {compression}", ", ".join(TIFF_LOSSLESS))
            shapes.add(page.shape)
        size = count * math.prod(next(iter(shapes))) * 4
        if len(shapes) > 1 or size > MAX_ARRAY_BYTES:
            reason = f"pages differ in shape: {sorted(shapes)}" if len(shapes) > 1 else f"{size / 2**30:.3g} GiB"
            raise InputError(field, reason, f"N × N pages, at most {MAX_ARRAY_BYTES / 2**30:g} GiB")
        channels = {name: pages[k].asarray().astype(np.float32, copy=False) for k, name in enumerate(names)}
    return cube_from_channels(field, metadata, channels)


_WRITERS: dict[str, Callable[[Path, PsfCube, str], None]] = {
    ".npz": _write_npz,
    ".mat": _write_mat,
    ".tif": _write_tiff,
    ".tiff": _write_tiff,
}
_READERS: dict[str, Callable[[Path, str], PsfCube]] = {
    ".npz": _read_npz,
    ".mat": _read_mat,
    ".tif": _read_tiff,
    ".tiff": _read_tiff,
}
