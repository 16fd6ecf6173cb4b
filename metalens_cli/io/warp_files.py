"""Warp files of ``metalens align --warp-out``: the "metalens-warp/1" contract.

A warp file is a ``.npz`` (``numpy.savez_compressed``) of plain arrays, read back without pickle:

- ``format``: "metalens-warp/1"; ``created_by``: "metalens VERSION" (informative, not read);
- ``homography`` (3, 3) float64: reference pixel (x, y, 1) → target pixel (x·w, y·w, w), x =
  column, y = row, pixel centres at integers;
- ``reference_shape``, ``target_shape`` (2,) int64: (rows, columns);
- ``flow_step`` () int64 and ``flow_nodes`` (ny, nx, 2) float32: the residual displacement
  (dx, dy) in target pixels added after the homography, given at reference rows and columns
  :func:`node_positions` (every ``flow_step`` pixels, and the last) and bilinear in between;
  ``flow_step`` 0 and (0, 0, 2) nodes when there is no refinement;
- ``matches``, ``inliers`` () int64, ``residual_px``, ``refined_residual_px`` () float64 (NaN:
  not measured), ``refine`` ("flow", "tps" or "none"): the registration's report.

Every member's header is checked (dtype, shape) before its data is read.
"""

from __future__ import annotations

import os
import zipfile
import zlib
from pathlib import Path

import numpy as np
from numpy.lib import format as npy_format

from metalens_cli.constants import REFINEMENTS, __version__
from metalens_cli.errors import InputError
from metalens_cli.io.atomic import atomic_write
from metalens_cli.io.input_files import MAX_IMAGE_PIXELS, regular_file

FORMAT = "metalens-warp/1"
MAX_SIDE = 32767  # OpenCV's remap limit
_EXPECTED = "a WARP.npz written by metalens align --warp-out"
_SCALARS = {"matches": "iu", "inliers": "iu", "residual_px": "f", "refined_residual_px": "f", "flow_step": "iu"}


def node_positions(size: int, step: int) -> np.ndarray:
    """Pixel indices 0, step, 2·step, … and ``size − 1`` (int64, increasing) at which a flow of
    ``size`` rows or columns is given."""
    positions = np.arange(0, size, step, dtype=np.int64)
    return positions if positions[-1] == size - 1 else np.append(positions, size - 1)


def write_warp_file(
    path: str | os.PathLike[str],
    homography: np.ndarray,
    reference_shape: tuple[int, int],
    target_shape: tuple[int, int],
    *,
    flow_step: int,
    flow_nodes: np.ndarray | None,
    matches: int,
    inliers: int,
    residual_px: float,
    refined_residual_px: float | None,
    refine: str,
) -> None:
    """Write a warp file atomically (fields as in the module docstring)."""
    nodes = np.zeros((0, 0, 2), np.float32) if flow_nodes is None else np.asarray(flow_nodes, np.float32)
    arrays = {
        "format": np.array(FORMAT),
        "created_by": np.array(f"metalens {__version__}"),
        "homography": np.asarray(homography, np.float64),
        "reference_shape": np.asarray(reference_shape, np.int64),
        "target_shape": np.asarray(target_shape, np.int64),
        "flow_step": np.array(flow_step if flow_nodes is not None else 0, np.int64),
        "flow_nodes": nodes,
        "matches": np.array(matches, np.int64),
        "inliers": np.array(inliers, np.int64),
        "residual_px": np.array(residual_px, np.float64),
        "refined_residual_px": np.array(np.nan if refined_residual_px is None else refined_residual_px, np.float64),
        "refine": np.array(refine),
    }
    with atomic_write(path) as temporary, open(temporary, "wb") as handle:
        np.savez_compressed(handle, **arrays)


def read_warp_file(path: str | os.PathLike[str], field: str) -> dict:
    """The fields of a warp file, validated: ``homography`` (3, 3) float64 finite,
    ``reference_shape``/``target_shape`` tuples of 2 ints, ``flow_step`` int, ``flow_nodes``
    (ny, nx, 2) float32 finite or None, ``matches``, ``inliers`` ints, ``residual_px`` float,
    ``refined_residual_px`` float or None, ``refine`` str. Anything else is an :class:`InputError` naming ``field``."""
    path = regular_file(path, field, _EXPECTED)
    try:
        with zipfile.ZipFile(path) as archive:
            raw = _members(archive, path.name, field)
    except (zipfile.BadZipFile, OSError, EOFError, zlib.error, NotImplementedError, RuntimeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc) or type(exc).__name__
        raise InputError(field, f"{path.name} is not a readable warp file ({reason[:120]})", _EXPECTED) from None
    return _validated(raw, path, field)


