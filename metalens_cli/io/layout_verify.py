"""Read a written lens layout back with an independent reader (KLayout) and check it against the design.

The check: the file has one top cell, the fin layer, exactly one fin per site inside the pupil
(the flattened polygon count), and at a random sample of sites one quadrilateral whose centre,
side lengths and rotation match the geometry contract of :mod:`metalens_cli.io.layout`, within
what rounding the vertices to the database unit d allows:

- centre: each coordinate off by at most d/2 (the site centre is rounded);
- sides: off by at most √2·d (each end vertex moves by at most d/√2);
- rotation of the width side: off by at most atan(√2·d / (w − √2·d)) from the written angle
  (θ itself, or its quantised level), modulo π.

The phase error against the design, 2·|rotation − θ| modulo 2π, is reported (it includes the
quantisation of ``angles=K``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from metalens_cli.io.layout import FinGeometry, quantise, require_klayout, site_count, site_rows, site_theta, sites_at

DEFAULT_SAMPLES = 1000


@dataclass(frozen=True)
class VerifyReport:
    """Outcome of :func:`verify_layout`: counts, worst errors (m, rad), tolerances and failures (text)."""

    ok: bool
    expected_atoms: int
    found_atoms: int
    samples: int
    worst: dict
    tolerance: dict
    failures: list = field(default_factory=list)

    def to_dict(self) -> dict:
        """JSON-ready report."""
        return {
            "ok": self.ok,
            "expected_atoms": self.expected_atoms,
            "found_atoms": self.found_atoms,
            "samples": self.samples,
            "worst": self.worst,
            "tolerance": self.tolerance,
            "failures": self.failures,
        }


def wrap(angle: np.ndarray, period: float) -> np.ndarray:
    """``angle`` reduced to [−period/2, period/2)."""
    return (angle + period / 2) % period - period / 2


def measure_fin(points: np.ndarray, width_dbu: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Centre (2,), side lengths (width side, length side) and width-side angle (rad) of a quadrilateral.

    ``points`` is (4, 2) in order around the ring; the width side is the pair of opposite sides whose
    mean length is nearer ``width_dbu``.
    """
    edges = np.roll(points, -1, axis=0) - points
    lengths = np.hypot(edges[:, 0], edges[:, 1])
    first = 0 if abs(lengths[[0, 2]].mean() - width_dbu) <= abs(lengths[[1, 3]].mean() - width_dbu) else 1
    sides = np.array([lengths[[first, first + 2]].mean(), lengths[[1 - first, 3 - first]].mean()])
    return points.mean(axis=0), sides, math.atan2(edges[first, 1], edges[first, 0])


def tolerances(geometry: FinGeometry) -> dict:
    """Rounding allowances (m, rad) of the centre, the sides and the rotation (see module docstring)."""
    d = geometry.dbu_m
    return {
        "centre_m": d / 2,
        "side_m": math.sqrt(2) * d,
        "rotation_rad": math.atan(math.sqrt(2) * d / (geometry.width_m - math.sqrt(2) * d)),
    }


def _count_fins(layout, top, layer: int) -> int:
    """Polygons and boxes on ``layer`` in the flattened top cell (texts excluded)."""

    def own(cell) -> int:
        shapes = cell.shapes(layer)
        texts = sum(1 for _ in shapes.each(type(shapes).STexts))
        return shapes.size() - texts

    total = own(top)
    for index in top.each_child_cell():
        child = layout.cell(index)
        total += own(child) * sum(1 for _ in child.each_parent_inst())
    return total


def _fins_at(db, top, layer: int, x: int, y: int) -> list[np.ndarray]:
    """Vertex arrays (k, 2) in dbu of the polygons touching the point (x, y), in top-cell coordinates."""
    found = []
    it = top.begin_shapes_rec_touching(layer, db.Box(x - 1, y - 1, x + 1, y + 1))
    while not it.at_end():
        shape = it.shape()
        if shape.is_polygon() or shape.is_box() or shape.is_simple_polygon():
            polygon = shape.polygon.transformed(it.trans())
            found.append(np.array([[p.x, p.y] for p in polygon.each_point_hull()], dtype=np.float64))
        it.next()
    return found


def verify_layout(
    path: str, design, geometry: FinGeometry, angles: int | None, samples: int = DEFAULT_SAMPLES, seed: int = 0
) -> VerifyReport:
    """Read ``path`` (GDSII or OASIS) with KLayout and check it against ``design`` (see module docstring)."""
    db = require_klayout()
    lens = design.lens
    rows = site_rows(lens.radius_m, lens.pitch_m)
    expected = site_count(rows)
    tol = tolerances(geometry)
    layout = db.Layout()
    try:
        layout.read(str(path))
    except RuntimeError as exc:
        return VerifyReport(False, expected, 0, 0, {}, tol, [f"KLayout cannot read the file: {exc}"])
    tops = layout.top_cells()
    layer = layout.find_layer(geometry.layer, geometry.datatype)
    if len(tops) != 1 or layer is None:
        failure = f"{len(tops)} top cells" if len(tops) != 1 else f"no layer {geometry.layer}/{geometry.datatype}"
        return VerifyReport(False, expected, 0, 0, {}, tol, [failure])
    top = tops[0]
    found = _count_fins(layout, top, layer)
    failures = [] if found == expected else [f"{found} fins in the file, {expected} sites in the pupil"]
    rng = np.random.default_rng(seed)
    index = rng.choice(expected, size=min(samples, expected), replace=False)
    i, j = sites_at(rows, index)
    theta = site_theta(lens, i, j)
    written = theta if angles is None else quantise(theta, angles)[1]
    d = geometry.dbu_m
    p = geometry.pitch_m / d
    width = geometry.width_m / d
    errors = {"centre_m": 0.0, "width_m": 0.0, "length_m": 0.0, "rotation_rad": 0.0, "phase_vs_design_rad": 0.0}
    for k in range(index.size):
        centre = np.array([i[k] * p, j[k] * p])
        fins = _fins_at(db, top, layer, *np.rint(centre).astype(int).tolist())
        if len(fins) != 1 or fins[0].shape[0] != 4:
            failures.append(f"site ({i[k]}, {j[k]}): {len(fins)} shapes, expected one quadrilateral")
            continue
        middle, sides, angle = measure_fin(fins[0], width)
        errors["centre_m"] = max(errors["centre_m"], float(np.max(np.abs(middle - centre))) * d)
        errors["width_m"] = max(errors["width_m"], abs(float(sides[0]) * d - geometry.width_m))
        errors["length_m"] = max(errors["length_m"], abs(float(sides[1]) * d - geometry.length_m))
        errors["rotation_rad"] = max(errors["rotation_rad"], abs(float(wrap(angle - written[k], math.pi))))
        errors["phase_vs_design_rad"] = max(
            errors["phase_vs_design_rad"], abs(float(wrap(2 * (angle - theta[k]), 2 * math.pi)))
        )
    limits = {
        "centre_m": tol["centre_m"],
        "width_m": tol["side_m"],
        "length_m": tol["side_m"],
        "rotation_rad": tol["rotation_rad"],
    }
    failures += [
        f"worst {key} {errors[key]:.3g} exceeds {limit:.3g}"
        for key, limit in limits.items()
        if errors[key] > limit * (1 + 1e-9)
    ]
    return VerifyReport(not failures, expected, found, int(index.size), errors, tol, failures[:10])
