"""`metalens evaluate --pairs DIR`: the metric table of captured photographs, on a synthetic
bench whose captures are the references warped by a known homography and ripple, blurred (one
lens sharper than the other) and, when obstructed, shaded by a dark blob."""

import json
import math

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter
from synthetic import save_png, texture, warp

from metalens_cli.cli.main import run
from metalens_cli.io.image_files import linear_to_srgb

SIDE = 256
HOMOGRAPHY = np.array([[1.02, 0.03, -6.0], [-0.02, 0.99, 4.0], [2e-5, -1e-5, 1.0]])
BLUR = {"sharp": 0.8, "blurry": 2.5}


def save(path, linear):
    """Linear RGB as a 16-bit sRGB-encoded PNG."""
    save_png(path, linear_to_srgb(np.clip(linear, 0, 1)), bits=16)


def occluder(seed):
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[:SIDE, :SIDE]
    blob = np.zeros((SIDE, SIDE))
    for _ in range(3):
        cy, cx, r = rng.uniform(60, 196), rng.uniform(60, 196), rng.uniform(10, 25)
        blob = np.maximum(blob, (np.hypot(y - cy, x - cx) < r).astype(float))
    return gaussian_filter(blob, 4)[:, :, None]


@pytest.fixture(scope="module")
def pairs(tmp_path_factory):
    root = tmp_path_factory.mktemp("pairs")
    for k in range(3):
        gt = texture(SIDE, SIDE, k)
        save(root / "gt" / f"scene{k}.png", gt)
        for design, sigma in BLUR.items():
            capture = warp(gaussian_filter(gt, (sigma, sigma, 0)), HOMOGRAPHY, ripple_px=1.5)
            save(root / design / "unobstructed" / f"scene{k}.png", capture)
            save(root / design / "obstructed" / f"scene{k}.png", capture * (1 - 0.8 * occluder(k)))
    return root


