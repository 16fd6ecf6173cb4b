"""Phase files that lens-design programs read: a Zemax OpticStudio lens file holding a Binary 2
surface (``.zmx``), a Grid Phase data file (``.dat``), the documented JSON ``metalens-phase/1``
and CSV tables (docs/formats.md, "Exported phase").

A radial design is written as a Binary 2 phase, phase(ρ) = M · Σ_{i=1..N} A_i ρ^{2i} with
ρ = r / R_norm, A_i in radians, M the diffraction order; a 2-D design as its phase on the
meta-atom grid (``kind: "grid"``). Sign: the phase is what the lens adds to the transmitted field
(``exp(+i·phase)`` under ``exp(+i(kz − ωt))``), i.e. optical path + phase·λ/(2π), the sense in
which OpticStudio adds a Binary 2 phase to a ray's optical path: a converging lens has A_1 < 0.

Every writer publishes through :mod:`metalens_cli.io.atomic` (nothing half-written); the readers
(:func:`read_zmx_binary2`, :func:`read_phase_json`) parse the files back, for round trips.
Lengths in SI metres (the .zmx in millimetres, its lens unit).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from metalens_cli.constants import __version__
from metalens_cli.errors import InputError
from metalens_cli.io.atomic import atomic_files, atomic_write
from metalens_cli.io.json_files import jsonable

PHASE_FORMAT = "metalens-phase/1"
PHASE_SUFFIXES = (".zmx", ".json", ".csv", ".dat")
SIGN_CONVENTION = (
    "phase added to the transmitted field, exp(+i*phase) under exp(+i(kz - wt)): optical path "
    "+ phase*lambda/(2*pi); a converging lens has phase decreasing away from the axis"
)
ZMX_MM = 1e3  # metres → the .zmx lens unit (millimetres)
GRID_SIDECAR = ".phase.npy"  # a 2-D design's JSON names its phase map NAME.phase.npy beside it
MAX_DAT_SIDE = 4097  # grid points per side of a Grid Phase .dat (16.8 M lines, about 1 GB of text)
DAT_BYTES_PER_POINT = 80  # "z dz/dx dz/dy d2z/dxdy nodata" in %.12g


@dataclass(frozen=True)
class Binary2Surface:
    """A Binary 2 phase: phase(r) = M · Σ_{i=1..N} A_i (r / R_norm)^{2i} (rad).

    Attributes:
        norm_radius_m: normalisation radius R_norm (m).
        coefficients_rad: A_1..A_N (rad), A_i on ρ^{2i}.
        diffraction_order: M (1 for the design's own handedness; −1 gives the opposite circular
            polarisation of a geometric-phase lens).
    """

    norm_radius_m: float
    coefficients_rad: tuple[float, ...]
    diffraction_order: int = 1

    @property
    def order(self) -> int:
        """N, the number of terms."""
        return len(self.coefficients_rad)

    def phase(self, r_m: np.ndarray) -> np.ndarray:
        """The phase (rad) at radii ``r_m`` (m), summed by Horner's rule in ρ² (float64)."""
        u = (np.asarray(r_m, dtype=np.float64) / self.norm_radius_m) ** 2
        total = np.zeros_like(u)
        for a in reversed(self.coefficients_rad):
            total = (total + a) * u
        return self.diffraction_order * total


def _number(value: float) -> str:
    """Shortest text that reads back as the same float64 (repr), as ASCII."""
    return repr(float(value))


