"""The EXR PSF-cube contract (docs/formats.md) and atomic writing."""

import json
import math
import os
import re
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

import metalens_cli
from metalens_cli.errors import InputError
from metalens_cli.io.atomic import atomic_write
from metalens_cli.io.exr import FORMAT, read_exr_cube, write_exr_cube
from metalens_cli.io.psf_cube_files import check_cube_size, read_psf_cube, write_psf_cube

WAVELENGTHS = np.array([450e-9, 530e-9, 630e-9])
DEPTHS = np.array([0.045, math.inf])
PITCH = 1.85e-6


def random_cube(n=9, seed=0):
    """psf (2, 3, n, n) and rgb (2, 3, n, n) float32 with values spanning many binades."""
    rng = np.random.default_rng(seed)
    psf = (rng.random((2, 3, n, n)) * 10.0 ** rng.integers(-30, 3, (2, 3, n, n))).astype(np.float32)
    rgb = rng.random((2, 3, n, n)).astype(np.float32)
    return psf, rgb


def write_example(path, **changes):
    """A valid cube with optional argument changes."""
    psf, rgb = random_cube()
    arguments = dict(
        psf=psf, wavelengths_m=WAVELENGTHS, depths_m=DEPTHS, pixel_pitch_m=PITCH, design="hyperbolic:532nm", rgb=rgb
    )
    arguments.update(changes)
    write_exr_cube(path, **arguments)
    return arguments


def write_raw(path, channels, metadata=None, header_extra=None):
    """An EXR written with OpenEXR directly, to build files that break the contract."""
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    if metadata is not None:
        header["metalens"] = metadata if isinstance(metadata, str) else json.dumps(metadata)
    header.update(header_extra or {})
    OpenEXR.File(header, channels).write(str(path))


def valid_metadata(**changes):
    metadata = {
        "format": FORMAT,
        "wavelengths_m": [530e-9],
        "depths_m": [None],
        "pixel_pitch_m": PITCH,
        "normalization": "fraction-of-aperture-power",
        "design": "hyperbolic:532nm",
        "version": "0.1.0",
    }
    metadata.update(changes)
    return metadata


def one_channel(n=5, value=0.01):
    return {"psf.d00.w000": np.full((n, n), value, dtype=np.float32)}


# ---------------------------------------------------------------------------- round trip


def test_round_trip_is_exact(tmp_path):
    path = tmp_path / "cube.exr"
    arguments = write_example(path, extra={"na": 0.3, "f_m": 4e-3, "accuracy": {"rel_l2": 1e-3}})
    cube = read_exr_cube(path)
    assert cube.psf.dtype == np.float32 and cube.rgb.dtype == np.float32
    # Lossless compression of float32: bit-exact.
    assert np.array_equal(cube.psf, arguments["psf"])
    assert np.array_equal(cube.rgb, arguments["rgb"])
    assert np.array_equal(cube.wavelengths_m, WAVELENGTHS)
    assert np.array_equal(cube.depths_m, DEPTHS)
    assert cube.pixel_pitch_m == PITCH
    assert cube.metadata["na"] == 0.3 and cube.metadata["accuracy"] == {"rel_l2": 1e-3}
    assert cube.metadata["version"] == metalens_cli.__version__
    assert cube.metadata["depths_m"] == [0.045, None]
    assert cube.metadata["normalization"] == "fraction-of-aperture-power"


def test_file_layout_follows_the_contract(tmp_path):
    path = tmp_path / "cube.exr"
    write_example(path, rgb=None, design={"kind": "hyperbolic", "wavelength_m": 532e-9})
    exr = OpenEXR.File(str(path), separate_channels=True)
    header = exr.header()
    assert header["compression"] == OpenEXR.ZIP_COMPRESSION
    assert sorted(exr.channels()) == [f"psf.d{i:02d}.w{j:03d}" for i in range(2) for j in range(3)]
    assert all(channel.pixels.dtype == np.float32 for channel in exr.channels().values())
    metadata = json.loads(header["metalens"])
    assert metadata["format"] == "metalens-psf-cube/1"
    assert metadata["design"] == {"kind": "hyperbolic", "wavelength_m": 532e-9}
    assert read_exr_cube(path).rgb is None


