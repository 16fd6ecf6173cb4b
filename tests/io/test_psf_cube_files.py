"""PSF cubes as .npz, .mat and TIFF (docs/formats.md): exact round trips, layouts, files from
other programs, refusals with one line, atomic writing."""

import json
import math
import re
import zipfile

import numpy as np
import pytest
import scipy.io
import tifffile

import metalens_cli
from metalens_cli.errors import InputError
from metalens_cli.io import psf_cube_files
from metalens_cli.io.exr import FORMAT
from metalens_cli.io.psf_cube_files import CUBE_SUFFIXES, check_cube_size, read_psf_cube, write_psf_cube

WAVELENGTHS = np.array([450e-9, 530e-9, 630e-9])
DEPTHS = np.array([0.045, math.inf])
PITCH = 1.85e-6
FORMATS = [".exr", ".npz", ".mat", ".tif", ".tiff"]
MATLAB_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,62}")


def random_cube(n=9, seed=0):
    """psf (2, 3, n, n) and rgb (2, 3, n, n) float32 spanning many binades, subnormals included."""
    rng = np.random.default_rng(seed)
    psf = (rng.random((2, 3, n, n)) * 10.0 ** rng.integers(-44, 3, (2, 3, n, n))).astype(np.float32)
    psf[0, 0, 0, :3] = [0.0, np.float32(1e-45), np.nextafter(np.float32(1), np.float32(2))]
    return psf, rng.random((2, 3, n, n)).astype(np.float32)


def write_example(path, **changes):
    psf, rgb = random_cube()
    arguments = dict(
        psf=psf, wavelengths_m=WAVELENGTHS, depths_m=DEPTHS, pixel_pitch_m=PITCH, design="hyperbolic:532nm", rgb=rgb
    )
    arguments.update(changes)
    write_psf_cube(path, **arguments, extra={"na": 0.3, "accuracy": {"rel_l2": 1e-3}, "note": "µm ✓"})
    return arguments


def metadata_text(**changes):
    metadata = {
        "format": FORMAT,
        "wavelengths_m": [530e-9],
        "depths_m": [None],
        "pixel_pitch_m": PITCH,
        "normalization": "sum-to-one",
    }
    return json.dumps(metadata | changes)


def refused(path, reason):
    with pytest.raises(InputError, match=re.escape(reason)) as caught:
        read_psf_cube(path)
    assert "\n" not in str(caught.value) and str(caught.value).startswith(str(path))
    return str(caught.value)


# ---------------------------------------------------------------------------- round trips


def test_the_suffixes_are_the_formats():
    assert CUBE_SUFFIXES == tuple(FORMATS)


@pytest.mark.parametrize("suffix", FORMATS)
@pytest.mark.parametrize("with_rgb", [True, False])
def test_round_trip_is_exact_and_equals_the_exr_one(tmp_path, suffix, with_rgb):
    arguments = write_example(tmp_path / f"cube{suffix}", **({} if with_rgb else {"rgb": None}))
    write_example(tmp_path / "reference.exr", **({} if with_rgb else {"rgb": None}))
    cube, reference = read_psf_cube(tmp_path / f"cube{suffix}"), read_psf_cube(tmp_path / "reference.exr")
    assert cube.psf.dtype == np.float32 and cube.psf.shape == (2, 3, 9, 9)
    assert np.array_equal(cube.psf.view(np.uint32), arguments["psf"].view(np.uint32))  # bit for bit
    if with_rgb:
        assert cube.rgb.dtype == np.float32 and np.array_equal(cube.rgb, arguments["rgb"])
    else:
        assert cube.rgb is None
    assert np.array_equal(cube.wavelengths_m, WAVELENGTHS) and np.array_equal(cube.depths_m, DEPTHS)
    assert cube.pixel_pitch_m == PITCH
    assert cube.metadata == reference.metadata
    assert cube.metadata["note"] == "µm ✓" and cube.metadata["version"] == metalens_cli.__version__