def zmx_text(surface: Binary2Surface, *, aperture_m: float, distance_m: float, wavelength_m: float, name: str) -> str:
    """The text of a minimal sequential OpticStudio lens: object at infinity, the Binary 2 surface as
    the stop (flat, in air, semi-diameter D/2), the image plane ``distance_m`` behind it; one field
    on axis and one wavelength (the phase itself does not depend on it). Lines end in CRLF."""
    mm = ZMX_MM
    xdat = [str(surface.order), *(_number(v) for v in (surface.norm_radius_m * mm, *surface.coefficients_rad))]
    lines = [
        "MODE SEQ",
        f"NAME {name}",
        "UNIT MM X W X CM MR CPMM",
        f"ENPD {_number(aperture_m * mm)}",
        "FTYP 0 0 1 1 0 0 0",
        "XFLN 0",
        "YFLN 0",
        "FWGN 1",
        f"WAVM 1 {_number(wavelength_m * 1e6)} 1",
        "PWAV 1",
        "SURF 0",
        "  TYPE STANDARD",
        "  CURV 0.0",
        "  DISZ INFINITY",
        "SURF 1",
        "  STOP",
        "  TYPE BINARY_2",
        "  CURV 0.0",
        f"  DISZ {_number(distance_m * mm)}",
        f'  DIAM {_number(aperture_m / 2 * mm)} 0 0 0 1 ""',
        f"  PARM 0 {surface.diffraction_order}",
        *(f'  XDAT {i} {v} 0 0 1 0 0 ""' for i, v in enumerate(xdat, start=1)),
        "SURF 2",
        "  TYPE STANDARD",
        "  CURV 0.0",
        "  DISZ 0",
    ]
    return "\r\n".join(lines) + "\r\n"


def write_zmx(
    path: str | os.PathLike[str],
    surface: Binary2Surface,
    *,
    aperture_m: float,
    distance_m: float,
    wavelength_m: float,
    name: str,
) -> None:
    """Write :func:`zmx_text` as UTF-16 LE with a byte-order mark, the encoding OpticStudio itself
    writes (it also reads ASCII); published atomically."""
    text = zmx_text(surface, aperture_m=aperture_m, distance_m=distance_m, wavelength_m=wavelength_m, name=name)
    with atomic_write(path) as temporary:
        temporary.write_bytes(b"\xff\xfe" + text.encode("utf-16-le"))


def _decode_zmx(data: bytes) -> str:
    if data.startswith((b"\xff\xfe", b"\xfe\xff")):
        return data.decode("utf-16")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1")


UNIT_METRES = {"MM": 1e-3, "CM": 1e-2, "IN": 0.0254, "METER": 1.0, "M": 1.0}


def read_zmx_binary2(path: str | os.PathLike[str], field: str = "file") -> Binary2Surface:
    """The first BINARY_2 surface of a .zmx file (UTF-16 with a byte-order mark, UTF-8 or ASCII):
    its diffraction order (PARM 0, default 1), number of terms (XDAT 1), normalisation radius (XDAT 2,
    in the file's lens unit) and coefficients (XDAT 3 …). An InputError naming ``field`` when the
    file holds none or its extra data are incomplete."""
    text = _decode_zmx(Path(path).read_bytes())
    unit, surfaces, current = 1e-3, [], None
    for line in text.splitlines():
        tokens = line.split()
        if not tokens:
            continue
        key = tokens[0]
        if key == "UNIT" and len(tokens) > 1:
            unit = UNIT_METRES.get(tokens[1].upper(), 1e-3)
        elif key == "SURF":
            current = {"type": "STANDARD", "parm": {}, "xdat": {}}
            surfaces.append(current)
        elif current is not None and key == "TYPE" and len(tokens) > 1:
            current["type"] = tokens[1]
        elif current is not None and key in ("PARM", "XDAT") and len(tokens) > 2:
            current[key.lower()][int(tokens[1])] = float(tokens[2])
    binary = next((s for s in surfaces if s["type"] == "BINARY_2"), None)
    if binary is None:
        raise InputError(field, f"{Path(path).name} holds no BINARY_2 surface", "a .zmx with a Binary 2 surface")
    xdat = binary["xdat"]
    terms = int(xdat.get(1, 0))
    missing = [i for i in range(1, terms + 3) if i not in xdat]
    if terms < 1 or missing:
        raise InputError(
            field,
            f"{Path(path).name}: the Binary 2 extra data are incomplete",
            "XDAT 1 = N, XDAT 2 = R_norm, XDAT 3..N+2",
        )
    return Binary2Surface(
        norm_radius_m=xdat[2] * unit,
        coefficients_rad=tuple(xdat[i] for i in range(3, terms + 3)),
        diffraction_order=int(binary["parm"].get(0, 1)),
    )


