"""psf-scan -o by suffix (.exr, .npz, .mat, .tif/.tiff), read back by mtf and psf compare."""

import json
from pathlib import Path

import numpy as np
import pytest

from metalens_cli.cli.main import run
from metalens_cli.io.psf_cube_files import read_psf_cube

PRESETS = Path(__file__).parents[2] / "presets"
SCAN = [
    "psf-scan",
    "--design",
    "hyperbolic:532nm",
    "--f",
    "4mm",
    "--aperture",
    "0.3mm",
    "--pixels",
    "17",
    "--pixel-pitch",
    "1.85um",
    "--preset",
    PRESETS / "split-spectrum.toml",  # R, G, B channel PSFs in the cube too
    "--wavelengths",
    "500:560:30nm",
    "--depths",
    "45mm,inf",
    "--quiet",
]
SUFFIXES = (".exr", ".npz", ".mat", ".tiff", ".tif")


def invoke(capsys, *args):
    code = run([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def cubes(tmp_path_factory):
    """The same scan written in every format."""
    folder = tmp_path_factory.mktemp("cubes")
    for suffix in SUFFIXES:
        assert run([str(a) for a in (*SCAN, "-o", folder / f"psf{suffix}")]) == 0
    return {suffix: folder / f"psf{suffix}" for suffix in SUFFIXES}


def test_every_format_holds_the_exr_cube_exactly(cubes):
    reference = read_psf_cube(cubes[".exr"])
    assert reference.psf.shape == (2, 3, 17, 17) and reference.rgb.shape == (2, 3, 17, 17)
    for suffix in SUFFIXES[1:]:
        cube = read_psf_cube(cubes[suffix])
        assert cube.psf.dtype == np.float32 and np.array_equal(cube.psf, reference.psf), suffix
        assert np.array_equal(cube.rgb, reference.rgb), suffix
        assert np.array_equal(cube.wavelengths_m, reference.wavelengths_m), suffix
        assert np.array_equal(cube.depths_m, reference.depths_m), suffix
        # The same scan twice: only the measured times differ.
        assert {**cube.metadata, "timing_s": None} == {**reference.metadata, "timing_s": None}, suffix


def test_mtf_gives_the_same_json_from_every_format(capsys, cubes):
    results = {}
    for suffix, path in cubes.items():
        code, out, err = invoke(capsys, "mtf", path, "--at", "50,100", "--json")
        assert code == 0, err
        report = json.loads(out)
        assert report.pop("file") == str(path)
        results[suffix] = report
    assert len(results[".exr"]["curves"]) == 2 * 3 + 2 * 3  # per (depth, λ), then per (depth, R/G/B)
    for suffix in SUFFIXES[1:]:
        assert results[suffix] == results[".exr"], suffix


def test_psf_compare_reads_every_format(capsys, cubes):
    code, out, err = invoke(capsys, "psf", "compare", cubes[".npz"], cubes[".tif"], "--json")
    assert code == 0, err
    pairs = json.loads(out)["pairs"]
    assert len(pairs) == 6 and all(pair["relative_l2"] == 0 and pair["peak_ratio"] == 1 for pair in pairs)
    code, out, err = invoke(capsys, "psf", "compare", cubes[".mat"], cubes[".exr"], "--json")
    assert code == 0 and all(pair["relative_l2"] == 0 for pair in json.loads(out)["pairs"]), err


@pytest.mark.parametrize("name", ["psf.png", "psf.npy", "psf.h5", "psf"])
def test_other_suffixes_exit_2_and_write_nothing(capsys, tmp_path, name):
    code, out, err = invoke(capsys, *SCAN, "-o", tmp_path / name)
    assert code == 2 and out == "" and err.count("\n") == 1
    assert "'-o' / '--output'" in err and "does not end in .exr, .npz, .mat, .tif or .tiff" in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("suffix", [".npz", ".mat", ".tiff"])
def test_corrupt_cubes_give_one_line(capsys, tmp_path, cubes, suffix):
    truncated = tmp_path / f"truncated{suffix}"
    truncated.write_bytes(cubes[suffix].read_bytes()[:700])
    garbage = tmp_path / f"garbage{suffix}"
    garbage.write_bytes(b"\x00not a cube\xff" * 50)
    for path in (truncated, garbage):
        code, out, err = invoke(capsys, "mtf", path, "--json")
        assert code == 2 and out == "" and err.count("\n") == 1 and "Traceback" not in err, err
        assert err.startswith(f"metalens: error: {path}: ")
    code, out, err = invoke(capsys, "mtf", tmp_path / "cube.dat")
    assert code == 2 and "does not end in .exr, .npz, .mat, .tif or .tiff" in err and err.count("\n") == 1