def test_npz_layout(tmp_path):
    path = tmp_path / "cube.npz"
    arguments = write_example(path)
    with np.load(path, allow_pickle=False) as npz:
        members = {key: npz[key] for key in npz.files}
    assert sorted(members) == ["depths_m", "metadata", "pixel_pitch_m", "psf", "rgb", "wavelengths_m"]
    assert members["psf"].dtype == np.float32 and np.array_equal(members["psf"], arguments["psf"])
    assert members["rgb"].dtype == np.float32 and members["rgb"].shape == (2, 3, 9, 9)
    assert members["wavelengths_m"].dtype == np.float64 and np.array_equal(members["wavelengths_m"], WAVELENGTHS)
    assert np.array_equal(members["depths_m"], DEPTHS)  # inf for a source at infinity
    assert members["pixel_pitch_m"].shape == () and members["pixel_pitch_m"] == PITCH
    metadata = json.loads(str(members["metadata"]))
    assert metadata["format"] == FORMAT and metadata["depths_m"] == [0.045, None]
    assert all(info.compress_type == zipfile.ZIP_DEFLATED for info in zipfile.ZipFile(path).infolist())


def test_mat_layout(tmp_path):
    path = tmp_path / "cube.mat"
    arguments = write_example(path)
    assert path.read_bytes()[:19] == b"MATLAB 5.0 MAT-file"
    listed = {name: (shape, kind) for name, shape, kind in scipy.io.whosmat(path)}
    assert all(MATLAB_NAME.fullmatch(name) for name in listed)
    assert listed == {
        "psf": ((2, 3, 9, 9), "single"),
        "rgb": ((2, 3, 9, 9), "single"),
        "wavelengths_m": ((3, 1), "double"),
        "depths_m": ((2, 1), "double"),
        "pixel_pitch_m": ((1, 1), "double"),
        "metadata": (listed["metadata"][0], "char"),
    }
    loaded = scipy.io.loadmat(path)
    assert np.array_equal(loaded["psf"], arguments["psf"])  # psf(i, j, :, :) in MATLAB: depth i, wavelength j
    assert json.loads(loaded["metadata"][0])["format"] == FORMAT


def test_tiff_layout(tmp_path):
    path = tmp_path / "cube.tif"
    arguments = write_example(path)
    with tifffile.TiffFile(path) as tiff:
        pages = list(tiff.pages)
        assert len(pages) == 2 * 3 + 2 * 3
        names = [page.tags["PageName"].value for page in pages]
        assert names[:4] == ["psf.d00.w000", "psf.d00.w001", "psf.d00.w002", "psf.d01.w000"]
        assert names[6:9] == ["rgb.d00.R", "rgb.d00.G", "rgb.d00.B"]
        assert all(p.dtype == np.float32 and p.shape == (9, 9) and p.compression == 1 for p in pages)
        assert all(p.photometric == 1 and p.sampleformat == 3 for p in pages)  # MinIsBlack, IEEE float
        assert tiff.byteorder == "<" and not tiff.is_bigtiff
        assert json.loads(pages[0].description)["format"] == FORMAT
        assert all(not page.description for page in pages[1:])
        assert np.array_equal(pages[3 * 1 + 2].asarray(), arguments["psf"][1, 2])  # page I·W + J
        assert np.array_equal(pages[6 + 3 * 1 + 2].asarray(), arguments["rgb"][1, 2])  # page D·W + 3·I + C
    assert tifffile.imread(path).shape == (12, 9, 9)  # a plain stack to other tools


# ---------------------------------------------------------------------------- files from other programs


def test_a_matlab_style_file_is_read(tmp_path):
    """MATLAB's own save is v7 (compressed) with row vectors; trailing singleton dimensions dropped (N = 1)."""
    path = tmp_path / "matlab.mat"
    psf = np.full((1, 1, 1, 1), 0.5, np.float32)
    arrays = {"psf": psf[0, 0], "wavelengths_m": np.array([[530e-9]]), "depths_m": np.array([[np.inf]])}
    arrays |= {"pixel_pitch_m": PITCH, "metadata": metadata_text(), "notes": "another variable"}
    scipy.io.savemat(path, arrays, do_compression=True, oned_as="row")
    cube = read_psf_cube(path)
    assert cube.psf.shape == (1, 1, 1, 1) and cube.psf[0, 0, 0, 0] == 0.5 and np.isinf(cube.depths_m[0])


def test_a_compressed_big_endian_tiff_is_read(tmp_path):
    path = tmp_path / "other.tiff"
    plane = np.arange(25, dtype=np.float32).reshape(5, 5) / 25
    tifffile.imwrite(path, plane, byteorder=">", compression="zlib", description=metadata_text(), metadata=None)
    assert np.array_equal(read_psf_cube(path).psf[0, 0], plane)