def binary2_header(
    surface: Binary2Surface, *, design: dict, aperture_m: float, phase_at_axis_rad: float, residual: dict
) -> dict:
    """The ``metalens-phase/1`` object of a radial design (docs/formats.md)."""
    return {
        "format": PHASE_FORMAT,
        "version": __version__,
        "kind": "binary2",
        "design": design,
        "sign_convention": SIGN_CONVENTION,
        "diffraction_order": surface.diffraction_order,
        "order": surface.order,
        "norm_radius_m": surface.norm_radius_m,
        "coefficients_rad": list(surface.coefficients_rad),
        "aperture_m": aperture_m,
        "phase_at_axis_rad": phase_at_axis_rad,
        "residual": residual,
    }


def write_phase_json(path: str | os.PathLike[str], header: dict) -> None:
    """Write a ``metalens-phase/1`` object of a radial design (strict JSON), atomically."""
    with atomic_write(path) as temporary:
        temporary.write_text(json.dumps(jsonable(header), indent=2, allow_nan=False) + "\n", encoding="utf-8")


def grid_sidecar(path: str | os.PathLike[str]) -> Path:
    """Where a 2-D design's JSON keeps its phase map: ``NAME.phase.npy`` beside ``NAME.json``."""
    path = Path(path)
    return path.with_name(path.stem + GRID_SIDECAR)


def write_grid_json(path: str | os.PathLike[str], header: dict, phase_rad: np.ndarray) -> Path:
    """Write a 2-D design's ``metalens-phase/1`` JSON and its float64 phase map (``.npy`` sidecar,
    named in the JSON's ``phase_file``), published together; returns the sidecar's path."""
    sidecar = grid_sidecar(path)
    header = {**header, "phase_file": sidecar.name}
    with atomic_files(path, sidecar) as (json_tmp, npy_tmp):
        json_tmp.write_text(json.dumps(jsonable(header), indent=2, allow_nan=False) + "\n", encoding="utf-8")
        with open(npy_tmp, "wb") as handle:
            np.save(handle, np.ascontiguousarray(phase_rad, dtype=np.float64))
    return sidecar


def read_phase_json(path: str | os.PathLike[str], field: str = "file") -> dict:
    """A ``metalens-phase/1`` object; for ``kind: "binary2"`` with ``surface`` (a
    :class:`Binary2Surface`) added, for ``kind: "grid"`` with ``phase_rad`` (the sidecar map)."""
    path = Path(path)
    try:
        header = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(field, f"{path.name} is not JSON ({exc})", f"a {PHASE_FORMAT} file") from None
    if not isinstance(header, dict) or header.get("format") != PHASE_FORMAT:
        raise InputError(field, f"{path.name} is not a {PHASE_FORMAT} file", f"format {PHASE_FORMAT!r}")
    if header.get("kind") == "binary2":
        header["surface"] = Binary2Surface(
            float(header["norm_radius_m"]),
            tuple(float(a) for a in header["coefficients_rad"]),
            int(header["diffraction_order"]),
        )
    elif header.get("kind") == "grid":
        header["phase_rad"] = np.load(path.with_name(header["phase_file"]), allow_pickle=False)
    else:
        raise InputError(field, f"{path.name} has kind {header.get('kind')!r}", "binary2 or grid")
    return header


def write_radial_csv(path: str | os.PathLike[str], r_m: np.ndarray, phase_rad: np.ndarray, fitted_rad: np.ndarray):
    """``r_m,phase_rad,fitted_rad``: the design's unwrapped phase less its value on the axis, at its
    samples in the pupil, and the Binary 2 fit there; atomically."""
    _write_csv(path, ["r_m", "phase_rad", "fitted_rad"], np.column_stack([r_m, phase_rad, fitted_rad]))