def test_float64_input_is_stored_as_float32(tmp_path):
    path = tmp_path / "cube.exr"
    psf = np.random.default_rng(1).random((2, 3, 4, 4))
    write_example(path, psf=psf, rgb=None)
    assert np.array_equal(read_exr_cube(path).psf, psf.astype(np.float32))


# ---------------------------------------------------------------------------- refusing broken files


@pytest.mark.parametrize(
    ("metadata", "channels", "reason"),
    [
        (None, one_channel(), "no 'metalens' header"),
        ("{not json", one_channel(), "not valid JSON"),
        ("[1, 2]", one_channel(), "not a JSON object"),
        (valid_metadata(format="metalens-psf-cube/2"), one_channel(), "format is"),
        ({k: v for k, v in valid_metadata().items() if k != "pixel_pitch_m"}, one_channel(), "lacks pixel_pitch_m"),
        (valid_metadata(wavelengths_m=[530e-9, 630e-9]), one_channel(), "missing channels psf.d00.w001"),
        (
            valid_metadata(),
            {**one_channel(), "psf.d00.w001": np.zeros((5, 5), np.float32)},
            "unexpected channels psf.d00.w001",
        ),
        (valid_metadata(), {**one_channel(), "Z": np.zeros((5, 5), np.float32)}, "foreign channels Z"),
        (valid_metadata(), {**one_channel(), "rgb.d00.R": np.zeros((5, 5), np.float32)}, "missing channels rgb.d00.B"),
        (valid_metadata(), {"psf.d00.w000": np.zeros((4, 6), np.float32)}, "square"),
        (valid_metadata(), {"psf.d00.w000": np.zeros((5, 5), np.float16)}, "float16"),
        (valid_metadata(), {"psf.d00.w000": np.full((5, 5), np.nan, np.float32)}, "NaN"),
        (valid_metadata(depths_m=[-1.0]), one_channel(), "depths_m holds -1.0"),
        (valid_metadata(depths_m=[]), one_channel(), "depths_m is not a list"),
        (valid_metadata(pixel_pitch_m="1.85um"), one_channel(), "pixel_pitch_m"),
        (valid_metadata(design=3), one_channel(), "design"),
        (
            valid_metadata(wavelengths_m=[530e-9, 530e-9]),
            {**one_channel(), "psf.d00.w001": np.zeros((5, 5), np.float32)},
            "wavelengths_m holds 5.3e-07 twice",
        ),
    ],
)
def test_broken_files_are_refused_with_one_line(tmp_path, metadata, channels, reason):
    path = tmp_path / "broken.exr"
    write_raw(path, channels, metadata)
    with pytest.raises(InputError, match=re.escape(reason)) as caught:
        read_exr_cube(path)
    assert "\n" not in str(caught.value)
    assert str(caught.value).startswith(str(path))


def test_a_cube_without_design_and_version_is_read(tmp_path):
    """A measured cube written by another program needs only the five keys a reader uses."""
    path = tmp_path / "measured.exr"
    metadata = {k: v for k, v in valid_metadata(normalization="peak-one").items() if k not in ("design", "version")}
    write_raw(path, one_channel(), metadata)
    cube = read_exr_cube(path)
    assert "design" not in cube.metadata and cube.psf.shape == (1, 1, 5, 5)


def test_lossy_compression_is_refused(tmp_path):
    path = tmp_path / "lossy.exr"
    write_raw(path, one_channel(16), valid_metadata(), {"compression": OpenEXR.PXR24_COMPRESSION})
    with pytest.raises(InputError, match="PXR24_COMPRESSION is lossy"):
        read_exr_cube(path)


def test_non_exr_and_missing_files_are_refused(tmp_path):
    garbage = tmp_path / "garbage.exr"
    garbage.write_bytes(b"not an image")
    with pytest.raises(InputError, match="not a readable OpenEXR file"):
        read_exr_cube(garbage)
    with pytest.raises(InputError, match="no such file"):
        read_exr_cube(tmp_path / "missing.exr")


def test_writer_refuses_what_the_reader_would(tmp_path):
    path = tmp_path / "cube.exr"
    with pytest.raises(InputError, match="psf of shape"):
        write_example(path, wavelengths_m=WAVELENGTHS[:2])
    with pytest.raises(InputError, match="NaN"):
        write_example(path, psf=np.full((2, 3, 4, 4), np.nan, np.float32), rgb=None)
    with pytest.raises(InputError, match="overrides the keys"):
        write_example(path, extra={"format": "x"})
    with pytest.raises(InputError, match="strict JSON"):
        write_example(path, extra={"na": float("nan")})
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------- atomic writing


