"""Lens layouts for e-beam lithography: the geometry contract and the GDSII/OASIS export.

Geometry contract (all lengths SI metres in the API, database units (dbu) in the file):

- The lens centre is the layout origin and a meta-atom site. Sites sit at (i·p, j·p) for integers
  i (along +x) and j (along +y), p the pitch; a site is kept when its centre lies within D/2 of the
  origin (i² + j² ≤ (D/2p)², with the 1e-9 site tolerance of :mod:`metalens_cli.optics.lens`).
- Each nanofin is a width × length rectangle centred on its site, its width side at angle θ
  counter-clockwise from +x (phase φ = 2θ, see :mod:`metalens_cli.optics.lens`). Its vertices are
  rounded to the database unit: the site centre rounded, plus each corner offset rounded (so the
  fin stays point-symmetric about its centre; with the pitch a whole number of dbu, as for 395 nm
  at 1 nm, that is each vertex rounded).
- θ at a site comes from the design: a radial profile θ(r) is interpolated linearly at the site
  radius (exactly as the simulations do); a 2-D map is read at row M//2 + j, column M//2 + i.
- ``angles=K`` quantises θ to the K levels k·π/K (a fin turned by π is the same fin): K cells
  each hold one fin at its level, placed by reference at the sites. The angle error is at most
  π/(2K), so the phase error 2·|θ − θ_k| is at most π/K. The vertices follow the same rule.

Sites are streamed in chunks of whole grid rows (about :data:`CHUNK_SITES` at a time), so memory
stays bounded whatever the lens size. GDSII is written by :mod:`metalens_cli.io.gdsii`; OASIS is
converted from that GDSII stream by KLayout's C++ reader and writer (the ``klayout`` package), the
stream passing through a FIFO so that no intermediate file is written.
"""

from __future__ import annotations

import errno
import json
import math
import os
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np

from metalens_cli.arguments import count, instance, positive
from metalens_cli.arguments import path as arguments_path
from metalens_cli.constants import __version__
from metalens_cli.errors import InputError, MetalensError
from metalens_cli.io.atomic import atomic_write
from metalens_cli.io.gdsii import MAX_COORDINATE, GdsStream

CHUNK_SITES = 1 << 20  # sites per chunk: ~250 MB of temporaries at most
SITE_TOLERANCE = 1e-9  # in pitches, as in optics.lens
MARGIN_SITES = 2  # how far (in sites) a θ array may reach beyond the pupil edge
FORMATS = ("gds", "oas")
MAX_LEVELS = 65536
LIBRARY_NAME = "metalens"
OASIS_COMPRESSION_LEVEL = 1  # KLayout: repetitions of identical shapes (level 2 came out larger and slower here)
OASIS_CBLOCKS = False  # deflated CBLOCKs: paper lens 53 MB in 63 s, without 77 MB in 56 s (2 busy cores)


@dataclass(frozen=True)
class FinGeometry:
    """Nanofin layout parameters: pitch, width, length and database unit (m), GDS layer/datatype.

    Checked when built: positive finite sizes; layer and datatype in 0-32767.

    Attributes:
        pitch_m: fin pitch (m), the design's meta-atom pitch.
        width_m: fin width (m).
        length_m: fin length (m).
        dbu_m: the layout's database unit (m).
        layer: GDSII layer number.
        datatype: GDSII datatype number.
    """

    pitch_m: float
    width_m: float
    length_m: float
    dbu_m: float = 1e-9
    layer: int = 1
    datatype: int = 0

    def __post_init__(self) -> None:
        """Positive finite sizes; GDSII layer and datatype numbers in 0-32767."""
        for name in ("pitch_m", "width_m", "length_m", "dbu_m"):
            positive(getattr(self, name), name)
        for name in ("layer", "datatype"):
            count(getattr(self, name), name, lo=0, hi=32767)

    def describe(self) -> dict:
        """JSON-ready summary for file headers and reports."""
        return {
            "pitch_m": self.pitch_m,
            "width_m": self.width_m,
            "length_m": self.length_m,
            "dbu_m": self.dbu_m,
            "layer": f"{self.layer}/{self.datatype}",
        }