def write_grid_csv(path: str | os.PathLike[str], x_m: np.ndarray, y_m: np.ndarray, phase_rad: np.ndarray):
    """``x_m,y_m,phase_rad``: one row per meta-atom site in the pupil (rows of the map in order of
    increasing y, each in order of increasing x); atomically."""
    _write_csv(path, ["x_m", "y_m", "phase_rad"], np.column_stack([x_m, y_m, phase_rad]))


def _write_csv(path, header: list[str], rows: np.ndarray) -> None:
    with atomic_write(path) as temporary, open(temporary, "w", newline="", encoding="ascii") as handle:
        np.savetxt(handle, rows, fmt="%.17g", delimiter=",", header=",".join(header), comments="")


def csv_bytes_estimate(rows: int, columns: int) -> int:
    """About how many bytes a CSV of ``rows`` × ``columns`` numbers takes (≤ 24 characters each)."""
    return int(rows * columns * 24 + 64)


def write_grid_dat(path: str | os.PathLike[str], phase_rad: np.ndarray, pitch_m: float, inside: np.ndarray) -> None:
    """OpticStudio's Grid Phase data file of a phase map (M × M, row i at y = (i − M//2)·pitch,
    column j at x; rad), atomically: the line ``nx ny delx dely unitflag xdec ydec`` (unitflag 0:
    millimetres, which scale the spacing and the derivatives; the phase stays in radians), then
    one line ``phase dφ/dx dφ/dy d²φ/dxdy nodata`` per point from the corner (−x, +y) along +x,
    row by row towards −y; derivatives by central differences (rad/mm, rad/mm²); points outside
    the pupil (``inside`` False) are ``0 0 0 0 1`` (no data)."""
    phase = np.asarray(phase_rad, dtype=np.float64)
    m = phase.shape[0]
    step = pitch_m * ZMX_MM
    gy, gx = np.gradient(phase, step)
    gxy = np.gradient(gx, step, axis=0)
    rows = np.stack([phase, gx, gy, gxy], axis=-1)[::-1]  # first line: the row of largest y
    flags = ~np.asarray(inside, dtype=bool)[::-1]
    rows[flags] = 0.0
    table = np.concatenate([rows.reshape(-1, 4), flags.reshape(-1, 1).astype(np.float64)], axis=1)
    with atomic_write(path) as temporary, open(temporary, "w", newline="\r\n", encoding="ascii") as handle:
        handle.write(f"{m} {m} {step!r} {step!r} 0 0 0\n")
        np.savetxt(handle, table, fmt=["%.12g", "%.12g", "%.12g", "%.12g", "%d"], delimiter=" ")


def read_grid_dat(path: str | os.PathLike[str], field: str = "file") -> tuple[np.ndarray, float, np.ndarray]:
    """A Grid Phase .dat back as (phase map M × M in this package's row order, rad; the spacing, m;
    the mask of points with data)."""
    path = Path(path)
    try:
        with open(path, encoding="ascii") as handle:
            head = handle.readline().split()
            table = np.loadtxt(handle, ndmin=2)
        nx, ny, delx, unit = int(head[0]), int(head[1]), float(head[2]), int(head[4])
    except (OSError, ValueError, IndexError, UnicodeDecodeError) as exc:
        raise InputError(
            field,
            f"{path.name} is not a Grid Phase file ({exc})",
            "nx ny delx dely unitflag xdec ydec, then nx·ny points",
        ) from None
    scale = {0: 1e-3, 1: 1e-2, 2: 0.0254, 3: 1.0}.get(unit)
    if scale is None or table.shape != (nx * ny, 5):
        raise InputError(field, f"{path.name} has {table.shape} data for {nx} × {ny} points", "nx·ny lines of 5 values")
    grid = table.reshape(ny, nx, 5)[::-1]
    return grid[..., 0], delx * scale, grid[..., 4] == 0
