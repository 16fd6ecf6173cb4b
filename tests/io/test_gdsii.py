"""GDSII writer and lens layout: record bytes, the geometry contract read back by gdstk, quantisation."""

import math
import struct

import numpy as np
import pytest
import torch

from metalens_cli.errors import InputError, MetalensError
from metalens_cli.io import gdsii
from metalens_cli.io.designs import resolve_design
from metalens_cli.io.layout import FinGeometry, export_layout, quantise, site_count, site_rows, site_theta, sites_at

PITCH, WIDTH, LENGTH = 395e-9, 305e-9, 125e-9
GEOMETRY = FinGeometry(PITCH, WIDTH, LENGTH)


@pytest.fixture
def gdstk():
    """gdstk as the independent reader (a test dependency)."""
    return pytest.importorskip("gdstk")


def small_design(aperture="20um"):
    return resolve_design(
        "hyperbolic:532nm", None, f_m=4e-3, aperture_m=float(aperture.rstrip("um")) * 1e-6, pitch_m=PITCH
    )


def records(data: bytes) -> list[tuple[int, bytes]]:
    """Split a GDSII byte string into (header word, data) records, checking the length fields."""
    out, at = [], 0
    while at < len(data):
        length, header = struct.unpack(">HH", data[at : at + 4])
        assert length >= 4 and length % 2 == 0
        out.append((header, data[at + 4 : at + length]))
        at += length
    assert at == len(data)  # lengths tile the file exactly
    return out


@pytest.mark.parametrize(
    "value, known",
    [
        (
            1e-3,
            "3e4189374bc6a7f0",
        ),  # the user-unit ratio of every 1 nm / 1 µm library (gdstk and KLayout write the same)
        (1e-9, "3944b82fa09b5a54"),  # the database unit in metres
        (1.0, "4110000000000000"),  # 16^(65−64) · 1/16
        (-2.5, "c128000000000000"),  # sign bit, 16^(65−64) · 0x28/256
        (0.0, "0000000000000000"),
    ],
)
def test_real8_known_bytes(value, known):
    assert gdsii.real8(value).hex() == known


def test_records_header_units_and_boundaries(tmp_path):
    path = tmp_path / "lens.gds"
    report = export_layout(small_design(), GEOMETRY, path)
    recs = records(path.read_bytes())
    headers = [h for h, _ in recs]
    assert recs[0] == (gdsii.HEADER, struct.pack(">h", 600))
    assert headers[1:4] == [gdsii.BGNLIB, gdsii.LIBNAME, gdsii.UNITS] and len(recs[1][1]) == 24
    assert recs[3][1].hex() == "3e4189374bc6a7f0" + "3944b82fa09b5a54"
    assert headers[-2:] == [gdsii.ENDSTR, gdsii.ENDLIB]
    xy = [data for (h, data), (prev, _) in zip(recs[1:], recs) if h == gdsii.XY and prev == gdsii.DATATYPE]
    assert headers.count(gdsii.BOUNDARY) == len(xy) == report.atoms
    ring = np.array([struct.unpack(">10i", data) for data in xy]).reshape(-1, 5, 2)
    np.testing.assert_array_equal(ring[:, 0], ring[:, 4])  # closed rings of 4 vertices (44-byte XY records)
    assert report.bytes == path.stat().st_size


def test_round_trip_through_gdstk(tmp_path, gdstk):
    design = small_design()
    path = tmp_path / "lens.gds"
    report = export_layout(design, GEOMETRY, path)
    library = gdstk.read_gds(str(path), unit=1e-9)  # coordinates in nm
    (top,) = library.top_level()
    assert top.name == "hyperbolic_532nm" and '"design":"hyperbolic:532nm"' in top.labels[0].text
    points = np.array([p.points for p in top.polygons])  # (n, 4, 2), gdstk drops the closing vertex
    # Aperture clipping: the fin centres are exactly the grid points within D/2 (brute force over a square).
    k = np.arange(-30, 31)
    ii, jj = np.meshgrid(k, k)
    inside = np.hypot(ii, jj) * PITCH <= design.lens.radius_m
    expected = {(int(a) * 395, int(b) * 395) for a, b in zip(ii[inside], jj[inside])}
    centres = points.mean(axis=1)
    assert report.atoms == len(points) == len(expected) == site_count(site_rows(design.lens.radius_m, PITCH))
    assert {(round(x), round(y)) for x, y in centres} == expected
    # Centres exact: the pitch is a whole number of database units and the fins are point-symmetric.
    np.testing.assert_array_equal(centres, np.rint(centres))
    edges = np.roll(points, -1, axis=1) - points
    sides = np.hypot(edges[..., 0], edges[..., 1])
    # Each vertex is within 0.5 nm of the exact corner per axis, so a side is within √2 nm.
    np.testing.assert_allclose(sides[:, [0, 2]], 305, atol=math.sqrt(2))
    np.testing.assert_allclose(sides[:, [1, 3]], 125, atol=math.sqrt(2))
    # Rotation of the width side against θ at the site, modulo π: within atan(√2 / (305 − √2)) = 4.7 mrad.
    i, j = np.rint(centres / 395).astype(np.int64).T
    theta = site_theta(design.lens, i, j)
    angle = np.arctan2(edges[:, 0, 1], edges[:, 0, 0])
    error = (angle - theta + math.pi / 2) % math.pi - math.pi / 2
    assert np.max(np.abs(error)) <= math.atan(math.sqrt(2) / (305 - math.sqrt(2)))


