"""`metalens align` end to end: pairs and folders, 16-bit PNG and EXR outputs, saved warps
reapplied, one-line errors (exit 2 bad input, exit 1 registration failed), nothing half-written."""

import json
import math
import subprocess
import sys

import cv2
import numpy as np
import pytest
from synthetic import save_png, texture, warp

from metalens_cli.cli.main import run
from metalens_cli.imaging.registration import load_warp, register
from metalens_cli.io.image_files import read_exr_rgb, read_image_file, write_exr_rgb

SIDE = 256
ANGLE = math.radians(3)
CAMERA = np.array(
    [
        [1.03 * math.cos(ANGLE), -1.03 * math.sin(ANGLE), 8.0],
        [1.03 * math.sin(ANGLE), 1.03 * math.cos(ANGLE), -6.0],
        [2e-5, -1e-5, 1.0],
    ]
)


def invoke(capsys, *args):
    code = run([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def capture(scene, seed=0):
    """The scene through a blurrier, dimmer, differently balanced camera with a small ripple."""
    blurred = cv2.GaussianBlur(scene, (0, 0), 1.2)
    return warp(blurred, CAMERA, ripple_px=1.5) * np.array([0.8, 0.6, 0.9], np.float32) + 0.02 * seed


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    """ref/sceneK.png (8-bit) and shots/sceneK.png (16-bit), K = 0, 1, plus ref/extra.png."""
    root = tmp_path_factory.mktemp("bench")
    for k in range(2):
        scene = texture(SIDE, SIDE, k)
        save_png(root / "ref" / f"scene{k}.png", scene)
        save_png(root / "shots" / f"scene{k}.png", capture(scene, k), bits=16)
    save_png(root / "ref" / "extra.png", texture(SIDE, SIDE, 7))
    return root


def one_error_line(err: str, text: str) -> None:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("metalens: error: ") and text in lines[0], err


def test_pair_json_warp_out_and_reapply(capsys, tmp_path, bench):
    aligned, warp_file = tmp_path / "aligned.png", tmp_path / "warp.npz"
    code, out, err = invoke(
        capsys,
        "align",
        bench / "ref/scene0.png",
        bench / "shots/scene0.png",
        "-o",
        aligned,
        "--warp-out",
        warp_file,
        "--json",
    )
    assert code == 0 and err == ""
    report = json.loads(out)
    assert report["refine"] == "flow" and report["warp"] is None and len(report["pairs"]) == 1
    pair = report["pairs"][0]
    assert pair["output"] == str(aligned) and pair["warp_out"] == str(warp_file) and not pair["reapplied"]
    assert {
        "matches",
        "inliers",
        "inlier_fraction",
        "residual_px",
        "refined_residual_px",
        "flow_rms_px",
        "flow_max_px",
        "valid_fraction",
        "homography",
        "warnings",
    } <= set(pair["registration"])
    raw = cv2.imread(str(aligned), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16 and raw.shape == (SIDE, SIDE, 3)
    # on the reference grid: the same scene (up to the capture's blur and colour) where it is covered
    registration = load_warp(warp_file)
    mask = registration.valid_mask()
    reference, _, _ = read_image_file(bench / "ref/scene0.png", "REFERENCE")
    expected = cv2.GaussianBlur(reference, (0, 0), 1.2) * np.array([0.8, 0.6, 0.9], np.float32)
    got = raw[:, :, ::-1] / 65535.0
    assert 10 * math.log10(1 / np.mean((got[mask] - expected[mask]) ** 2)) > 30
    assert np.all(got[~mask] == 0)
    again = tmp_path / "again.png"
    code, out, err = invoke(
        capsys, "align", bench / "ref/scene0.png", bench / "shots/scene0.png", "-o", again, "--warp", warp_file
    )
    assert code == 0 and err == "" and "saved warp" in out and f"wrote {again}" in out
    assert np.array_equal(cv2.imread(str(again), cv2.IMREAD_UNCHANGED), raw)


def test_exr_target_gives_the_core_result_as_exr(capsys, tmp_path, bench):
    reference, _, _ = read_image_file(bench / "ref/scene1.png", "REFERENCE")
    linear = capture(texture(SIDE, SIDE, 1))[:, :, 1]  # one channel
    write_exr_rgb(tmp_path / "shot.exr", linear[None])
    code, out, err = invoke(
        capsys,
        "align",
        bench / "ref/scene1.png",
        tmp_path / "shot.exr",
        "-o",
        tmp_path / "out.exr",
        "--refine",
        "tps",
        "--quiet",
    )
    assert code == 0 and out == "" and err == ""
    expected = register(reference, linear[:, :, None], refine="tps").apply(linear[:, :, None])
    assert np.array_equal(read_exr_rgb(tmp_path / "out.exr")[0], expected[:, :, 0])


def test_folders_with_warps_and_reapply(capsys, tmp_path, bench):
    out_dir, warps = tmp_path / "aligned", tmp_path / "warps"
    code, out, err = invoke(capsys, "align", bench / "ref", bench / "shots", "-o", out_dir, "--warp-out", warps)
    assert code == 0 and err == ""
    assert sorted(p.name for p in out_dir.iterdir()) == [
        "scene0.png",
        "scene1.png",
    ]  # extra.png has no capture: skipped
    assert sorted(p.name for p in warps.iterdir()) == ["scene0.warp.npz", "scene1.warp.npz"]
    assert "scene0.png" in out and f"wrote 2 image(s) to {out_dir}/" in out and f"wrote 2 warp(s) to {warps}/" in out
    # one saved warp reapplied to every capture of the folder
    code, out, err = invoke(
        capsys,
        "align",
        bench / "ref",
        bench / "shots",
        "-o",
        tmp_path / "again",
        "--warp",
        warps / "scene0.warp.npz",
        "--json",
    )
    pairs = json.loads(out)["pairs"]
    assert (
        code == 0 and [p["reapplied"] for p in pairs] == [True, True] and pairs[0]["registration"]["refine"] == "flow"
    )
    first = [cv2.imread(str(folder / "scene0.png"), cv2.IMREAD_UNCHANGED) for folder in (out_dir, tmp_path / "again")]
    assert np.array_equal(*first)
    # folders that hold files are the user's: refused before any work, unless --overwrite
    for option, folder in (("--output", out_dir), ("--warp-out", warps)):
        before = {p: p.stat().st_mtime_ns for p in folder.iterdir()}
        other = {"--output": tmp_path / "fresh", "--warp-out": tmp_path / "fresh-warps"}
        args = [
            "-o",
            out_dir if option == "--output" else other["--output"],
            "--warp-out",
            warps if option == "--warp-out" else other["--warp-out"],
        ]
        code, out, err = invoke(capsys, "align", bench / "ref", bench / "shots", *args)
        assert code == 2 and out == ""
        one_error_line(err, f"{option}: folder '{folder}' already holds ")
        assert {p: p.stat().st_mtime_ns for p in folder.iterdir()} == before and not other[option].exists()
    code, _, err = invoke(
        capsys, "align", bench / "ref", bench / "shots", "-o", out_dir, "--warp-out", warps, "--overwrite"
    )
    assert code == 0 and err == ""


def test_low_overlap_is_a_warning(capsys, tmp_path):
    scene = texture(SIDE, SIDE, 3)
    save_png(tmp_path / "ref.png", scene)
    shifted = np.array([[1, 0, 120.0], [0, 1, 40.0], [0, 0, 1]])
    save_png(tmp_path / "shot.png", warp(scene, shifted))
    code, out, err = invoke(
        capsys,
        "align",
        tmp_path / "ref.png",
        tmp_path / "shot.png",
        "-o",
        tmp_path / "out.png",
        "--refine",
        "none",
        "--json",
    )
    report = json.loads(out)
    assert code == 0 and report["refine"] == "none" and report["pairs"][0]["registration"]["valid_fraction"] < 0.5
    lines = err.strip().splitlines()
    assert (
        len(lines) == 1
        and lines[0].startswith(f"metalens: warning: {tmp_path / 'shot.png'}: ")
        and "covers only" in lines[0]
    )


def test_unrelated_images_exit_1_with_one_line(capsys, tmp_path, bench):
    code, out, err = invoke(
        capsys, "align", bench / "ref/scene0.png", bench / "ref/extra.png", "-o", tmp_path / "out.png"
    )
    assert code == 1 and out == ""
    one_error_line(err, "TARGET: only ")
    assert list(tmp_path.iterdir()) == []


def test_one_failing_pair_writes_no_folder(capsys, tmp_path, bench):
    refs, shots = tmp_path / "refs", tmp_path / "shots"
    for name, scene in (("a", 0), ("b", 1)):
        save_png(refs / f"{name}.png", texture(SIDE, SIDE, scene))
    save_png(shots / "a.png", capture(texture(SIDE, SIDE, 0)), bits=16)
    save_png(shots / "b.png", texture(SIDE, SIDE, 9), bits=16)
    code, out, err = invoke(
        capsys, "align", refs, shots, "-o", tmp_path / "out", "--warp-out", tmp_path / "warps", "--json"
    )
    assert code == 1 and out == ""
    one_error_line(err, f"{shots / 'b.png'}: only ")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["refs", "shots"]


def test_a_failing_reference_in_folder_mode_is_named_by_its_file(capsys, tmp_path, bench):
    """A uniform REF_DIR/b.png (and its target) once gave `REFERENCE: the image is uniform`,
    without saying which of the pairs; a uniform reference of two files still says REFERENCE."""
    refs, shots = tmp_path / "refs", tmp_path / "shots"
    save_png(refs / "a.png", texture(SIDE, SIDE, 0))
    save_png(shots / "a.png", capture(texture(SIDE, SIDE, 0)), bits=16)
    flat = np.full((SIDE, SIDE, 3), 0.5, np.float32)
    save_png(refs / "b.png", flat)
    save_png(shots / "b.png", flat, bits=16)
    code, out, err = invoke(capsys, "align", "--quiet", refs, shots, "-o", tmp_path / "out")
    assert code == 1 and out == ""
    one_error_line(err, f"metalens: error: {refs / 'b.png'}: the image is uniform; there is nothing to register")
    assert not (tmp_path / "out").exists()
    code, out, err = invoke(capsys, "align", refs / "b.png", shots / "a.png", "-o", tmp_path / "one.png")
    assert code == 1
    one_error_line(err, "metalens: error: REFERENCE: the image is uniform")


@pytest.fixture
def broken(tmp_path, bench):
    """Inputs that are wrong in one way each, and a saved warp of bench's scene0 in bench/w.npz."""
    (tmp_path / "garbage.png").write_bytes(b"\x89PNG\r\n\x1a\n not really")
    (tmp_path / "lonely").mkdir()
    save_png(tmp_path / "lonely" / "scene0.png", texture(SIDE, SIDE, 0))
    save_png(tmp_path / "lonely" / "orphan.png", texture(SIDE, SIDE, 5))
    save_png(tmp_path / "small.png", texture(64, 64, 0))
    (tmp_path / "notes.npz").write_text("no")
    if not (bench / "w.npz").exists():
        assert (
            run(
                [
                    "align",
                    str(bench / "ref/scene0.png"),
                    str(bench / "shots/scene0.png"),
                    "-o",
                    str(bench / "w.png"),
                    "--warp-out",
                    str(bench / "w.npz"),
                    "--quiet",
                ]
            )
            == 0
        )
    return tmp_path


@pytest.mark.parametrize(
    "args, text",
    [
        (["{ref}", "{bench}/shots/none.png", "-o", "{tmp}/out.png"], "TARGET: no such file"),
        (["{ref}", "{tmp}/garbage.png", "-o", "{tmp}/out.png"], "TARGET: garbage.png is not a readable image"),
        (["{bench}/ref", "{tmp}/lonely", "-o", "{tmp}/out"], "1 image(s) without a reference of the same name"),
        (["{bench}/ref", "{shot}", "-o", "{tmp}/out.png"], "is a file but REFERENCE"),
        (["{bench}/ref", "{bench}/shots", "-o", "{tmp}/out.png"], "names a file, but REFERENCE and TARGET are folders"),
        (["{bench}/ref", "{bench}/shots", "-o", "{bench}/shots"], "is also an input"),
        (["{ref}", "{shot}", "-o", "{tmp}/out.png", "--refine", "spline"], "'--refine'"),
        (
            ["{ref}", "{shot}", "-o", "{tmp}/out.png", "--warp", "{tmp}/notes.npz"],
            "--warp: notes.npz is not a readable warp file",
        ),
        (
            ["{ref}", "{tmp}/small.png", "-o", "{tmp}/out.png", "--warp", "{bench}/w.npz"],
            "TARGET: small.png is 64 × 64 pixels",
        ),
        (
            ["{ref}", "{shot}", "-o", "{tmp}/out.png", "--warp", "{bench}/w.npz", "--refine", "tps"],
            "--refine does not apply with --warp",
        ),
        (["{ref}", "{shot}", "-o", "{tmp}/out.png", "--warp-out", "{tmp}/warp.txt"], "--warp-out: '"),
    ],
    ids=[
        "missing",
        "unreadable",
        "unpaired",
        "file-and-folder",
        "file-for-folders",
        "output-is-input",
        "refine",
        "not-a-warp",
        "warp-size",
        "warp-refine",
        "warp-out-suffix",
    ],
)
def test_bad_input_exit_2_nothing_written(capsys, bench, broken, args, text):
    before = sorted(p.name for p in broken.iterdir()), sorted(p.name for p in bench.rglob("*"))
    filled = [
        a.format(ref=bench / "ref/scene0.png", shot=bench / "shots/scene0.png", bench=bench, tmp=broken) for a in args
    ]
    code, out, err = invoke(capsys, "align", *filled)
    assert code == 2 and out == ""
    one_error_line(err, text)
    assert (sorted(p.name for p in broken.iterdir()), sorted(p.name for p in bench.rglob("*"))) == before


@pytest.mark.parametrize(
    "output, text",
    [
        ("out.exr", "the output keeps the target's encoding"),
        ("out.jpg", "does not end in .png, .tif, .tiff or .exr"),
        ("missing/out.png", "does not exist"),
    ],
)
def test_bad_outputs_are_refused_before_work(capsys, tmp_path, bench, output, text):
    code, out, err = invoke(
        capsys, "align", bench / "ref/scene0.png", bench / "shots/scene0.png", "-o", tmp_path / output
    )
    assert code == 2 and out == ""
    one_error_line(err, text)
    assert list(tmp_path.iterdir()) == []


def test_the_command_imports_no_torch(tmp_path, bench):
    script = (
        "import sys; from metalens_cli.cli.main import run; "
        f"code = run(['align', {str(bench / 'ref/scene0.png')!r}, {str(bench / 'shots/scene0.png')!r}, "
        f"'-o', {str(tmp_path / 'a.png')!r}, '--quiet']); print(code, 'torch' in sys.modules)"
    )
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert result.stdout.split() == ["0", "False"], result.stderr