def _members(archive: zipfile.ZipFile, name: str, field: str) -> dict[str, np.ndarray]:
    """Each expected member after its header passes: small scalars and strings, a (3, 3) float
    homography, (2,) integer shapes, (ny, nx, 2) float nodes within the image pixel limit."""
    limits = {
        "homography": ((3, 3), "f"),
        "reference_shape": ((2,), "iu"),
        "target_shape": ((2,), "iu"),
        **{key: ((), kinds) for key, kinds in _SCALARS.items()},
    }
    raw = {}
    for key in ("format", "refine", *limits, "flow_nodes"):
        try:
            handle = archive.open(f"{key}.npy")
        except KeyError:
            raise InputError(field, f"{name} has no {key!r}", _EXPECTED) from None
        with handle:
            try:
                version = npy_format.read_magic(handle)
                read_header = (
                    npy_format.read_array_header_1_0 if version == (1, 0) else npy_format.read_array_header_2_0
                )
                shape, fortran, dtype = read_header(handle, max_header_size=10_000)
            except (ValueError, SyntaxError, TypeError, UnicodeDecodeError) as exc:
                raise InputError(
                    field, f"{name}: {key!r} is not a .npy array ({str(exc).splitlines()[0][:80]})", _EXPECTED
                ) from None
            if key in ("format", "refine"):
                good = dtype.kind == "U" and shape == () and dtype.itemsize <= 4 * 64
            elif key == "flow_nodes":
                good = (
                    dtype == np.float32
                    and len(shape) == 3
                    and shape[2] == 2
                    and shape[0] * shape[1] <= MAX_IMAGE_PIXELS
                )
            else:
                want_shape, kinds = limits[key]
                good = shape == want_shape and dtype.kind in kinds and not dtype.hasobject
            if not good:
                raise InputError(field, f"{name}: {key!r} is {dtype} of shape {shape}", _EXPECTED)
            count = int(np.prod(shape, dtype=np.int64))
            data = handle.read(count * dtype.itemsize + 1)
        if len(data) != count * dtype.itemsize:
            raise InputError(field, f"{name}: {key!r} is truncated", _EXPECTED)
        raw[key] = np.frombuffer(data, dtype=dtype, count=count).reshape(shape, order="F" if fortran else "C")
    return raw


def _validated(raw: dict[str, np.ndarray], path: Path, field: str) -> dict:
    """Check the values against each other: format, finite numbers, shapes, node grid."""
    name = path.name

    def bad(message: str) -> InputError:
        return InputError(field, f"{name}: {message}", _EXPECTED)

    if str(raw["format"]) != FORMAT:
        raise bad(f"format {str(raw['format'])[:40]!r}, not {FORMAT!r}")
    refine = str(raw["refine"])
    if refine not in REFINEMENTS:
        raise bad(f"unknown refine {refine[:20]!r}")
    shapes = {}
    for key in ("reference_shape", "target_shape"):
        rows, columns = (int(v) for v in raw[key])
        if not (1 <= rows <= MAX_SIDE and 1 <= columns <= MAX_SIDE and rows * columns <= MAX_IMAGE_PIXELS):
            raise bad(f"{key} {rows} × {columns} is not an image size")
        shapes[key] = (rows, columns)
    homography = np.array(raw["homography"], dtype=np.float64)
    if not np.all(np.isfinite(homography)) or abs(np.linalg.det(homography)) < 1e-300:
        raise bad("the homography is not finite and invertible")
    matches, inliers, step = int(raw["matches"]), int(raw["inliers"]), int(raw["flow_step"])
    residual, refined = float(raw["residual_px"]), float(raw["refined_residual_px"])
    if (
        not (0 <= inliers <= matches)
        or not (np.isfinite(residual) and residual >= 0)
        or refined < 0
        or np.isinf(refined)
    ):
        raise bad(f"inconsistent report (matches {matches}, inliers {inliers}, residuals {residual}, {refined})")
    nodes = np.array(raw["flow_nodes"], dtype=np.float32)
    rows, columns = shapes["reference_shape"]
    if step < 0 or (refine == "none") != (step == 0):
        raise bad(f"refine {refine!r} with flow_step {step}")
    if step == 0:
        if nodes.size:
            raise bad("flow nodes without a flow_step")
        nodes = None
    else:
        expected = (node_positions(rows, step).size, node_positions(columns, step).size, 2)
        if nodes.shape != expected:
            raise bad(f"flow nodes of shape {nodes.shape} do not match a {rows} × {columns} reference at step {step}")
        if not np.all(np.isfinite(nodes)):
            raise bad("the flow holds NaN or infinite values")
    return {
        "homography": homography,
        **shapes,
        "flow_step": step,
        "flow_nodes": nodes,
        "matches": matches,
        "inliers": inliers,
        "residual_px": residual,
        "refined_residual_px": None if np.isnan(refined) else refined,
        "refine": refine,
    }
