"""Hostile input over every command: bad paths, devices, corrupt files, non-finite options, huge
requests. Each case must end in exactly one stderr line ``metalens: error: …`` naming what is
wrong, the documented exit code (2 bad input, 1 environment), no traceback, no internal error,
and no file left behind or destroyed (docs/failures.md)."""

import json
import os
import signal
import stat
import subprocess
import sys
import time
import zlib
from pathlib import Path

import numpy as np
import pytest

from metalens_cli.cli.main import run
from metalens_cli.io.image_files import write_exr_rgb

ROOT = Path(__file__).parents[2]
PRESETS = ROOT / "presets"
TINY = ROOT / "tests" / "design" / "tiny.toml"
LENS = ["--f", "1mm", "--aperture", "0.1mm"]
SCAN = [
    "psf-scan",
    "--design",
    "hyperbolic:532nm",
    *LENS,
    "--pixels",
    "16",
    "--wavelengths",
    "532nm",
    "--depths",
    "inf",
]
SIM = ["hyperbolic:532nm", *LENS, "--pixels", "32", "--wavelengths", "520nm,540nm", "--images", "{imgs}"]
NPY, NPY_REST = ["psf-scan", "--design"], [*LENS, "--pitch", "395nm", *SCAN[5:], "-o", "{tmp}/n.exr"]
GDS = ["export-gds", "--design", "hyperbolic:532nm", *LENS, "--pitch", "395nm", "--width", "200nm", "--length", "100nm"]


def cv2_write(path: Path, image: np.ndarray) -> None:
    import cv2

    assert cv2.imwrite(str(path), image)


