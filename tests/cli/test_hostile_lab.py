"""Hostile input, round two (issue 29), on the lab commands: noiseless and empty PSF frames, a
material table's columns, a Cauchy fit below vacuum's index, a file-size limit or full disk under
`align` and `psf`, pitches no PSF can have. Each failure is one stderr line (docs/failures.md)
with its exit code, and a command's outputs are published together or not at all."""

import errno
import json
import os
import resource
from pathlib import Path

import cv2
import numpy as np
import pytest
from cli.test_align import capture  # tests/ is on the path (pyproject's pythonpath)
from cli.test_hostile import _cli
from synthetic import gaussian_spot, save_png, texture

from metalens_cli.cli.main import run


def _one_line(capsys, code: int, *words) -> None:
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and err.startswith("metalens: error: "), err
    assert "internal error" not in err and all(word in err for word in words), err


def _files(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def _full_disk(*args, **kwargs):
    """A writer failing as Python's own writes do on a full disk (the file's name unknown)."""
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


@pytest.fixture
def frames(tmp_path):
    """A noiseless simulated spot (16-bit, on a constant offset: its border has σ = 0), a flat
    frame and an all-saturated one, each with its manifest."""
    spot = gaussian_spot(64, 64, (31.4, 32.7), 2.0)
    cv2.imwrite(str(tmp_path / "spot.png"), np.rint(100 + 60000 * spot / spot.max()).astype(np.uint16))
    cv2.imwrite(str(tmp_path / "flat.png"), np.full((64, 64), 1000, np.uint16))
    cv2.imwrite(str(tmp_path / "full.png"), np.full((64, 64), 65535, np.uint16))
    for name in ("spot", "flat", "full"):
        (tmp_path / f"{name}.csv").write_text(f"file,wavelength,depth\nspot.png,530nm,inf\n{name}.png,630nm,inf\n")
    return tmp_path


def test_a_noiseless_simulated_spot_imports(frames, capsys):
    assert (
        run(
            [
                "psf",
                "import",
                str(frames / "spot.csv"),
                "-o",
                str(frames / "spot.exr"),
                "--pixel-pitch",
                "2um",
                "--json",
            ]
        )
        == 0
    )
    report = json.loads(capsys.readouterr().out)
    assert [f["centre_px"] for f in report["frames"]] == [[31.4, 32.7]] * 2 and report["warnings"] == []


@pytest.mark.parametrize(
    ("manifest", "args", "words"),
    [
        ("flat", [], "flat.csv line 3: flat.png has no light above the background noise"),
        (
            "full",
            ["--allow-saturated"],
            "full.csv line 3: full.png has no light above the background noise (4096 of its 4096 pixels saturated)",
        ),
    ],
)
def test_a_frame_without_a_spot_is_refused_naming_its_manifest_line(frames, capsys, manifest, args, words):
    before = _files(frames)
    assert (
        run(
            [
                "psf",
                "import",
                str(frames / f"{manifest}.csv"),
                "-o",
                str(frames / "p.exr"),
                "--pixel-pitch",
                "2um",
                *args,
            ]
        )
        == 2
    )
    _one_line(capsys, 2, words)
    assert _files(frames) == before


def test_psf_import_refuses_a_pitch_no_camera_has(frames, capsys):
    assert run(["psf", "import", str(frames / "spot.csv"), "-o", str(frames / "p.exr"), "--pixel-pitch", "1pm"]) == 2
    _one_line(capsys, 2, "--pixel-pitch: 0.001 nm is not a camera's pixel pitch (expected 0.1 µm to 100 µm")


@pytest.mark.parametrize("command", ["import", "compare"])
def test_psf_outputs_are_published_together_or_not_at_all(frames, capsys, monkeypatch, command):
    """--plot fails on a full disk: the cube (import) or the CSV (compare) is not left behind."""
    cube = frames / "spot.exr"
    assert run(["psf", "import", str(frames / "spot.csv"), "-o", str(cube), "--pixel-pitch", "2um", "--quiet"]) == 0
    capsys.readouterr()
    before = _files(frames)
    plotter = "psf_scan.plot_psf_scan" if command == "import" else "psf_compare.plot_psf_comparison"
    monkeypatch.setattr(f"metalens_cli.plotting.{plotter}", _full_disk)
    first = (
        ["import", str(frames / "spot.csv"), "-o", str(frames / "new.exr"), "--pixel-pitch", "2um"]
        if command == "import"
        else ["compare", str(cube), str(cube), "--csv", str(frames / "c.csv")]
    )
    assert run(["psf", *first, "--plot", str(frames / "p.png")]) == 1
    _one_line(capsys, 1, f"{frames / 'p.png'}: No space left on device")
    assert _files(frames) == before


def test_psf_compare_refuses_a_1_pm_cube(frames, capsys, tmp_path):
    """The cube a 1 pm camera pitch would give (written here as psf import no longer does):
    MTF50 would read 1e8 lp/mm against the simulation's hundred."""
    from metalens_cli.io.exr import read_exr_cube, write_exr_cube

    cube = frames / "spot.exr"
    assert run(["psf", "import", str(frames / "spot.csv"), "-o", str(cube), "--pixel-pitch", "2um", "--quiet"]) == 0
    c = read_exr_cube(cube)
    write_exr_cube(frames / "pm.exr", c.psf, c.wavelengths_m, c.depths_m, 1e-12, "measured")
    capsys.readouterr()
    assert run(["psf", "compare", str(frames / "pm.exr"), str(cube)]) == 2
    _one_line(capsys, 2, "MEASURED: its ", "pixels of 0.001 nm span", "less than half its shortest wavelength (530 nm)")


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    root = tmp_path_factory.mktemp("align")
    scene = texture(256, 256, 0)
    save_png(root / "ref.png", scene)
    save_png(root / "shot.png", capture(scene), bits=16)
    return root


def test_align_under_a_file_size_limit_exits_1_with_one_line(pair, tmp_path):
    """OpenCV's PNG writer failed at the limit, printed libpng's line and deleted its file, so the
    error read as a bad suffix (exit 2); now the image is encoded in memory and written by Python."""
    proc = _cli(
        "align",
        str(pair / "ref.png"),
        str(pair / "shot.png"),
        "-o",
        str(tmp_path / "a.png"),
        "--warp-out",
        str(tmp_path / "w.npz"),
        "--quiet",
        preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (65536, 65536)),
    )
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 1, err
    assert (
        err == f"metalens: error: {tmp_path / 'a.png'}: File too large (the file-size limit, ulimit -f, is reached)\n"
    )
    assert _files(tmp_path) == []