def test_failed_write_leaves_nothing_and_keeps_the_old_file(tmp_path):
    path = tmp_path / "cube.exr"
    write_example(path)
    before = path.read_bytes()
    with pytest.raises(InputError):
        write_example(path, extra={"bad": object()})  # not JSON-able
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cube.exr"]


def test_atomic_write_renames_on_success_and_cleans_up_on_failure(tmp_path):
    target = tmp_path / "out.txt"
    with atomic_write(target) as temporary:
        assert temporary.parent == tmp_path and temporary.suffix == ".txt" and temporary.exists()
        assert not target.exists()
        temporary.write_text("done")
    assert target.read_text() == "done"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.txt"]

    with pytest.raises(RuntimeError, match="boom"):
        with atomic_write(target) as temporary:
            temporary.write_text("half")
            raise RuntimeError("boom")
    assert target.read_text() == "done"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.txt"]


def test_atomic_write_gives_ordinary_permissions(tmp_path):
    umask = os.umask(0)
    os.umask(umask)
    with atomic_write(tmp_path / "a.bin") as temporary:
        temporary.write_bytes(b"x")
    assert (tmp_path / "a.bin").stat().st_mode & 0o777 == 0o666 & ~umask


def test_exr_writer_failure_inside_openexr_leaves_nothing(tmp_path, monkeypatch):
    def failing_write(self, filename):
        Path(filename).write_bytes(b"half an EXR")
        raise RuntimeError("disk full")

    monkeypatch.setattr(OpenEXR.File, "write", failing_write)
    with pytest.raises(RuntimeError, match="disk full"):
        write_example(tmp_path / "cube.exr")
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------- field cubes


def field_extra(angles=(0.0, 0.05, 0.1), **changes):
    """The field keys of fields at ``angles`` along +x, f = 4 mm, and any changes."""
    chief = [[4e-3 * math.tan(a), 0.0] for a in angles]
    extra = {
        "field_angles_rad": list(angles),
        "field_azimuth_rad": 0.0,
        "chief_ray_m": chief,
        "window_centre_px": [[round(x / PITCH), 0] for x, _ in chief],
    }
    extra.update(changes)
    return extra


def random_field_cube(fields=3, n=9, seed=0):
    rng = np.random.default_rng(seed)
    psf = (rng.random((fields, 2, 3, n, n)) * 10.0 ** rng.integers(-30, 3, (fields, 2, 3, n, n))).astype(np.float32)
    return psf, rng.random((fields, 2, 3, n, n)).astype(np.float32)


def write_field_example(path, fields=3, **changes):
    psf, rgb = random_field_cube(fields)
    angles = tuple(0.05 * k for k in range(fields))
    arguments = dict(
        psf=psf,
        wavelengths_m=WAVELENGTHS,
        depths_m=DEPTHS,
        pixel_pitch_m=PITCH,
        design="hyperbolic:532nm",
        rgb=rgb,
        extra={**field_extra(angles), "field_kept": np.full((fields, 2, 3), 0.9).tolist()},
    )
    arguments.update(changes)
    write_exr_cube(path, **arguments)
    return arguments


def test_field_cube_round_trip_is_exact(tmp_path):
    path = tmp_path / "field.exr"
    arguments = write_field_example(path)
    cube = read_exr_cube(path)
    assert cube.is_field_cube and cube.field_count == 3
    assert np.array_equal(cube.field_psf, arguments["psf"]) and np.array_equal(cube.field_rgb, arguments["rgb"])
    assert cube.field_psf.dtype == np.float32 and cube.field_rgb.dtype == np.float32
    assert np.array_equal(cube.psf, arguments["psf"][0]) and np.array_equal(cube.rgb, arguments["rgb"][0])
    assert np.array_equal(cube.field_angles_rad, [0.0, 0.05, 0.1]) and cube.field_azimuth_rad == 0.0
    assert cube.window_centre_px.dtype == np.int64
    assert cube.window_centre_px.tolist() == arguments["extra"]["window_centre_px"]
    assert cube.chief_ray_m.tolist() == arguments["extra"]["chief_ray_m"]
    names = sorted(OpenEXR.File(str(path), separate_channels=True).channels())
    assert len(names) == 3 * 2 * (3 + 3)
    assert {"psf.d01.w002", "rgb.d00.R", "psf.f01.d00.w000", "psf.f02.d01.w002", "rgb.f02.d01.B"} <= set(names)
    assert not any(name.startswith(("psf.f00", "rgb.f00")) for name in names)