def _png_header(path: Path, width: int, height: int) -> None:
    """A PNG whose header claims width × height pixels, with one tiny (truncated) data chunk."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return len(data).to_bytes(4, "big") + kind + data + zlib.crc32(kind + data).to_bytes(4, "big")

    ihdr = width.to_bytes(4, "big") + height.to_bytes(4, "big") + bytes([8, 0, 0, 0, 0])
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 1024)) + chunk(b"IEND", b"")
    )


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    """A folder of hostile inputs, made once: their paths by name (dots as underscores) for the case table."""
    root = tmp_path_factory.mktemp("hostile")
    paths = {"tmp": root}
    (root / "folder.exr").mkdir()
    os.mkfifo(root / "fifo.csv")
    (root / "a_file").write_text("x")
    (root / "link.csv").symlink_to(root / "a_file")
    (root / "deep.toml").write_text("a = " + "[" * 100_000 + "]" * 100_000 + "\n")
    (root / "user_files").mkdir()
    (root / "user_files" / "theta.npy").write_bytes(b"the user's own file")
    _png_header(root / "fake.png", 0, 0)
    cv2_write(root / "one.png", np.zeros((1, 1), np.uint8))
    cv2_write(root / "mask.png", np.full((8, 8), 255, np.uint8))
    (root / "latin1.toml").write_bytes(b"name = '\xe9\xff'\n")
    (root / "big.toml").write_bytes(b"#" * (5 << 20))
    with open(root / "huge.npy", "wb") as handle:
        np.lib.format.write_array_header_1_0(handle, {"descr": "<f4", "fortran_order": False, "shape": (10**6, 10**6)})
        handle.write(b"\0" * 64)
    np.save(root / "short.npy", np.zeros((64, 64)))
    (root / "short.npy").write_bytes((root / "short.npy").read_bytes()[:2000])
    np.save(root / "nan.npy", np.full((8, 8), np.nan))
    (root / "garbage.exr").write_bytes(b"v/1\x01" + b"\0" * 40)
    _png_header(root / "bomb.png", 60000, 60000)
    write_exr_rgb(root / "nan.exr", np.full((3, 32, 32), np.nan, np.float32))
    write_exr_rgb(root / "negative.exr", np.full((3, 32, 32), -0.5, np.float32))
    for name, frame in (
        ("bomb", "bomb.png"),
        ("nanframe", "nan.npy"),
        ("hugeframe", "huge.npy"),
        ("fifoframe", "fifo.csv"),
    ):
        (root / f"m_{name}.csv").write_text(f"file,wavelength,depth\n{frame},530nm,inf\n")
    (root / "m_ok.csv").write_text("file,wavelength,depth\nmask.png,530nm,inf\n")
    (root / "nopairs").mkdir()
    (root / "pairs" / "gt").mkdir(parents=True)
    cv2_write(root / "pairs" / "gt" / "a.png", np.zeros((8, 8), np.uint8))
    for folder in ("unobstructed", "obstructed"):
        (root / "pairs" / "lens" / folder).mkdir(parents=True)
        cv2_write(root / "pairs" / "lens" / folder / "a.png", np.zeros((8, 8), np.uint8))
    (root / "imgs").mkdir()
    write_exr_rgb(root / "imgs" / "grey.exr", np.full((3, 32, 32), 0.5, np.float32))
    assert run([*SCAN, "-o", str(root / "cube.exr"), "--quiet"]) == 0
    (root / "truncated.exr").write_bytes((root / "cube.exr").read_bytes()[:600])
    preset = (PRESETS / "split-spectrum.toml").read_text()
    variants = {
        "overlap.toml": preset.replace('widths = ["22nm", "20nm", "28nm"]', 'widths = ["22nm", "200nm", "28nm"]'),
        "camera.toml": preset.replace('camera_response = "Nikon 5100 (NPL)"', 'camera_response = "Kodak Brownie"'),
        "range.toml": preset.replace('wavelength_range = "400nm:700nm"', 'wavelength_range = "1pm:2pm"'),
        "name.toml": preset.replace('name = "split-spectrum"', 'name = "../../x"'),
        "drops.toml": preset.replace('drop_radius = "0.2mm:0.8mm"', 'drop_radius = "0.2mm:inf"'),
        "rate.toml": preset.replace("learning_rate = ", "learning_rate = 1e308 # "),
    }
    assert all(text != preset for text in variants.values())
    for name, text in variants.items():
        (root / name).write_text(text)
    return {k: str(v) for k, v in {**paths, **{p.name.replace(".", "_"): p for p in root.iterdir()}}.items()}


CASES = {  # argv (with {names} from the bench), exit code, words the one error line must hold
    # 1. output paths, every writer
    "psf-scan -o in a missing folder": ([*SCAN, "-o", "{tmp}/nope/x.exr"], 2, "does not exist"),
    "psf-scan -o onto a folder": ([*SCAN, "-o", "{folder_exr}"], 2, "is a folder"),
    "psf-scan -o in /proc (unwritable)": ([*SCAN, "-o", "/proc/x.exr"], 2, "cannot write in folder"),
    "psf-scan -o name too long": ([*SCAN, "-o", "{tmp}/" + "a" * 300 + ".exr"], 2, "bytes"),
    "psf-scan -o without .exr": ([*SCAN, "-o", "{tmp}/x.png"], 2, "does not end in .exr"),
    "psf-scan -o a bare suffix": ([*SCAN, "-o", "{tmp}/.exr"], 2, "'.exr' has no name before its suffix"),
    "psf-scan --plot a bare suffix": ([*SCAN, "-o", "{tmp}/y.exr", "--plot", "{tmp}/.png"], 2, "no name before"),
    "psf-scan --plot in a missing folder": (
        [*SCAN, "-o", "{tmp}/y.exr", "--plot", "{tmp}/nope/p.png"],
        2,
        "does not exist",
    ),
    "psf-scan --plot unknown format": (
        [*SCAN, "-o", "{tmp}/y.exr", "--plot", "{tmp}/p.xyz"],
        2,
        "does not end in .png",
    ),
    "mtf --csv onto its input": (["mtf", "{cube_exr}", "--csv", "{cube_exr}"], 2, "also an input"),
    "mtf --csv onto a FIFO": (["mtf", "{cube_exr}", "--csv", "{fifo_csv}"], 2, "not a regular file"),
    "mtf --csv onto a symbolic link": (["mtf", "{cube_exr}", "--csv", "{link_csv}"], 2, "symbolic link"),
    "mtf --csv onto /dev/null": (["mtf", "{cube_exr}", "--csv", "/dev/null"], 2, "not a regular file"),
    "export-gds -o in a missing folder": ([*GDS, "-o", "{tmp}/nope/x.gds"], 2, "does not exist"),
    "obstruction preview -o not PNG": (["obstruction", "preview", "-o", "{tmp}/x.jpg"], 2, "does not end in .png"),
    "evaluate --csv in a missing folder": (["evaluate", *SIM, "--csv", "{tmp}/nope/x.csv"], 2, "does not exist"),
    "simulate -o under a file": (["simulate", *SIM, "-o", "{a_file}/out"], 2, "not a folder"),
    "optimize -o under a file": (["optimize", str(TINY), "-o", "{a_file}/run"], 2, "not a folder"),
    "symmetry --plot in a missing folder": (
        ["symmetry", "--f", "4mm", "--lambda-d", "450nm", "--plot", "{tmp}/nope/s.png"],
        2,
        "does not exist",
    ),
    "bands check --plot in a missing folder": (
        ["bands", "check", "--preset", str(PRESETS / "split-spectrum.toml"), "--plot", "{tmp}/nope/b.png"],
        2,
        "does not exist",
    ),
    "mtf: --csv and --plot on one path": (
        ["mtf", "{cube_exr}", "--csv", "{tmp}/same.png", "--plot", "{tmp}/same.png"],
        2,
        "is also --csv's output",
    ),
    "obstruction file: mask as its own output": (
        ["obstruction", "preview", "--pixels", "16", "--kinds", "file:{mask_png}", "-o", "{mask_png}"],
        2,
        "also an input",
    ),
    "optimize into a folder of user files": (["optimize", str(TINY), "-o", "{user_files}"], 2, "is not empty"),
    # 2. input files
    "preset nested 100 000 deep": (["preset", "show", "{deep_toml}"], 2, "too deeply"),
    "image with a broken header": (["mtf", "--edge", "{fake_png}"], 2, "not a readable image"),
    "slanted edge of 1 × 1 pixel": (["mtf", "--edge", "{one_png}"], 2, "at least"),
    "preset show: not UTF-8": (["preset", "show", "{latin1_toml}"], 2, "UTF-8"),
    "preset show /dev/zero": (["preset", "show", "/dev/zero"], 2, "not a regular file"),
    "preset show: 5 MiB": (["preset", "show", "{big_toml}"], 2, "larger than"),
    "design .npy claiming 4 TB": ([*NPY, "{huge_npy}", *NPY_REST], 2, "claims"),
    "design .npy truncated": ([*NPY, "{short_npy}", *NPY_REST], 2, "truncated"),
    "design .npy of NaN": ([*NPY, "{nan_npy}", *NPY_REST], 2, "NaN"),
    "mtf of a truncated EXR": (["mtf", "{truncated_exr}", "--json"], 2, "corrupt or truncated"),
    "mtf of garbage": (["mtf", "{garbage_exr}", "--json"], 2, "not a readable OpenEXR file"),
    # the size itself, read from the header past Pillow's own bomb check (it said "over 179 megapixels")
    "mtf --edge decompression bomb": (["mtf", "--edge", "{bomb_png}"], 2, "60000 × 60000 pixels; the limit is"),
    "simulate NaN image": (["simulate", *SIM[:-1], "{nan_exr}", "-o", "{tmp}/s1"], 2, "NaN"),
    "simulate negative image": (["simulate", *SIM[:-1], "{negative_exr}", "-o", "{tmp}/s2"], 2, "negative"),
    # 3. validation before work
    "--photons nan": (["simulate", *SIM, "--photons", "nan", "-o", "{tmp}/s3"], 2, "not a finite number"),
    "--read-noise inf": (["simulate", *SIM, "--read-noise", "inf", "-o", "{tmp}/s4"], 2, "--read-noise"),
    "--alpha-gain nan": (["evaluate", *SIM, "--alpha-gain", "nan"], 2, "not a finite number"),
    "--device meta": ([*SCAN, "-o", "{tmp}/d.exr", "--device", "meta"], 2, "unknown device"),
    "--device xpu": (["simulate", *SIM, "--device", "xpu", "-o", "{tmp}/s5"], 2, "unknown device"),
    "--wavelengths 1m": ([*SCAN[:-4], "--wavelengths", "1m", "-o", "{tmp}/w.exr"], 2, "not an optical wavelength"),
    "1141 wavelengths": ([*SCAN[:-4], "--wavelengths", "430:1000:0.5nm", "-o", "{tmp}/w.exr"], 2, "at most 1000"),
    "one wavelength with a preset's filter": (
        [
            "psf-scan",
            "--design",
            "hyperbolic:532nm",
            "--preset",
            str(PRESETS / "split-spectrum.toml"),
            "--wavelengths",
            "530nm",
            "-o",
            "{tmp}/w.exr",
        ],
        2,
        "--wavelengths: channel quadrature",
    ),
    "101 depths": ([*SCAN[:-2], "--depths", "1m:101m:1m", "-o", "{tmp}/w.exr"], 2, "at most 100"),
    "preset: overlapping bands": (["preset", "show", "{overlap_toml}"], 2, "overlap"),
    "preset: unknown camera": (["preset", "show", "{camera_toml}"], 2, "unknown camera"),
    "preset: sensor range 1pm:2pm": (["preset", "show", "{range_toml}"], 2, "not an optical wavelength"),
    "preset: infinite drops": (["preset", "show", "{drops_toml}"], 2, "obstruction.drop_radius"),
    "preset: learning rate 1e308": (["preset", "show", "{rate_toml}"], 2, "optimize.learning_rate"),
    "--read-noise 1e300": (["simulate", *SIM, "--read-noise", "1e300", "-o", "{tmp}/s7"], 2, "--read-noise"),
    "--photons 1e-300": (["simulate", *SIM, "--photons", "1e-300", "-o", "{tmp}/s8"], 2, "at least 1"),
    "--images ''": (["simulate", *SIM[:-1], "", "-o", "{tmp}/s9"], 2, "--images: is empty"),
    "export-gds --format oas into .gds": ([*GDS, "-o", "{tmp}/f.gds", "--format", "oas"], 2, "extension says gds"),
    "a 1 km lens": ([*SCAN[:3], "--f", "1mm", "--aperture", "1km", *SCAN[7:], "-o", "{tmp}/k.exr"], 2, "--aperture"),
    "hyperbolic:1e300nm": (
        ["psf-scan", "--design", "hyperbolic:1e300nm", *SCAN[3:], "-o", "{tmp}/k.exr"],
        2,
        "not an optical wavelength",
    ),
    "--threads 100000": (["optimize", str(TINY), "-o", "{tmp}/run2", "--threads", "100000"], 2, "--threads"),
    "--seed 0:99999999999": (["evaluate", *SIM, "--seed", "0:99999999999"], 2, "holds 100000000000 seeds"),
    "obstruction sheet of 1000 depths": (
        ["obstruction", "preview", "--pixels", "16", "--z-near", "1:1000:1mm", "-o", "{tmp}/o.png"],
        2,
        "at most 16 rows",
    ),
    "obstruction 1 nm away": (
        ["obstruction", "preview", "--pixels", "16", "--z-near", "1nm", "-o", "{tmp}/o.png"],
        2,
        "spans",
    ),
    "preset: name escaping runs/": (["preset", "show", "{name_toml}"], 2, "not a plain name"),
    "psf import: manifest /dev/zero": (
        ["psf", "import", "/dev/zero", "-o", "{tmp}/p.exr", "--pixel-pitch", "2um"],
        2,
        "not a regular file",
    ),
    "psf import: manifest a FIFO": (
        ["psf", "import", "{fifo_csv}", "-o", "{tmp}/p.exr", "--pixel-pitch", "2um"],
        2,
        "not a regular file",
    ),
    "psf import: a decompression bomb frame": (
        ["psf", "import", "{m_bomb_csv}", "-o", "{tmp}/p.exr", "--pixel-pitch", "2um"],
        2,
        "megapixels",
    ),
    "psf import: a NaN frame": (
        ["psf", "import", "{m_nanframe_csv}", "-o", "{tmp}/p.exr", "--pixel-pitch", "2um"],
        2,
        "NaN",
    ),
    "psf import: a frame claiming 4 TB": (
        ["psf", "import", "{m_hugeframe_csv}", "-o", "{tmp}/p.exr", "--pixel-pitch", "2um"],
        2,
        "claims",
    ),
    "psf import: a FIFO as frame": (
        ["psf", "import", "{m_fifoframe_csv}", "-o", "{tmp}/p.exr", "--pixel-pitch", "2um"],
        2,
        "not a frame format",
    ),
    "psf import --pixel-pitch nan": (
        ["psf", "import", "{m_ok_csv}", "-o", "{tmp}/p.exr", "--pixel-pitch", "nan"],
        2,
        "--pixel-pitch",
    ),
    "psf import --magnification inf": (
        ["psf", "import", "{m_ok_csv}", "-o", "{tmp}/p.exr", "--pixel-pitch", "2um", "--magnification", "inf"],
        2,
        "--magnification",
    ),
    "psf import -o onto /dev/full": (
        ["psf", "import", "{m_ok_csv}", "-o", "/dev/full", "--pixel-pitch", "2um"],
        2,
        "does not end in .exr",
    ),
    "psf import --plot onto a frame": (
        ["psf", "import", "{m_ok_csv}", "-o", "{tmp}/p.exr", "--pixel-pitch", "2um", "--plot", "{mask_png}"],
        2,
        "also an input",
    ),
    "psf compare of garbage": (["psf", "compare", "{garbage_exr}", "{cube_exr}"], 2, "not a readable OpenEXR file"),
    "psf compare --csv onto a FIFO": (
        ["psf", "compare", "{cube_exr}", "{cube_exr}", "--csv", "{fifo_csv}"],
        2,
        "not a regular file",
    ),
    "psf retrieve of garbage": (
        ["psf", "retrieve", "{garbage_exr}", "-o", "{tmp}/t.npy", "--design", "hyperbolic:532nm"],
        2,
        "not a readable OpenEXR file",
    ),
    "psf retrieve -o onto its design": (
        ["psf", "retrieve", "{cube_exr}", "-o", "{tmp}/theta.npy", "--design", "{tmp}/theta.npy"],
        2,
        "also an input",
    ),
    "psf retrieve -o not .npy": (["psf", "retrieve", "{cube_exr}", "-o", "{tmp}/t.exr"], 2, "does not end in .npy"),
    "evaluate --pairs of a file": (["evaluate", "--pairs", "{a_file}"], 2, "is a file"),
    "evaluate --pairs --plot onto a capture": (
        ["evaluate", "--pairs", "{pairs}", "--plot", "{pairs}/lens/obstructed/a.png"],
        2,
        "inside --pairs",
    ),
    "evaluate --pairs --plot into gt/": (
        ["evaluate", "--pairs", "{pairs}", "--plot", "{pairs}/gt/new.png"],
        2,
        "inside --pairs",
    ),
    "evaluate --pairs of an empty folder": (["evaluate", "--pairs", "{nopairs}"], 2, "no images in"),
    "nanofin --material /dev/zero": (["nanofin", "efficiency", "--material", "/dev/zero"], 2, "--material"),
    "nanofin --material a FIFO": (["nanofin", "efficiency", "--material", "{fifo_csv}"], 2, "--material"),
    "nanofin --width nan": (["nanofin", "efficiency", "--width", "nan"], 2, "--width"),
    "nanofin sweep -o under a file": (
        ["nanofin", "sweep", "--width", "300nm", "--length", "100nm", "-o", "{a_file}/out"],
        2,
        "not a folder",
    ),
    "nanofin sweep of 10^6 fins": (
        ["nanofin", "sweep", "--width", "1:395:0.4nm", "--length", "1:395:0.4nm", "-o", "{tmp}/sw"],
        2,
        "at most",
    ),
    # 4. estimates before big jobs
    "psf-scan 8192 px": (
        [
            "psf-scan",
            "--design",
            "hyperbolic:532nm",
            "--f",
            "4mm",
            "--aperture",
            "2.516mm",
            "--pixels",
            "8192",
            "-o",
            "{tmp}/big.exr",
        ],
        2,
        "over the host RAM available",
    ),
    "psf-scan over --max-memory": ([*SCAN, "-o", "{tmp}/m.exr", "--max-memory", "1kB"], 2, "--max-memory"),
    # issue 60: limits that round to nothing are refused as 0 is, not taken as 0
    "--max-memory 0.5B": ([*SCAN, "-o", "{tmp}/m.exr", "--max-memory", "0.5B"], 2, "less than one byte"),
    "--max-time 1e-300s": ([*SCAN, "-o", "{tmp}/m.exr", "--max-time", "1e-300s"], 2, "below 1 ms"),
    # issue 60: the off-axis model's 60° limit, in the option and the unit typed
    "--field-angles 70deg": ([*SCAN, "--field-angles", "0deg,70deg", "-o", "{tmp}/f.exr"], 2, "--field-angles: 70°"),
    "--field-heights past 60°": (
        [*SCAN, "--field-heights", "0um,2mm", "-o", "{tmp}/f.exr"],
        2,
        "--field-heights: 2 mm is a field angle of 63.43° at f = 1 mm",
    ),
    "simulate --psf-pixels 8192": (
        [
            "simulate",
            "hyperbolic:532nm",
            "--f",
            "4mm",
            "--aperture",
            "2.516mm",
            "--psf-pixels",
            "8192",
            "--images",
            "{imgs}",
            "-o",
            "{tmp}/s6",
        ],
        2,
        "over the host RAM available",
    ),
    "symmetry --validate of a 1 m lens": (
        ["symmetry", "--f", "4mm", "--lambda-d", "450nm", "--validate", "--aperture", "1m"],
        2,
        "TiB",
    ),
    "export-gds of a 1 m lens": (
        [*GDS[:3], "--f", "1m", "--aperture", "1m", *GDS[7:], "-o", "{tmp}/big.gds"],
        2,
        "TiB on disk",
    ),
    "optimize over --max-memory": (
        ["optimize", str(TINY), "-o", "{tmp}/run", "--max-memory", "1MiB"],
        2,
        "--max-memory",
    ),
    "evaluate --pairs over --max-memory": (
        ["evaluate", "--pairs", "{pairs}", "--max-memory", "1kB"],
        2,
        "--max-memory",
    ),
    "psf import over --max-memory": (
        ["psf", "import", "{m_ok_csv}", "-o", "{tmp}/p.exr", "--pixel-pitch", "2um", "--max-memory", "1kB"],
        2,
        "--max-memory",
    ),
}


def _snapshot(folder: str) -> dict:
    """Every file's size and time, every folder's name (a folder's time moves with the write probe)."""
    return {p: None if p.is_dir() else (p.stat().st_size, p.stat().st_mtime_ns) for p in Path(folder).rglob("*")}


@pytest.mark.parametrize("name", list(CASES))
def test_hostile_input_gets_one_line_and_no_debris(name, bench, capsys):
    argv, code, words = CASES[name]
    before = _snapshot(bench["tmp"])
    dev_null = os.stat("/dev/null")
    assert run([a.format(**bench) for a in argv]) == code
    out, err = capsys.readouterr()
    assert err.count("\n") == 1 and err.startswith("metalens: error: "), err
    assert "Traceback" not in err and "internal error" not in err
    assert words in err, err
    assert out == ""
    assert _snapshot(bench["tmp"]) == before  # nothing written, nothing destroyed
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode) and os.stat("/dev/null").st_ino == dev_null.st_ino