@dataclass(frozen=True)
class ExportReport:
    """What :func:`export_layout` wrote: atom count, file, size (bytes), format, worst phase error (rad), time (s)."""

    atoms: int
    file: str
    bytes: int
    format: str
    max_phase_error_rad: float
    seconds: float
    top_cell: str

    def to_dict(self) -> dict:
        """The ``--json`` report keys."""
        return {
            "atoms": self.atoms,
            "file": self.file,
            "bytes": self.bytes,
            "format": self.format,
            "max_phase_error_rad": self.max_phase_error_rad,
            "seconds": self.seconds,
        }


# --- sites -------------------------------------------------------------------------------------------------


def site_rows(radius_m: float, pitch_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Grid rows j = −J..J inside the pupil and each row's half-width h_j (int64).

    Row j holds the sites i = −h_j..h_j; exactly those with i² + j² ≤ ρ², ρ = R/p + 1e-9.
    """
    rho2 = (radius_m / pitch_m + SITE_TOLERANCE) ** 2
    top = math.isqrt(math.floor(rho2))
    j = np.arange(-top, top + 1, dtype=np.int64)
    h = np.floor(np.sqrt(rho2 - j * j)).astype(np.int64)
    h += (h + 1) ** 2 + j * j <= rho2  # repair float rounding of the square root, both ways
    h -= h * h + j * j > rho2
    return j, h


def site_count(rows: tuple[np.ndarray, np.ndarray]) -> int:
    """Number of sites in ``rows`` (from :func:`site_rows`)."""
    return int(np.sum(2 * rows[1] + 1))


def _expand(j: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All sites (i, j) of the given rows, row by row, i ascending."""
    counts = 2 * h + 1
    row = np.repeat(np.arange(j.size), counts)
    first = np.cumsum(counts) - counts
    i = np.arange(int(counts.sum()), dtype=np.int64) - first[row] - h[row]
    return i, j[row]


def site_chunks(
    rows: tuple[np.ndarray, np.ndarray], max_sites: int = CHUNK_SITES
) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Yield (i, j) int64 arrays of whole rows, about ``max_sites`` sites (at least one row) at a time."""
    j, h = rows
    bounds = np.concatenate([[0], np.cumsum(2 * h + 1)])
    start = 0
    while start < j.size:
        stop = max(start + 1, int(np.searchsorted(bounds, bounds[start] + max_sites, side="right")) - 1)
        yield _expand(j[start:stop], h[start:stop])
        start = stop


def sites_at(rows: tuple[np.ndarray, np.ndarray], index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The sites (i, j) at flat positions ``index`` of the row-by-row site order."""
    j, h = rows
    bounds = np.cumsum(2 * h + 1)
    row = np.searchsorted(bounds, index, side="right")
    return index - (bounds[row] - (2 * h[row] + 1)) - h[row], j[row]


# --- θ at the sites ----------------------------------------------------------------------------------------


def check_theta_extent(lens) -> None:
    """Refuse a θ array reaching more than :data:`MARGIN_SITES` sites beyond the pupil edge.

    :func:`metalens_cli.optics.lens.from_array` already refuses arrays too small for the pupil;
    one much larger than it means that the pitch or aperture in force is not the array's.
    """
    rho = lens.radius_m / lens.pitch_m
    n = lens.theta.shape[0]
    reach = n - 1 if lens.radial else n // 2
    if reach > rho + MARGIN_SITES + SITE_TOLERANCE:
        what = f"radial θ of {n} samples" if lens.radial else f"θ map of {n} × {n} sites"
        raise InputError(
            "--design",
            f"{what} reaches {reach * lens.pitch_m * 1e3:.4g} mm from the axis at pitch "
            f"{lens.pitch_m * 1e9:.4g} nm, beyond the {lens.aperture_m * 1e3:.4g} mm aperture: "
            "the map's pitch or aperture contradicts the options",
            f"the map's own --pitch and --aperture (at most {MARGIN_SITES} sites beyond D/2)",
        )


def site_theta(lens, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """θ (rad, float64) of the design at sites (i, j): radial profile at r = p·√(i² + j²), or the 2-D map."""
    if lens.radial:  # linear between samples at k·p, clamped beyond: Metalens.phase_at_radius / 2
        samples = lens.theta.numpy()
        return np.interp(np.sqrt((i * i + j * j).astype(np.float64)), np.arange(samples.size), samples)
    centre = lens.theta.shape[0] // 2
    return lens.theta.numpy()[centre + j, centre + i].astype(np.float64)


def quantise(theta: np.ndarray, levels: int) -> tuple[np.ndarray, np.ndarray]:
    """Nearest of the ``levels`` angles k·π/K: level k in [0, K) and the written angle (rad).

    The written angle differs from θ by at most π/(2K) (it may differ from k·π/K by a multiple of π,
    the same fin), so the phase error 2·|θ − written| is at most π/K.
    """
    from metalens_cli.optics.fabrication import quantize

    written = quantize(theta, levels)
    return np.mod(np.rint(written / (math.pi / levels)), levels).astype(np.int64), written


# --- vertices ----------------------------------------------------------------------------------------------


def pitch_dbu(geometry: FinGeometry) -> float:
    """The pitch in database units, snapped to the integer it is within 1e-9 of (395 nm / 1 nm → 395)."""
    ratio = geometry.pitch_m / geometry.dbu_m
    return float(round(ratio)) if abs(ratio - round(ratio)) < 1e-9 * ratio else ratio


def site_positions(i: np.ndarray, j: np.ndarray, geometry: FinGeometry) -> np.ndarray:
    """Site centres (n, 2) int32 in dbu: (i·p, j·p) rounded."""
    p = pitch_dbu(geometry)
    out = np.empty((i.size, 2), dtype=np.int32)
    out[:, 0] = np.rint(i * p)
    out[:, 1] = np.rint(j * p)
    return out


def corner_offsets(theta: np.ndarray, geometry: FinGeometry) -> np.ndarray:
    """Corner offsets (n, 4, 2) int32 in dbu from the fin centre, counter-clockwise, rounded.

    With u = (cos θ, sin θ) along the width side and v = (−sin θ, cos θ) along the length side, the
    corners are −a·u − b·v, a·u − b·v, a·u + b·v, −a·u + b·v (a = width/2, b = length/2). The last
    two are the negatives of the first two, rounded alike, so the fin stays point-symmetric.
    """
    a = geometry.width_m / 2 / geometry.dbu_m
    b = geometry.length_m / 2 / geometry.dbu_m
    c, s = np.cos(theta), np.sin(theta)
    out = np.empty((theta.size, 4, 2), dtype=np.int32)
    out[:, 0, 0] = np.rint(b * s - a * c)
    out[:, 0, 1] = np.rint(-a * s - b * c)
    out[:, 1, 0] = np.rint(a * c + b * s)
    out[:, 1, 1] = np.rint(a * s - b * c)
    np.negative(out[:, :2], out=out[:, 2:])
    return out


def fin_vertices(i: np.ndarray, j: np.ndarray, theta: np.ndarray, geometry: FinGeometry) -> np.ndarray:
    """Vertices (n, 4, 2) int32 in dbu of the fins at sites (i, j) with rotations θ (rad).

    Each vertex is the rounded site centre plus the rounded corner offset (:func:`corner_offsets`).
    """
    out = corner_offsets(theta, geometry)
    out += site_positions(i, j, geometry)[:, None, :]
    return out


# --- checks and names --------------------------------------------------------------------------------------


def check_geometry(geometry: FinGeometry, aperture_m: float, angles: int | None) -> None:
    """Refuse fins that could overlap or collapse, coordinates beyond 32 bits, or a bad level count."""
    g = geometry
    if math.hypot(g.width_m, g.length_m) > g.pitch_m:
        raise InputError(
            "--width",
            f"a {g.width_m * 1e9:.4g} × {g.length_m * 1e9:.4g} nm fin can overlap its "
            f"neighbours at pitch {g.pitch_m * 1e9:.4g} nm",
            "a diagonal √(w² + l²) ≤ pitch",
        )
    if min(g.width_m, g.length_m) < 2 * g.dbu_m:
        raise InputError(
            "--dbu",
            f"{g.dbu_m:g} m is too coarse for a {g.length_m * 1e9:.4g} nm fin",
            "a database unit at most half the fin's smaller side",
        )
    if (aperture_m / 2 + g.pitch_m) / g.dbu_m >= MAX_COORDINATE:
        raise InputError("--dbu", f"{g.dbu_m:g} m makes coordinates exceed 32 bits", "a coarser database unit")
    if angles is not None:
        count(angles, "angles", lo=2, hi=MAX_LEVELS)


def cell_name(spec: str) -> str:
    """A GDSII structure name for the design: its file or directory name, [A-Za-z0-9_?$] only, ≤ 32 chars."""
    text = str(spec).strip()
    stem = Path(text.rstrip("/")).stem if not text.startswith("hyperbolic:") else text
    return re.sub(r"[^A-Za-z0-9_?$]", "_", stem)[:32] or "LENS"


def level_cell_names(top: str, levels: int) -> np.ndarray:
    """Fixed-width (even, NUL-padded) byte names of the K level cells, TOP_A00000 … for θ = k·π/K
    (TOP cut to 8 characters: the name is repeated in every reference)."""
    names = [f"{top[:8]}_A{k:05d}".encode("ascii") for k in range(levels)]
    width = len(names[0]) + len(names[0]) % 2
    return np.array(names, dtype=f"S{width}")


def metadata_text(design, geometry: FinGeometry, angles: int | None, atoms: int) -> str:
    """The ASCII JSON recorded in the top cell as a TEXT element: tool, design, geometry, conventions."""
    return json.dumps(
        {
            "tool": f"metalens {__version__}",
            "design": Path(str(design.spec).rstrip("/")).name or design.spec,
            "aperture_m": design.lens.aperture_m,
            **geometry.describe(),
            "angles": "exact" if angles is None else angles,
            "atoms": atoms,
            "convention": "fin centred on site (i*pitch, j*pitch), width side at theta CCW from +x, phase 2*theta",
        },
        separators=(",", ":"),
        ensure_ascii=True,
    )


# --- writing -----------------------------------------------------------------------------------------------


def _write_level_cells(stream: GdsStream, names: np.ndarray, used: np.ndarray, geometry: FinGeometry) -> None:
    """The level cells referenced (``used[k]``), each one fin at θ = k·π/K centred on its origin. They
    follow the top cell, so that levels no site uses are left out rather than left as extra top cells."""
    levels = np.flatnonzero(used)
    origin = np.zeros(levels.size, dtype=np.int64)
    for name, vertices in zip(names[levels], fin_vertices(origin, origin, levels * math.pi / used.size, geometry)):
        stream.begin_structure(name.decode("ascii"))
        stream.boundaries(vertices[None], geometry.layer, geometry.datatype)
        stream.end_structure()


def write_gds(
    file, design, geometry: FinGeometry, angles: int | None, progress: Callable[[int, int], None] | None = None
) -> tuple[int, float, str]:
    """Stream the lens as GDSII into the open binary ``file``; return (atoms, max phase error (rad), top cell)."""
    lens = design.lens
    rows = site_rows(lens.radius_m, lens.pitch_m)
    total = site_count(rows)
    top = cell_name(design.spec)
    stream = GdsStream(file)
    stream.begin_library(LIBRARY_NAME, geometry.dbu_m)
    names = None if angles is None else level_cell_names(top, angles)
    used = np.zeros(0 if angles is None else angles, dtype=bool)
    stream.begin_structure(top)
    stream.text(geometry.layer, geometry.datatype, 0, 0, metadata_text(design, geometry, angles, total))
    done, worst = 0, 0.0
    for i, j in site_chunks(rows):
        theta = site_theta(lens, i, j)
        if names is None:
            stream.boundaries(fin_vertices(i, j, theta, geometry), geometry.layer, geometry.datatype)
        else:
            level, written = quantise(theta, angles)
            worst = max(worst, float(np.max(2 * np.abs(theta - written))))
            used[level] = True
            stream.srefs(names[level], site_positions(i, j, geometry))
        done += i.size
        if progress is not None:
            progress(done, total)
    stream.end_structure()
    if names is not None:
        _write_level_cells(stream, names, used, geometry)
    stream.end_library()
    return total, worst, top


def gds_to_oasis(gds_path: str, oas_path: str) -> None:
    """Convert a GDSII file (or FIFO) to OASIS with KLayout: CBLOCK (deflate) compression and
    repetitions of identical shapes (compression level :data:`OASIS_COMPRESSION_LEVEL`)."""
    db = require_klayout()
    layout = db.Layout()
    layout.read(gds_path)
    options = db.SaveLayoutOptions()
    options.format = "OASIS"
    options.oasis_write_cblocks = OASIS_CBLOCKS
    options.oasis_strict_mode = True
    options.oasis_compression_level = OASIS_COMPRESSION_LEVEL
    layout.write(oas_path, options)


CONVERTER = "import sys; from metalens_cli.io.layout import gds_to_oasis; gds_to_oasis(sys.argv[1], sys.argv[2])"


def _open_fifo_writer(fifo: str, reader: subprocess.Popen) -> BinaryIO:
    """Open ``fifo`` for writing once ``reader`` has opened it; None if the reader exited first."""
    while True:
        try:
            descriptor = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
            break
        except OSError as exc:
            if exc.errno != errno.ENXIO or reader.poll() is not None:
                return None
            time.sleep(0.01)
    os.set_blocking(descriptor, True)
    return os.fdopen(descriptor, "wb")


def write_oasis(
    path: str | os.PathLike,
    design,
    geometry: FinGeometry,
    angles: int | None,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[int, float, str]:
    """Write the lens as OASIS to ``path``: the GDSII stream goes through a FIFO into a KLayout process
    (:func:`gds_to_oasis`), so that writing and reading overlap on two cores and no intermediate file
    touches the disk."""
    with tempfile.TemporaryDirectory(prefix="metalens-gds-") as folder:
        fifo = os.path.join(folder, "layout.gds")
        os.mkfifo(fifo)
        converter = subprocess.Popen([sys.executable, "-c", CONVERTER, fifo, str(path)], stderr=subprocess.PIPE)
        try:
            file = _open_fifo_writer(fifo, converter)
            result = None
            if file is not None:
                with file:
                    result = write_gds(file, design, geometry, angles, progress)
        except BrokenPipeError:
            result = None
        except BaseException:
            converter.kill()
            raise
        finally:
            message = converter.communicate()[1].decode(errors="replace").strip()
    if result is None or converter.returncode != 0:
        last = message.splitlines()[-1] if message else f"exit code {converter.returncode}"
        raise MetalensError(f"KLayout failed to convert the layout to OASIS: {last}")
    return result


def require_klayout():
    """The ``klayout.db`` module, or an :class:`InputError` telling how to install it."""
    try:
        import klayout.db as db
    except ImportError:
        raise InputError(
            "klayout", "the klayout package is not installed (needed for OASIS and --verify)", "pip install klayout"
        ) from None
    return db


def format_of(path: str | os.PathLike, fmt: str | None) -> str:
    """The output format: ``fmt`` if given (refused when the extension names the other one), else
    from the extension (.gds, .oas)."""
    suffix = Path(path).suffix.lower().lstrip(".")
    aliases = {"gds": "gds", "gdsii": "gds", "gds2": "gds", "oas": "oas", "oasis": "oas"}
    if fmt is not None:
        if aliases.get(suffix, fmt) != fmt:
            raise InputError(
                "--format",
                f"{fmt} into {Path(path).name!r}, whose extension says {aliases[suffix]}",
                "a format matching the extension",
            )
        return fmt
    if suffix not in aliases:
        raise InputError(
            "--output", f"cannot tell the format of {str(path)!r} from its extension", ".gds or .oas, or --format"
        )
    return aliases[suffix]


# Per fin: bytes in the file, fins written per second, bytes held in memory (OASIS is built in
# KLayout's memory); measured by benchmarks/bench_gds.py on the paper's lens (docs/benchmarks.md).
FIN_COSTS = {
    ("gds", "exact"): (64, 2.3e6, 0),
    ("gds", "quantised"): (40, 3.9e6, 0),
    ("oas", "exact"): (2.4, 5.6e5, 36),
    ("oas", "quantised"): (2.4, 5.6e5, 36),
}
STREAMING_BYTES = 1 << 29  # the chunked writer's working set (CHUNK_SITES sites of temporaries, 0.41 GiB measured)


def estimate_layout(aperture_m: float, pitch_m: float, fmt: str, angles: int | None) -> tuple[int, int, int, float]:
    """(fins, file bytes, peak memory bytes, seconds) of :func:`export_layout` for a lens of
    diameter ``aperture_m`` on a grid of ``pitch_m``, from the measured per-fin costs."""
    fins = int(math.pi * (aperture_m / 2) ** 2 / pitch_m**2)
    size, rate, held = FIN_COSTS[(fmt if fmt in FORMATS else "gds", "exact" if angles is None else "quantised")]
    return fins, int(fins * size), int(STREAMING_BYTES + fins * held), fins / rate


def export_layout(
    design,
    geometry: FinGeometry,
    path: str | os.PathLike,
    *,
    fmt: str = "gds",
    angles: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> ExportReport:
    """Write the lens layout of ``design`` (a :class:`metalens_cli.io.designs.Design`) to ``path``.

    The file is written to a temporary name beside ``path`` and renamed.

    Args:
        design: the resolved design (:func:`resolve_design`).
        geometry: the fins (:class:`FinGeometry`); its pitch must be the design's.
        path: the output file.
        fmt: "gds" or "oas" (OASIS, through KLayout).
        angles: None writes every fin as its own polygon at its exact θ; K quantises θ into K
            referenced cells.
        progress: ``progress(done, total)`` reports the fins written.

    Returns:
        ``ExportReport``: atom count, file, size (bytes), format, worst phase error (rad), time (s)
        and the top cell's name.
    """
    from metalens_cli.io.designs import Design

    start = time.perf_counter()
    lens = instance(design, "design", Design, "a Design (ml.resolve_design)").lens
    instance(geometry, "geometry", FinGeometry, "a FinGeometry")
    path = arguments_path(path, "path", "an output file path")
    if not math.isclose(geometry.pitch_m, lens.pitch_m, rel_tol=1e-9):
        raise InputError(
            "--pitch",
            f"fin pitch {geometry.pitch_m:g} m differs from the design's {lens.pitch_m:g} m",
            "one pitch for the θ map and the layout",
        )
    check_theta_extent(lens)
    check_geometry(geometry, lens.aperture_m, angles)
    if fmt not in FORMATS:
        raise InputError("fmt", f"unknown format {fmt!r}", " or ".join(FORMATS))
    if fmt == "oas":
        require_klayout()
    with atomic_write(path) as temporary:
        if fmt == "gds":
            with open(temporary, "wb") as file:
                atoms, worst, top = write_gds(file, design, geometry, angles, progress)
        else:
            atoms, worst, top = write_oasis(temporary, design, geometry, angles, progress)
    size = os.path.getsize(path)
    return ExportReport(atoms, str(path), size, fmt, worst, time.perf_counter() - start, top)