def test_an_on_axis_reader_reads_field_0(tmp_path):
    """Field 0 sits under the on-axis names: reading only those (what a reader that knows nothing of
    fields does) gives field 0; the on-axis properties of a cube give one field at 0."""
    path = tmp_path / "field.exr"
    arguments = write_field_example(path)
    channels = OpenEXR.File(str(path), separate_channels=True).channels()
    on_axis = np.array([[channels[f"psf.d{i:02d}.w{j:03d}"].pixels for j in range(3)] for i in range(2)])
    assert np.array_equal(on_axis, arguments["psf"][0]) and np.array_equal(read_exr_cube(path).psf, on_axis)
    plain = tmp_path / "plain.exr"
    write_example(plain)
    cube = read_exr_cube(plain)
    assert not cube.is_field_cube and cube.field_psf is None and cube.field_rgb is None and cube.field_count == 1
    assert cube.field_angles_rad.tolist() == [0.0] and cube.window_centre_px.tolist() == [[0, 0]]
    assert np.array_equal(cube.psf_by_field[0], cube.psf) and np.array_equal(cube.rgb_by_field[0], cube.rgb)


def test_a_4d_psf_with_field_keys_is_a_field_cube_of_one_field(tmp_path):
    path = tmp_path / "one.exr"
    psf, rgb = random_cube()
    write_example(path, psf=psf, rgb=rgb, extra=field_extra((0.2,)))
    cube = read_exr_cube(path)
    assert cube.is_field_cube and cube.field_psf.shape == (1, 2, 3, 9, 9) and np.array_equal(cube.field_psf[0], psf)
    assert sorted(OpenEXR.File(str(path), separate_channels=True).channels()) == sorted(
        [f"psf.d{i:02d}.w{j:03d}" for i in range(2) for j in range(3)]
        + [f"rgb.d{i:02d}.{c}" for i in range(2) for c in "RGB"]
    )


def field_metadata(**changes):
    """Header of a one-depth, one-wavelength field cube of 2 fields."""
    return valid_metadata(**{**field_extra((0.0, 0.1)), **changes})


def field_channels(n=5, fields=2):
    return {
        ("psf.d00.w000" if k == 0 else f"psf.f{k:02d}.d00.w000"): np.full((n, n), 0.01, np.float32)
        for k in range(fields)
    }


@pytest.mark.parametrize(
    ("metadata", "channels", "reason"),
    [
        (field_metadata(), field_channels(fields=1), "missing channels psf.f01.d00.w000 for 2 fields × 1 depths"),
        (field_metadata(), field_channels(fields=3), "unexpected channels psf.f02.d00.w000 for 2 fields"),
        (field_metadata(), {**field_channels(), "psf.f00.d00.w000": np.zeros((5, 5), np.float32)}, "unexpected"),
        (valid_metadata(), field_channels(), "unexpected channels psf.f01.d00.w000 (field channels need"),
        (
            field_metadata(),
            {**field_channels(), "rgb.d00.R": np.zeros((5, 5), np.float32)},
            "missing channels rgb.d00.B",
        ),
        (field_metadata(chief_ray_m=[[0.0, 0.0]]), field_channels(), "chief_ray_m holds 1 entries for 2 field angles"),
        (field_metadata(window_centre_px=[[0, 0]]), field_channels(), "window_centre_px holds 1 entries for 2"),
        (field_metadata(window_centre_px=[[0, 0], [54.5, 0]]), field_channels(), "window_centre_px holds [54.5, 0]"),
        (field_metadata(window_centre_px=[[0, 0], [54.0, 0]]), field_channels(), "[column, row] of integers"),
        (field_metadata(window_centre_px=[[0, 0], [54]]), field_channels(), "window_centre_px holds [54]"),
        (field_metadata(field_angles_rad=[0.0, 1.6]), field_channels(), "field_angles_rad holds 1.6"),
        (field_metadata(field_angles_rad=[0.1, 0.1]), field_channels(), "field_angles_rad holds 0.1 twice"),
        (field_metadata(field_angles_rad=[]), field_channels(), "field_angles_rad is not a list of 1 to 100"),
        (field_metadata(field_azimuth_rad="0"), field_channels(), "field_azimuth_rad is '0'"),
        (
            {k: v for k, v in field_metadata().items() if k != "chief_ray_m"},
            field_channels(),
            "has field_angles_rad but lacks chief_ray_m",
        ),
        (field_metadata(field_kept=[[[0.9]]]), field_channels(), "field_kept is not F × D × W nested lists"),
        (field_metadata(field_kept=[[[0.9]], [[-0.1]]]), field_channels(), "field_kept holds -0.1"),
    ],
)
def test_broken_field_cubes_are_refused_with_one_line(tmp_path, metadata, channels, reason):
    path = tmp_path / "broken.exr"
    write_raw(path, channels, metadata)
    with pytest.raises(InputError, match=re.escape(reason)) as caught:
        read_exr_cube(path)
    assert "\n" not in str(caught.value) and str(caught.value).startswith(str(path))