def test_a_240_byte_name_is_written(bench, capsys):
    target = Path(bench["tmp"]) / ("b" * 236 + ".exr")
    assert run([*SCAN, "-o", str(target), "--quiet"]) == 0
    assert target.is_file() and not [p for p in target.parent.iterdir() if p.name.startswith(".metalens-")]
    target.unlink()


def test_verify_without_klayout_is_refused_before_writing(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "klayout", None)
    monkeypatch.setitem(sys.modules, "klayout.db", None)
    assert run([*GDS, "-o", str(tmp_path / "v.gds"), "--verify"]) == 2
    assert "klayout" in capsys.readouterr().err and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("group", [[], ["bands"], ["preset"], ["obstruction"], ["reconstruct"]])
def test_a_group_alone_prints_its_help_and_succeeds(group, capsys):
    assert run(group) == 0
    out, err = capsys.readouterr()
    assert "Usage: metalens" in out and err == ""


def test_optimize_early_failure_leaves_no_run_directory(tmp_path, capsys):
    empty = tmp_path / "no_images"
    empty.mkdir()
    preset = tmp_path / "p.toml"
    preset.write_text(TINY.read_text().replace("[optimize]", f'[optimize]\nimages = "{empty}"'))
    assert run(["optimize", str(preset), "-o", str(tmp_path / "run"), "--quiet"]) == 2
    assert "holds no images" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