def test_radial_theta_matches_the_simulation_rule():
    lens = small_design("60um").lens
    rows = site_rows(lens.radius_m, lens.pitch_m)
    i, j = sites_at(rows, np.arange(site_count(rows)))
    expected = lens.phase_at_radius(torch.from_numpy(lens.pitch_m * np.hypot(i, j))).numpy() / 2
    np.testing.assert_allclose(site_theta(lens, i, j), expected, rtol=0, atol=1e-12)  # float64 round-off


def test_two_d_map_orientation(tmp_path, gdstk):
    """θ[row, col]: row along y, column along x, axis at (M//2, M//2)."""
    m = 51  # the smallest grid holding a 20 µm pupil at 395 nm
    cols = np.arange(m) - m // 2
    theta = np.add.outer(0.01 * cols, 0.001 * cols)  # θ = 0.01·j + 0.001·i for site (i, j): tells rows from columns
    npy = tmp_path / "theta.npy"
    np.save(npy, theta)
    design = resolve_design(str(npy), None, f_m=4e-3, aperture_m=20e-6, pitch_m=PITCH)
    path = tmp_path / "map.gds"
    export_layout(design, GEOMETRY, path)
    (top,) = gdstk.read_gds(str(path), unit=1e-9).top_level()
    assert top.name == "theta"
    points = np.array([p.points for p in top.polygons])
    i, j = np.rint(points.mean(axis=1) / 395).astype(int).T
    edge = points[:, 1] - points[:, 0]
    error = np.arctan2(edge[:, 1], edge[:, 0]) - (0.01 * j + 0.001 * i)
    assert np.max(np.abs(error)) <= 0.005  # dbu rounding bound, 4.7 mrad; a transposed map is off by up to 0.23 rad


def test_quantised_levels_phase_error(tmp_path, gdstk):
    theta = np.random.default_rng(1).uniform(-50, 50, 100_000)
    for levels in (2, 7, 64, 256):
        level, written = quantise(theta, levels)
        assert level.min() >= 0 and level.max() < levels
        turns = (written - level * math.pi / levels) / math.pi  # the written angle is the level's, modulo π
        np.testing.assert_allclose(turns, np.rint(turns), rtol=0, atol=1e-9)
        assert np.max(2 * np.abs(theta - written)) <= math.pi / levels + 1e-12
    design = small_design()
    path = tmp_path / "q.gds"
    report = export_layout(design, GEOMETRY, path, angles=16)
    rows = site_rows(design.lens.radius_m, PITCH)
    theta = site_theta(design.lens, *sites_at(rows, np.arange(site_count(rows))))
    assert report.max_phase_error_rad == pytest.approx(np.max(2 * np.abs(theta - quantise(theta, 16)[1])), abs=1e-12)
    assert 0 < report.max_phase_error_rad <= math.pi / 16
    library = gdstk.read_gds(str(path), unit=1e-9)
    (top,) = library.top_level()
    assert len(top.references) == report.atoms and not top.polygons
    for cell in library.cells:
        if cell is not top:  # one fin per level cell, at angle k·π/16, centred on the origin
            (fin,) = cell.polygons
            k = int(cell.name.rsplit("_A", 1)[1])
            edge = fin.points[1] - fin.points[0]
            rotation = (math.atan2(edge[1], edge[0]) - k * math.pi / 16 + math.pi / 2) % math.pi - math.pi / 2
            assert abs(rotation) <= 0.005 and np.allclose(fin.points.mean(axis=0), 0)


@pytest.mark.parametrize(
    "pitch, field",
    [
        (800e-9, "--design"),  # the map reaches far beyond the pupil: its pitch was not 800 nm
        (200e-9, "design"),  # the map cannot hold the pupil (refused by optics.lens.from_array)
    ],
)
def test_refuses_map_contradicting_pitch(tmp_path, pitch, field):
    npy = tmp_path / "theta.npy"
    np.save(npy, np.zeros((51, 51)))  # holds a 20 µm pupil at 395 nm: 2·25 + 1 sites
    with pytest.raises(InputError) as info:
        design = resolve_design(str(npy), None, f_m=4e-3, aperture_m=20e-6, pitch_m=pitch)
        export_layout(design, FinGeometry(pitch, 150e-9, 60e-9), tmp_path / "x.gds")
    assert info.value.field == field
    assert [p.name for p in tmp_path.iterdir()] == ["theta.npy"]  # nothing written


def test_refuses_overlapping_fins_and_a_second_pitch(tmp_path):
    with pytest.raises(InputError, match="overlap"):
        export_layout(small_design(), FinGeometry(PITCH, 380e-9, 125e-9), tmp_path / "x.gds")
    with pytest.raises(InputError, match="differs from the design"):
        export_layout(small_design(), FinGeometry(400e-9, WIDTH, LENGTH), tmp_path / "x.gds")
    assert list(tmp_path.iterdir()) == []


def test_oasis_converter_failure_leaves_nothing(tmp_path, monkeypatch):
    pytest.importorskip("klayout")
    from metalens_cli.io import layout

    monkeypatch.setattr(layout, "CONVERTER", "import sys; sys.exit('converter broke')")
    with pytest.raises(MetalensError, match="converter broke"):
        export_layout(small_design(), GEOMETRY, tmp_path / "x.oas", fmt="oas")
    assert list(tmp_path.iterdir()) == []
