"""`metalens reconstruct train/apply/export` and `evaluate --recon` from the command line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from metalens_cli.cli.main import run

TINY = Path(__file__).parents[1] / "design" / "tiny_reconstruct.toml"
LENS = ["hyperbolic:532nm", "--f", "1mm", "--aperture", "0.2mm"]


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    out = tmp_path_factory.mktemp("recon") / "run"
    assert run(["reconstruct", "train", *LENS, "--preset", str(TINY), "-o", str(out), "--quiet", "--json"]) == 0
    return out


def _one_line_error(capsys, text: str) -> None:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("metalens: error:") and text in err[0], err


def test_train_writes_a_run_directory(trained):
    report = json.loads((trained / "run.json").read_text())
    assert report["design"]["spec"] == "hyperbolic:532nm" and report["cost"]["steps_run"] == 4
    assert report["validation"]["final"]["step"] == 4 and "raw_obstructed_psnr_db" in report["validation"]["final"]
    for name in ("model.pt", "reconstruct.toml", "design.json", "loss.csv", "loss.png", "validation/step_000004.png"):
        assert (trained / name).is_file(), name


def test_apply_writes_exr_and_png_equal_to_the_core(trained, tmp_path, capsys):
    import cv2

    from metalens_cli.imaging.restore import load_reconstructor
    from metalens_cli.io.image_files import read_exr_rgb, srgb_to_linear, write_exr_rgb

    inputs = tmp_path / "in"
    inputs.mkdir()
    rng = np.random.default_rng(0)
    srgb = rng.integers(0, 255, size=(30, 44, 3), dtype=np.uint8)
    cv2.imwrite(str(inputs / "photo.png"), srgb)
    linear = rng.uniform(0, 1, size=(3, 21, 17)).astype(np.float32)
    write_exr_rgb(inputs / "raw.exr", linear)
    capsys.readouterr()
    assert (
        run(["reconstruct", "apply", str(trained), str(inputs), "-o", str(tmp_path / "out"), "--json", "--quiet"]) == 0
    )
    report = json.loads(capsys.readouterr().out)
    assert [Path(r["input"]).name for r in report["images"]] == ["photo.png", "raw.exr"]
    recon = load_reconstructor(trained)
    np.testing.assert_array_equal(read_exr_rgb(tmp_path / "out" / "raw.exr"), recon(linear))
    photo = srgb_to_linear(np.transpose(srgb[:, :, ::-1], (2, 0, 1)) / 255.0)
    np.testing.assert_allclose(read_exr_rgb(tmp_path / "out" / "photo.exr"), recon(photo), rtol=0, atol=1e-6)
    assert (tmp_path / "out" / "photo.png").is_file()


def test_export_reproduces_apply(trained, tmp_path, capsys):
    import torch

    from metalens_cli.imaging.restore import load_reconstructor

    target = tmp_path / "model.pt2"
    assert run(["reconstruct", "export", str(trained), "-o", str(target), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["passed"] and report["max_abs_difference"] <= 1e-5
    program = torch.export.load(str(target)).module()
    capture = np.random.default_rng(5).uniform(0, 1, size=(3, 50, 38)).astype(np.float32)
    with torch.no_grad():
        exported = program(torch.from_numpy(capture)).numpy()
    np.testing.assert_allclose(exported, load_reconstructor(trained)(capture), rtol=0, atol=1e-5)
    assert run(["reconstruct", "export", str(trained), "-o", str(tmp_path / "model.onnx")]) == 2
    _one_line_error(capsys, ".pt2")


def test_evaluate_with_recon_adds_recon_rows(trained, capsys):
    common = ["--pixels", "32", "--limit", "2", "--wavelengths", "450:650:100nm", "--obstruction", "dirt"]
    assert run(["evaluate", *LENS, *common, "--recon", str(trained), "--json", "--quiet"]) == 0
    report = json.loads(capsys.readouterr().out)
    captures = {(r["capture"], r["condition"]) for r in report["rows"]}
    assert captures == {
        ("raw", "unobstructed"),
        ("raw", "obstructed"),
        ("recon", "unobstructed"),
        ("recon", "obstructed"),
    }
    versus = [c for c in report["comparisons"] if c["capture"] == "recon" and c["versus_capture"] == "raw"]
    assert versus and all(c["design"] == c["versus"] == "hyperbolic:532nm" for c in versus)
    assert (
        run(["evaluate", "hyperbolic:500nm", "--f", "1mm", "--aperture", "0.2mm", *common, "--recon", str(trained)])
        == 2
    )
    _one_line_error(capsys, "was trained for 'hyperbolic:532nm'")
    assert run(["evaluate", *LENS, "hyperbolic:500nm", *common, "--recon", str(trained)]) == 2
    _one_line_error(capsys, "1 runs for 2 designs")


def test_bad_inputs_are_one_line_exit_2(trained, tmp_path, capsys):
    from metalens_cli.io.image_files import write_exr_rgb

    assert run(["reconstruct", "apply", str(tmp_path / "nowhere"), str(TINY), "-o", str(tmp_path / "o")]) == 2
    _one_line_error(capsys, "INPUT")  # the inputs are checked first: a .toml is not an image
    garbage = tmp_path / "broken.png"
    garbage.write_bytes(b"\x89PNG not really")
    assert run(["reconstruct", "apply", str(tmp_path / "nowhere"), str(garbage), "-o", str(tmp_path / "o")]) == 2
    _one_line_error(capsys, "no such run directory")
    assert run(["reconstruct", "apply", str(trained), str(garbage), "-o", str(tmp_path / "o")]) == 2
    _one_line_error(capsys, "not a readable image")
    nan = np.full((3, 8, 8), np.nan, dtype=np.float32)
    write_exr_rgb(tmp_path / "nan.exr", nan)
    assert run(["reconstruct", "apply", str(trained), str(tmp_path / "nan.exr"), "-o", str(tmp_path / "o")]) == 2
    _one_line_error(capsys, "NaN")
    assert run(["reconstruct", "train", *LENS, "--preset", str(TINY), "-o", str(trained)]) == 2
    _one_line_error(capsys, "already holds a run")
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    assert run(["reconstruct", "apply", str(trained), str(tmp_path / "nan.exr"), "-o", str(blocker / "out")]) == 2
    _one_line_error(capsys, "is not a folder")
    assert run(["reconstruct", "export", str(trained), "-o", str(tmp_path / "missing" / "m.pt2")]) == 2
    _one_line_error(capsys, "does not exist")
    assert run(["reconstruct", "train", *LENS, "--preset", str(TINY), "-o", str(blocker / "run")]) == 2
    _one_line_error(capsys, "not a folder")
    assert not (tmp_path / "missing").exists()
    assert (
        run(
            [
                "reconstruct",
                "train",
                "hyperbolic:500nm",
                "--f",
                "1mm",
                "--aperture",
                "0.2mm",
                "-o",
                str(trained),
                "--resume",
            ]
        )
        == 2
    )
    _one_line_error(capsys, "not the design the run was made for")


def test_train_on_captured_pairs(tmp_path, capsys):
    import cv2

    rng = np.random.default_rng(4)
    for folder in ("gt", "captures"):
        (tmp_path / "pairs" / folder).mkdir(parents=True)
    for k in range(3):
        gt = rng.integers(0, 255, size=(44, 40, 3), dtype=np.uint8)
        cv2.imwrite(str(tmp_path / "pairs" / "gt" / f"scene{k}.png"), gt)
        cv2.imwrite(str(tmp_path / "pairs" / "captures" / f"scene{k}@a.png"), cv2.GaussianBlur(gt, (0, 0), 2))
    out = tmp_path / "run"
    assert (
        run(
            [
                "reconstruct",
                "train",
                *LENS,
                "--preset",
                str(TINY),
                "--pairs",
                str(tmp_path / "pairs"),
                "-o",
                str(out),
                "--steps",
                "2",
                "--json",
                "--quiet",
            ]
        )
        == 0
    )
    report = json.loads(capsys.readouterr().out)
    assert report["data"]["kind"] == "captured pairs" and report["data"]["pool_entries"] == 2
    assert report["data"]["validation_entries"] == 1 and report["data"]["pool_pixels"] == 40


def test_train_refuses_degenerate_pairs_bad_names_and_names_design(tmp_path, capsys):
    """One scene cannot be split into training and validation scenes; a gt scene without a
    capture is refused as evaluate --pairs refuses it; a preset's name must be plain; the
    positional DESIGN is named as such. Nothing is written."""
    import cv2

    rng = np.random.default_rng(5)
    for folder, scenes, captured in (("one", ["s0"], ["s0@a", "s0@b"]), ("lacking", ["s0", "s1", "s2"], ["s0"])):
        for sub in ("gt", "captures"):
            (tmp_path / folder / sub).mkdir(parents=True)
        for name in scenes:
            cv2.imwrite(
                str(tmp_path / folder / "gt" / f"{name}.png"), rng.integers(0, 255, size=(40, 40, 3), dtype=np.uint8)
            )
        for name in captured:
            cv2.imwrite(
                str(tmp_path / folder / "captures" / f"{name}.png"),
                rng.integers(0, 255, size=(40, 40, 3), dtype=np.uint8),
            )
    out = tmp_path / "run"
    train = ["reconstruct", "train", *LENS, "-o", str(out), "--steps", "1", "--quiet", "--preset"]
    assert run([*train, str(TINY), "--pairs", str(tmp_path / "one")]) == 2
    _one_line_error(
        capsys,
        "--pairs: '" + str(tmp_path / "one") + "' holds 1 scene (s0), too few to hold out validation scenes "
        "apart from the training ones (expected at least 2 scenes",
    )
    assert run([*train, str(TINY), "--pairs", str(tmp_path / "lacking")]) == 2
    _one_line_error(capsys, "--pairs: captures lacks s1, s2")
    evil = tmp_path / "evil.toml"
    evil.write_text(TINY.read_text().replace('name = "tiny-reconstruct"', 'name = "../evil"'))
    assert run(["preset", "show", str(evil)]) == 2
    _one_line_error(capsys, "name: '../evil' is not a plain name")
    assert run([*train, str(evil)]) == 2
    _one_line_error(capsys, "name: '../evil' is not a plain name")
    assert run(["reconstruct", "train", "hyperbolic:abc", *LENS[1:], "--preset", str(TINY), "-o", str(out)]) == 2
    _one_line_error(capsys, "metalens: error: DESIGN: 'abc' is not a length")
    assert not out.exists()


def test_resume_refuses_another_preset_and_too_many_threads(trained, tmp_path, capsys):
    """--resume goes on with the run's own preset: one given must match it (steps and seed aside),
    else it would be silently ignored; --threads beyond the usable cores would only stall."""
    import os
    import shutil

    copy = tmp_path / "run"
    shutil.copytree(trained, copy)
    other = tmp_path / "wider.toml"
    other.write_text(TINY.read_text().replace("width = 4", "width = 8"))
    before = {p: p.stat().st_mtime_ns for p in copy.rglob("*")}
    assert run(["reconstruct", "train", *LENS, "--preset", str(other), "-o", str(copy), "--resume"]) == 2
    _one_line_error(capsys, "wider.toml sets network.width = 8, but the run")
    assert {p: p.stat().st_mtime_ns for p in copy.rglob("*")} == before
    assert (
        run(
            [
                "reconstruct",
                "train",
                *LENS,
                "--preset",
                str(TINY),
                "-o",
                str(copy),
                "--resume",
                "--steps",
                "4",
                "--quiet",
            ]
        )
        == 0
    )
    capsys.readouterr()
    cores = len(os.sched_getaffinity(0))
    assert run(["reconstruct", "train", *LENS, "-o", str(tmp_path / "new"), "--threads", str(cores + 1)]) == 2
    _one_line_error(capsys, f"--threads: {cores + 1} threads on the {cores} CPU core(s)")