def _cli(*args, **kwargs):
    return subprocess.Popen(
        [sys.executable, "-m", "metalens_cli", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **kwargs,
    )


def test_sigterm_removes_the_output_being_written(tmp_path):
    """SIGTERM while export-gds streams a 50 MB layout: exit 143, one line, no temporary, no target."""
    proc = _cli(*GDS[:3], "--f", "4mm", "--aperture", "0.5mm", *GDS[7:], "-o", str(tmp_path / "lens.gds"), "--quiet")
    deadline = time.monotonic() + 60
    while not list(tmp_path.glob(".metalens-*")) and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.01)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 143 and err == "metalens: terminated\n", err
    assert list(tmp_path.iterdir()) == []


def test_file_size_limit_is_one_line_exit_1(tmp_path):
    """RLIMIT_FSIZE (ulimit -f) below the layout's size: the writer fails with EFBIG."""

    def limit():
        import resource

        resource.setrlimit(resource.RLIMIT_FSIZE, (1 << 20, 1 << 20))

    proc = _cli(*GDS, "-o", str(tmp_path / "lens.gds"), "--quiet", preexec_fn=limit)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 1 and err.count("\n") == 1 and "file-size limit" in err, err
    assert list(tmp_path.iterdir()) == []


def test_simulate_under_a_file_size_limit_leaves_no_folder(bench, tmp_path):
    def limit():
        import resource

        resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))

    proc = _cli("simulate", *[a.format(**bench) for a in SIM], "-o", str(tmp_path / "out"), preexec_fn=limit)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 1 and err.count("\n") == 1 and "file-size limit" in err, err
    assert list(tmp_path.iterdir()) == []