def test_a_valid_raw_field_cube_is_read(tmp_path):
    """The reader's rules above, met by a file written with OpenEXR directly (as docs/formats.md shows)."""
    path = tmp_path / "raw.exr"
    write_raw(path, field_channels(), field_metadata(field_kept=[[[0.9]], [[0.8]]]))
    assert read_exr_cube(path).field_psf.shape == (2, 1, 1, 5, 5)


def test_the_field_cube_writer_refuses_what_the_reader_would(tmp_path):
    path = tmp_path / "cube.exr"
    psf, rgb = random_field_cube()
    with pytest.raises(InputError, match=r"psf of shape \(3, 2, 3, 9, 9\) for 2 depths × 3 wavelengths"):
        write_example(path, psf=psf, rgb=rgb)  # no field keys
    with pytest.raises(InputError, match="for 2 fields × 2 depths × 3 wavelengths"):
        write_example(path, psf=psf, rgb=rgb, extra=field_extra((0.0, 0.1)))
    with pytest.raises(InputError, match="rgb of shape"):
        write_example(path, psf=psf, rgb=rgb[:, 0], extra=field_extra())
    with pytest.raises(InputError, match="window_centre_px holds"):
        write_example(path, psf=psf, rgb=rgb, extra=field_extra(window_centre_px=[[0, 0], [1.5, 0], [3, 0]]))
    with pytest.raises(InputError, match="lacks field_azimuth_rad"):
        write_example(path, psf=psf, rgb=rgb, extra={"field_angles_rad": [0.0, 0.1, 0.2]})
    assert list(tmp_path.iterdir()) == []
    write_example(path, psf=psf, rgb=None, extra=field_extra(window_centre_px=np.array([[0, 0], [108, 0], [216, 0]])))
    assert read_exr_cube(path).window_centre_px[2].tolist() == [216, 0]  # numpy field keys taken as their lists


@pytest.mark.parametrize("suffix", [".npz", ".mat", ".tif"])
def test_other_formats_refuse_a_field_cube(tmp_path, suffix):
    psf, rgb = random_field_cube()
    path = tmp_path / f"cube{suffix}"
    arguments = (psf, WAVELENGTHS, DEPTHS, PITCH, "x")
    with pytest.raises(InputError, match=re.escape(f"a field cube is written as .exr, not {suffix}")):
        write_psf_cube(path, *arguments, rgb=rgb, extra=field_extra())
    with pytest.raises(InputError, match="a field cube is written as .exr"):
        write_psf_cube(path, psf[0], *arguments[1:], extra=field_extra((0.0,)))  # one field too
    with pytest.raises(InputError, match="a field cube is written as .exr"):
        check_cube_size(path, "-o", 2, 3, 9, field_cube=True)
    assert list(tmp_path.iterdir()) == []
    check_cube_size(tmp_path / "cube.exr", "-o", 2, 3, 9, field_cube=True)
    write_psf_cube(tmp_path / "cube.exr", *arguments, rgb=rgb, extra=field_extra())
    assert np.array_equal(read_psf_cube(tmp_path / "cube.exr").field_rgb, rgb)