@pytest.mark.parametrize(
    "writer", ["metalens_cli.cli.align._write_image", "metalens_cli.imaging.registration.save_warp"]
)
def test_align_on_a_full_disk_publishes_neither_output(pair, tmp_path, capsys, monkeypatch, writer):
    monkeypatch.setattr(writer, _full_disk)
    assert (
        run(
            [
                "align",
                str(pair / "ref.png"),
                str(pair / "shot.png"),
                "-o",
                str(tmp_path / "a.png"),
                "--warp-out",
                str(tmp_path / "w.npz"),
                "--quiet",
            ]
        )
        == 1
    )
    _one_line(capsys, 1, "No space left on device")
    assert _files(tmp_path) == []


@pytest.mark.parametrize(
    ("table", "words"),
    [
        (
            "lam,index\n400,2.1\n700,2.0\n",
            "--material: film.csv: header 'lam,index' does not name its columns (expected a header "
            "naming its columns, in any order (wavelength_nm: wavelength_nm or wavelength",
        ),
        (None, "--material: cauchy:1,-0.2809 gives n = "),
    ],
)
def test_nanofin_refuses_a_material_it_cannot_read_as_given(tmp_path, capsys, table, words):
    material = "cauchy:1,-0.2809"
    if table is not None:
        (tmp_path / "film.csv").write_text(table)
        material = str(tmp_path / "film.csv")
    assert run(["nanofin", "efficiency", "--material", material, "--wavelengths", "530nm"]) == 2
    _one_line(capsys, 2, words)


def test_a_material_tables_columns_are_read_by_name(tmp_path, capsys):
    """k before n: η is that of the same film written n before k (it read n = k, η 0.175 for 0.577)."""
    efficiency = []
    for header, rows in (
        ("wavelength_nm,n,k", ("400,2.1,0.01", "700,2.0,0.0")),
        ("wavelength_nm,k,n", ("400,0.01,2.1", "700,0.0,2.0")),
    ):
        (tmp_path / "film.csv").write_text("\n".join((header, *rows)) + "\n")
        assert (
            run(["nanofin", "efficiency", "--material", str(tmp_path / "film.csv"), "--wavelengths", "530nm", "--json"])
            == 0
        )
        efficiency.append(json.loads(capsys.readouterr().out)["conversion_efficiency"])
    assert efficiency[0] == efficiency[1] and efficiency[0][0] > 0.3


def test_a_tiff_cube_past_the_file_size_limit_says_so(tmp_path):
    """tifffile's own OSError carries no errno: it printed "[Errno None] None: 'x.tif'" (issue 60)."""
    proc = _cli(
        *"psf-scan --design hyperbolic:532nm --f 1mm --aperture 0.1mm --pixels 128".split(),
        *"--wavelengths 520nm,540nm --depths inf --quiet -o".split(),
        str(tmp_path / "x.tif"),
        preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (65536, 65536)),
    )
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 1, err
    assert (
        err == f"metalens: error: {tmp_path / 'x.tif'}: File too large (the file-size limit, ulimit -f, is reached)\n"
    )
    assert _files(tmp_path) == []