def test_full_stdout_is_one_line_exit_1():
    with open("/dev/full", "w") as full:
        proc = subprocess.run(
            [sys.executable, "-m", "metalens_cli", "symmetry", "--f", "4mm", "--lambda-d", "450nm", "--json"],
            stdout=full,
            stderr=subprocess.PIPE,
            text=True,
            timeout=60,
        )
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1 and "No space left" in proc.stderr, proc.stderr


def test_json_stdout_stays_json_when_the_exr_library_complains(bench, capfd):
    """OpenEXR writes its warnings to file descriptor 1; --json output must still parse (here: empty on error)."""
    assert run(["mtf", bench["truncated_exr"], "--json"]) == 2
    out, err = capfd.readouterr()
    assert out == "" and err.count("\n") == 1
    assert run(["mtf", bench["cube_exr"], "--json"]) == 0
    json.loads(capfd.readouterr().out)


def test_closed_standard_streams_are_not_errors(tmp_path):
    """`>&-` / `2>&-`: what would go there is dropped, the work is done."""
    out = tmp_path / "sheet.png"
    proc = subprocess.run(
        f"{sys.executable} -m metalens_cli obstruction preview --pixels 16 -o {out} --json >&- 2>&-",
        shell=True,
        timeout=60,
    )
    assert proc.returncode == 0 and out.is_file()


def test_a_scene_at_1e300_m_images_like_one_at_infinity(bench, capsys):
    far = [a.format(**bench) for a in SIM[:-1]] + ["charts", "--limit", "1", "--seed", "0", "--json", "--quiet"]
    assert run(["evaluate", *far, "--z-far", "1e300m", "--obstruction", "dirt"]) == 0
    at_1e300 = json.loads(capsys.readouterr().out)["rows"]
    assert run(["evaluate", *far, "--z-far", "1e12m", "--obstruction", "dirt"]) == 0
    assert json.loads(capsys.readouterr().out)["rows"] == at_1e300