def invoke(capsys, *args):
    code = run([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def row(report, design, condition, capture="raw"):
    return next(
        r for r in report["rows"] if (r["design"], r["condition"], r["capture"]) == (design, condition, capture)
    )


def test_the_sharper_lens_scores_higher_and_obstruction_costs_both(capsys, pairs, tmp_path):
    code, out, err = invoke(
        capsys, "evaluate", "--pairs", pairs, "--json", "--csv", tmp_path / "t.csv", "--plot", tmp_path / "t.png"
    )
    assert code == 0, err
    report = json.loads(out)
    assert report["images"] == ["scene0", "scene1", "scene2"] and report["alignment"] == "unobstructed"
    assert len(report["alignments"]) == 6 and all(a["inliers"] >= 12 for a in report["alignments"])
    sharp, blurry = row(report, "sharp", "unobstructed"), row(report, "blurry", "unobstructed")
    assert sharp["psnr_db"] > blurry["psnr_db"] + 3 and sharp["ssim"] > blurry["ssim"]
    assert sharp["psnr_db"] > 30  # registration leaves little: the residual is the 0.8 px blur
    for design in BLUR:
        delta = next(d for d in report["deltas"] if d["design"] == design)
        assert delta["delta_psnr_db"] < -3 and delta["delta_psnr_db_ci"][1] < 0
    versus = [c for c in report["comparisons"] if c["metric"] == "psnr_db" and c["condition"] == "unobstructed"]
    assert len(versus) == 1 and abs(versus[0]["difference"]) > 3
    assert (tmp_path / "t.csv").read_text().count("\n") == 5 and (tmp_path / "t.png").stat().st_size > 0
    code, out, _ = invoke(capsys, "evaluate", "--pairs", pairs)
    assert code == 0 and "Captures vs gt" in out


def test_without_alignment_the_same_captures_score_far_lower(capsys, pairs):
    aligned = json.loads(invoke(capsys, "evaluate", "--pairs", pairs, "--json")[1])
    code, out, err = invoke(capsys, "evaluate", "--pairs", pairs, "--align", "none", "--json")
    assert code == 0, err
    raw = json.loads(out)
    assert row(raw, "sharp", "unobstructed")["psnr_db"] < row(aligned, "sharp", "unobstructed")["psnr_db"] - 10


def test_recon_folders_add_recon_rows(capsys, pairs, tmp_path):
    import shutil

    folder = tmp_path / "with_recon"
    shutil.copytree(pairs, folder)
    for name in ("unobstructed", "obstructed"):
        shutil.copytree(folder / "sharp" / name, folder / "sharp" / f"recon-{name}")
    code, out, err = invoke(capsys, "evaluate", "--pairs", folder, "--json")
    assert code == 0, err
    report = json.loads(out)
    recon = row(report, "sharp", "unobstructed", "recon")
    assert recon["psnr_db"] == pytest.approx(row(report, "sharp", "unobstructed")["psnr_db"])  # the same images
    assert not any(r["capture"] == "recon" for r in report["rows"] if r["design"] == "blurry")


@pytest.mark.parametrize(
    ("change", "args", "code", "message"),
    [
        (lambda root: (root / "sharp" / "obstructed" / "scene1.png").unlink(), [], 2, "sharp/obstructed lacks scene1"),
        (lambda root: (root / "sharp" / "misc").mkdir(), [], 2, "unexpected folder sharp/misc"),
        (
            None,
            ["--seed", "3"],
            2,
            "--seed: does not apply to --pairs (the designs are the folders of DIR) (expected --pairs DIR with only ",
        ),
        (
            None,
            ["hyperbolic:532nm"],
            2,
            "DESIGN: does not apply to --pairs (the designs are the folders of DIR) (expected ",
        ),
        (
            None,
            ["--max-time", "0.001s"],
            2,
            "--pairs: evaluate --pairs of 2 design(s) × 3 scene(s)",
        ),  # estimated, so --max-time holds
        (
            lambda root: (root / "sharp" / "misc").mkdir(),
            ["--max-time", "1h"],
            2,
            "unexpected folder sharp/misc",
        ),  # past the option rule
        (
            lambda root: save(root / "blurry" / "unobstructed" / "scene2.png", texture(SIDE, SIDE, 99)),
            [],
            1,
            "scene2.png",
        ),
    ],
)
def test_bad_pairs_are_one_line_errors(capsys, pairs, tmp_path, change, args, code, message):
    import shutil

    folder = tmp_path / "copy"
    shutil.copytree(pairs, folder)
    if change is not None:
        change(folder)
    got, out, err = invoke(capsys, "evaluate", "--pairs", folder, *args)
    assert got == code and out == "" and err.count("\n") == 1 and message in err, err
    assert "internal error" not in err


@pytest.mark.parametrize(
    ("name", "args", "words"),
    [
        (
            "sharp/obstructed/scene1.png",
            [],
            "is 128 × 128 pixels, the capture whose warp it shares ({folder}/sharp/unobstructed/scene1.png) "
            "256 × 256 (expected the captures of one scene and design at one size (one camera), "
            "or --align each)",
        ),
        (
            "blurry/unobstructed/scene0.png",
            ["--align", "none"],
            "is 128 × 128 pixels, its gt 256 × 256 (expected captures of the reference's size with --align none)",
        ),
    ],
)
def test_a_half_size_capture_is_refused_naming_its_file(capsys, pairs, tmp_path, name, args, words):
    """A capture of another size than the one whose warp it reuses (or, unaligned, than its gt):
    the one line names --pairs and the file."""
    import shutil

    folder = tmp_path / "copy"
    shutil.copytree(pairs, folder)
    save(folder / name, texture(SIDE // 2, SIDE // 2, 1))
    got, out, err = invoke(capsys, "evaluate", "--pairs", folder, *args)
    assert (
        got == 2 and out == "" and err == f"metalens: error: --pairs: {folder / name}: {words.format(folder=folder)}\n"
    )


def test_physics_a_capture_equal_to_its_reference_scores_perfectly_up_to_encoding(capsys, tmp_path):
    """No lens, no obstruction: the capture is its reference, and the PSNR reaches its ceiling
    instead of +∞ (which would break the statistics)."""
    for k in range(2):
        gt = texture(SIDE, SIDE, 10 + k)
        save(tmp_path / "gt" / f"s{k}.png", gt)
        save(tmp_path / "identity" / "unobstructed" / f"s{k}.png", gt)
        save(tmp_path / "identity" / "obstructed" / f"s{k}.png", gt * (1 - 0.8 * occluder(k)))
    code, out, err = invoke(capsys, "evaluate", "--pairs", tmp_path, "--align", "none", "--json")
    assert code == 0, err
    report = json.loads(out)
    clear = row(report, "identity", "unobstructed")
    assert clear["ssim"] == pytest.approx(1, abs=1e-6) and clear["psnr_db"] == 100.0  # the ceiling of an exact match
    assert "2 score(s) match their reference exactly" in report["warnings"][0]
    assert (
        math.isfinite(row(report, "identity", "obstructed")["psnr_db"])
        and row(report, "identity", "obstructed")["psnr_db"] < 40
    )


def test_a_greyscale_reference_is_compared_with_the_captures_luminance(capsys, tmp_path):
    """A monochrome reference of a colour scene: a colour capture whose Rec. 709 luminance is
    the reference scores as a match (only the 16-bit encoding differs), not as a colour error."""
    for k in range(2):
        colour = texture(SIDE, SIDE, 20 + k)
        grey = colour @ np.array([0.2126, 0.7152, 0.0722])  # linear Y, the reference's one channel
        save_png(tmp_path / "gt" / f"s{k}.png", linear_to_srgb(grey), bits=16)
        save(tmp_path / "lens" / "unobstructed" / f"s{k}.png", colour)
        save(tmp_path / "lens" / "obstructed" / f"s{k}.png", colour * (1 - 0.8 * occluder(k)))
    code, out, err = invoke(capsys, "evaluate", "--pairs", tmp_path, "--align", "none", "--json")
    assert code == 0, err
    report = json.loads(out)
    assert row(report, "lens", "unobstructed")["psnr_db"] > 60 and row(report, "lens", "obstructed")["psnr_db"] < 40
    assert any("2 greyscale reference(s) (s0, s1)" in w for w in report["warnings"])