def test_a_big_endian_npz_is_read(tmp_path):
    path = tmp_path / "other.npz"
    plane = np.linspace(0, 1, 16, dtype=">f4").reshape(1, 1, 4, 4)
    np.savez(path, psf=plane, wavelengths_m=[530e-9], depths_m=[np.inf], pixel_pitch_m=PITCH, metadata=metadata_text())
    cube = read_psf_cube(path)
    assert cube.psf.dtype == np.float32 and np.array_equal(cube.psf, plane)


# ---------------------------------------------------------------------------- refusals


@pytest.mark.parametrize("suffix", [".png", ".npy", ".h5", ""])
def test_other_suffixes_are_refused_and_nothing_is_written(tmp_path, suffix):
    with pytest.raises(InputError, match=r"does not end in \.exr, \.npz, \.mat, \.tif or \.tiff"):
        write_example(tmp_path / f"cube{suffix}")
    assert list(tmp_path.iterdir()) == []
    (tmp_path / f"cube{suffix}").write_bytes(b"anything")
    refused(tmp_path / f"cube{suffix}", "does not end in .exr, .npz, .mat, .tif or .tiff")


@pytest.mark.parametrize(
    ("suffix", "reason"),
    [(".npz", "not a readable .npz file"), (".mat", "not a readable MATLAB v5 .mat file"), (".tif", "TIFF")],
)
@pytest.mark.parametrize("damage", ["garbage", "empty", "truncated"])
def test_corrupt_files_are_refused_with_one_line(tmp_path, suffix, reason, damage):
    good = tmp_path / f"good{suffix}"
    write_example(good)
    data = {"garbage": b"II*\0" + b"\x07" * 200, "empty": b"", "truncated": good.read_bytes()[:1500]}[damage]
    path = tmp_path / f"bad{suffix}"
    path.write_bytes(data)
    with pytest.raises(InputError) as caught:
        read_psf_cube(path)
    assert "\n" not in str(caught.value) and str(caught.value).startswith(str(path))
    if damage != "truncated" or suffix != ".tif":  # a truncated TIFF may still list whole pages
        assert reason in str(caught.value)


def test_missing_file_and_matlab_73_are_refused(tmp_path):
    refused(tmp_path / "none.npz", "no such file")
    write_example(tmp_path / "cube.mat")
    header = bytearray((tmp_path / "cube.mat").read_bytes())
    header[124:126] = b"\x00\x02"  # the version of an HDF5-based v7.3 file
    (tmp_path / "v73.mat").write_bytes(bytes(header))
    refused(tmp_path / "v73.mat", "MATLAB v7.3 (HDF5) file (expected a MATLAB v5 or v7 file")


def _npz(path, **changes):
    arrays = {
        "psf": np.full((1, 1, 4, 4), 0.1, np.float32),
        "wavelengths_m": np.array([530e-9]),
        "depths_m": np.array([np.inf]),
        "pixel_pitch_m": np.float64(PITCH),
        "metadata": np.str_(metadata_text()),
    }
    np.savez(path, **{k: v for k, v in (arrays | changes).items() if v is not None})


@pytest.mark.parametrize(
    ("changes", "reason"),
    [
        ({"metadata": None}, "no member 'metadata' (not a metalens PSF cube)"),
        ({"metadata": np.float64(1)}, "member 'metadata' is not a string"),
        ({"metadata": np.str_("{no")}, "member 'metadata' is not valid JSON"),
        ({"metadata": np.str_(metadata_text(format="x"))}, "format is 'x'"),
        ({"psf": None}, "no member 'psf'"),
        ({"psf": np.full((1, 1, 4, 4), 0.1)}, "member 'psf' is float64"),
        ({"psf": np.zeros((1, 2, 4, 4), np.float32)}, "member 'psf' has shape (1, 2, 4, 4) for 1 depths × 1"),
        ({"psf": np.zeros((1, 1, 4, 5), np.float32)}, "square"),
        ({"psf": np.full((1, 1, 4, 4), np.nan, np.float32)}, "holds NaN"),
        ({"rgb": np.zeros((1, 3, 5, 5), np.float32)}, "channels differ in shape"),
        ({"wavelengths_m": np.array([531e-9])}, "member 'wavelengths_m' disagrees with the metadata's"),
        ({"depths_m": np.array([1.0])}, "member 'depths_m' disagrees"),
        ({"pixel_pitch_m": np.array([1e-6, 2e-6])}, "member 'pixel_pitch_m' is float64 of shape (2,)"),
        ({"depths_m": np.array(["inf"])}, "member 'depths_m' is <U3"),
    ],
)
def test_broken_npz_is_refused_with_one_line(tmp_path, changes, reason):
    path = tmp_path / "broken.npz"
    _npz(path, **changes)
    refused(path, reason)


