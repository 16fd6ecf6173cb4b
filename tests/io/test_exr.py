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
from metalens_cli.io.exr import FORMAT, read_psf_cube, write_psf_cube

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
    write_psf_cube(path, **arguments)
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
    cube = read_psf_cube(path)
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
    assert read_psf_cube(path).rgb is None


def test_float64_input_is_stored_as_float32(tmp_path):
    path = tmp_path / "cube.exr"
    psf = np.random.default_rng(1).random((2, 3, 4, 4))
    write_example(path, psf=psf, rgb=None)
    assert np.array_equal(read_psf_cube(path).psf, psf.astype(np.float32))


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
        read_psf_cube(path)
    assert "\n" not in str(caught.value)
    assert str(caught.value).startswith(str(path))


def test_a_cube_without_design_and_version_is_read(tmp_path):
    """A measured cube written by another program needs only the five keys a reader uses."""
    path = tmp_path / "measured.exr"
    metadata = {k: v for k, v in valid_metadata(normalization="peak-one").items() if k not in ("design", "version")}
    write_raw(path, one_channel(), metadata)
    cube = read_psf_cube(path)
    assert "design" not in cube.metadata and cube.psf.shape == (1, 1, 5, 5)


def test_lossy_compression_is_refused(tmp_path):
    path = tmp_path / "lossy.exr"
    write_raw(path, one_channel(16), valid_metadata(), {"compression": OpenEXR.PXR24_COMPRESSION})
    with pytest.raises(InputError, match="PXR24_COMPRESSION is lossy"):
        read_psf_cube(path)


def test_non_exr_and_missing_files_are_refused(tmp_path):
    garbage = tmp_path / "garbage.exr"
    garbage.write_bytes(b"not an image")
    with pytest.raises(InputError, match="not a readable OpenEXR file"):
        read_psf_cube(garbage)
    with pytest.raises(InputError, match="no such file"):
        read_psf_cube(tmp_path / "missing.exr")


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