def test_npz_is_read_without_pickle_and_within_the_memory_limit(tmp_path):
    path = tmp_path / "object.npz"
    _npz(path, psf=np.array([None, 1], dtype=object))
    refused(path, "member 'psf' holds object")
    bomb = tmp_path / "bomb.npz"
    with zipfile.ZipFile(bomb, "w") as archive, archive.open("psf.npy", "w") as handle:
        header = {"descr": "<f4", "fortran_order": False, "shape": (10**5, 10**5)}
        np.lib.format.write_array_header_1_0(handle, header)  # 40 GB claimed, no data
    refused(bomb, "member 'psf' claims 37.3 GiB; the limit is 4 GiB")


def test_broken_mat_and_tiff_are_refused_with_one_line(tmp_path):
    scipy.io.savemat(tmp_path / "cell.mat", {"psf": np.array([[1, "a"]], dtype=object), "metadata": metadata_text()})
    refused(tmp_path / "cell.mat", "variable 'psf' is a MATLAB cell")
    scipy.io.savemat(tmp_path / "axes.mat", {"psf": np.zeros((1, 1, 3, 3), np.float32), "metadata": metadata_text()})
    refused(tmp_path / "axes.mat", "no variable 'wavelengths_m', 'depths_m', 'pixel_pitch_m'")
    tifffile.imwrite(tmp_path / "plain.tif", np.zeros((4, 4), np.float32), metadata=None)
    refused(tmp_path / "plain.tif", "no JSON ImageDescription on the first page (not a metalens PSF cube)")
    tifffile.imwrite(
        tmp_path / "two.tif",
        np.zeros((2, 4, 4), np.float32),
        photometric="minisblack",
        description=metadata_text(),
        metadata=None,
    )
    refused(tmp_path / "two.tif", "2 pages for 1 depths × 1 wavelengths (expected 1 PSF pages, optionally then 3")
    tifffile.imwrite(tmp_path / "int.tif", np.zeros((4, 4), np.uint16), description=metadata_text(), metadata=None)
    refused(tmp_path / "int.tif", "page 0 is uint16 of shape (4, 4)")


# ---------------------------------------------------------------------------- writing


@pytest.mark.parametrize("suffix", [".npz", ".mat", ".tif"])
def test_writer_refuses_what_the_reader_would_and_writes_nothing(tmp_path, suffix):
    with pytest.raises(InputError, match="NaN"):
        write_example(tmp_path / f"cube{suffix}", psf=np.full((2, 3, 4, 4), np.nan, np.float32), rgb=None)
    with pytest.raises(InputError, match="psf of shape"):
        write_example(tmp_path / f"cube{suffix}", wavelengths_m=WAVELENGTHS[:2])
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("suffix", [".npz", ".mat", ".tif"])
def test_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path, monkeypatch, suffix):
    path = tmp_path / f"cube{suffix}"
    write_example(path)
    before = path.read_bytes()

    def failing(*args, **kwargs):
        raise RuntimeError("writer failed")

    target = {".npz": (np, "savez_compressed"), ".mat": (scipy.io, "savemat"), ".tif": (tifffile.TiffWriter, "write")}
    monkeypatch.setattr(*target[suffix], failing)
    with pytest.raises(RuntimeError, match="writer failed"):
        write_example(path)
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == [path.name]


def test_mat_variables_over_2_gib_are_refused_before_any_work(tmp_path):
    check_cube_size(tmp_path / "cube.mat", "-o", 2, 1000, 512)  # 2000 MiB of PSFs
    with pytest.raises(InputError, match=r"-o: a \.mat variable holds at most 2 GiB; this cube's PSFs take 2.93"):
        check_cube_size(tmp_path / "cube.mat", "-o", 3, 1000, 512)
    check_cube_size(tmp_path / "cube.mat", "-o", 682, 1, 512)  # rgb (D, 3, N, N) is the larger variable
    with pytest.raises(InputError, match="at most 2 GiB"):
        check_cube_size(tmp_path / "cube.mat", "-o", 683, 1, 512)
    check_cube_size(tmp_path / "cube.npz", "-o", 3, 1000, 512)
    assert psf_cube_files.MAT_MAX_VARIABLE_BYTES == 2**31 - 1
