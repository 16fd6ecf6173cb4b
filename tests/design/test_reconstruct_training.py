"""Training the reconstruction network: schedule, loss encoding, pairs, batches, exact resume,
torchrun data parallel."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from launch import run_metalens

from metalens_cli.design.reconstruct_data import Camera, Pool, batch, read_pairs, strata
from metalens_cli.design.reconstruct_training import learning_rate_factor, train_reconstruction
from metalens_cli.errors import InputError
from metalens_cli.io.designs import resolve_design
from metalens_cli.io.image_files import srgb_encode_tensor
from metalens_cli.io.reconstruct_presets import load_reconstruct_preset

TINY = Path(__file__).with_name("tiny_reconstruct.toml")
CAMERA = Camera(1.85e-6, (0.040, 0.050), (1.0, 20.0))


def _design(wavelength: str = "532nm"):
    return resolve_design(f"hyperbolic:{wavelength}", f_m=1e-3, aperture_m=0.2e-3)


def test_learning_rate_warm_up_then_cosine_with_warm_restarts():
    t = dataclasses.replace(load_reconstruct_preset(TINY).train, warmup_steps=10, restart_period=100, restart_growth=2)
    assert learning_rate_factor(0, t) == pytest.approx(0.1)
    assert learning_rate_factor(5, t) == pytest.approx(0.55)
    assert learning_rate_factor(10, t) == pytest.approx(1.0)
    assert learning_rate_factor(60, t) == pytest.approx(0.5)  # half-way through the first period
    assert learning_rate_factor(109, t) == pytest.approx(0.5 * (1 + math.cos(math.pi * 99 / 100)))
    assert learning_rate_factor(110, t) == pytest.approx(1.0)  # restart
    assert learning_rate_factor(210, t) == pytest.approx(0.5)  # the second period is twice as long
    assert learning_rate_factor(310, t) == pytest.approx(1.0)


def test_display_encoding_is_srgb():
    import colour

    x = np.linspace(0, 1, 1001)
    expected = colour.cctf_encoding(x, function="sRGB")
    np.testing.assert_allclose(srgb_encode_tensor(torch.from_numpy(x)).numpy(), expected, rtol=0, atol=1e-9)
    assert srgb_encode_tensor(torch.tensor(-0.01)).item() == pytest.approx(-0.1292)  # the toe continues linearly


def test_strata_midpoints():
    assert strata((0.04, 0.05), 4) == pytest.approx([0.04125, 0.04375, 0.04625, 0.04875])
    assert strata((1.0, math.inf), 2) == pytest.approx([1 / 0.75, 4.0])  # midpoints of 1/z in (0, 1]


def test_generated_scenes_by_choice():
    """``data.scenes``: "natural" and "procedural" are ``procedural_scene`` with and without
    ``structure`` on the canvas (margin: half of canvas − sensor); "mixed" is natural or a
    dead-leaves chart, as its first draw says."""
    from metalens_cli.design.reconstruct_data import _scene
    from metalens_cli.design.scenes import procedural_scene
    from metalens_cli.imaging.dead_leaves import dead_leaves

    data = load_reconstruct_preset(TINY).data
    for choice, structure in (("natural", True), ("procedural", False)):
        scene = _scene(dataclasses.replace(data, scenes=choice), 96, 32, np.random.default_rng(1), None)
        np.testing.assert_array_equal(
            scene, procedural_scene((96, 96), np.random.default_rng(1), 32, structure=structure)
        )
    for seed in range(4):
        scene = _scene(dataclasses.replace(data, scenes="mixed"), 96, 32, np.random.default_rng(seed), None)
        rng = np.random.default_rng(seed)
        expected = (
            procedural_scene((96, 96), rng, 32, structure=True)
            if rng.integers(2) == 0
            else dead_leaves((96, 96), 1000 + int(rng.integers(2**31)), sensor_shape=(32, 32))
        )
        np.testing.assert_array_equal(scene, expected)


def test_batch_positions_follow_their_pixels_over_the_whole_sensor():
    s, crop, sensor = 24, 10, 64
    ys, xs = np.mgrid[0:s, 0:s].astype(np.float32)
    coded = np.stack([xs, ys, np.ones_like(xs)])[None].repeat(2, axis=0)  # pixel values name their column and row
    offsets = np.array([[30, 5], [0, 40]])  # where each capture lies on the sensor (top, left)
    pool = Pool(coded, coded, coded, ["dirt", "dirt"], offsets=offsets, sensor=sensor)
    data = dataclasses.replace(load_reconstruct_preset(TINY).data, noise_sigma=0.0, brightness=0.0, contrast=0.0)
    b = batch(pool, data, crop, seed=3, step=7, indices=list(range(8)))
    centre, scale = (sensor - 1) / 2, sensor / 2
    for k in range(8):  # every turn and flip: the position planes still name where on the sensor each pixel lies
        sensor_x, sensor_y = (b.positions[k, a] * scale + centre for a in (0, 1))
        assert any(
            torch.allclose(sensor_x - left, b.targets[k, 0], atol=1e-4)
            and torch.allclose(sensor_y - top, b.targets[k, 1], atol=1e-4)
            for top, left in offsets
        )
    torch.testing.assert_close(b.inputs, b.targets)  # no jitter, no noise: the input is the same window
    whole = torch.tensor([(s - 1) / 2, (s - 1) / 2, 1.0]).view(1, 3, 1, 1).expand(8, -1, -1, -1)
    torch.testing.assert_close(b.means, whole)  # the mean of the whole capture, not of the crop


def _write_pairs(root: Path, names, size=(40, 48), mismatch: str | None = None) -> None:
    import cv2

    (root / "gt").mkdir(parents=True)
    (root / "captures").mkdir()
    rng = np.random.default_rng(0)
    for name in names:
        gt = rng.integers(0, 255, size=(*size, 3), dtype=np.uint8)
        cv2.imwrite(str(root / "gt" / f"{name}.png"), gt)
        for k in range(2):
            shape = (size[0] - 2, size[1]) if name == mismatch else size
            cv2.imwrite(
                str(root / "captures" / f"{name}@{k}.png"), rng.integers(0, 255, size=(*shape, 3), dtype=np.uint8)
            )


def test_captured_pairs_layout_and_refusals(tmp_path):
    _write_pairs(tmp_path / "ok", [f"s{k:02d}" for k in range(10)])
    train, validation = read_pairs(tmp_path / "ok")
    assert len(train) == 18 and len(validation) == 2  # the last scene (two captures) is held out
    assert train.clean.shape[1:] == (3, 40, 40)  # centred square crops
    _write_pairs(tmp_path / "bad", ["a", "b"], mismatch="b")
    with pytest.raises(InputError, match="aligned"):
        read_pairs(tmp_path / "bad")
    (tmp_path / "orphan" / "gt").mkdir(parents=True)
    (tmp_path / "orphan" / "captures").mkdir()
    (tmp_path / "orphan" / "captures" / "x.png").write_bytes((tmp_path / "bad" / "gt" / "a.png").read_bytes())
    with pytest.raises(InputError, match="captures has x without a gt image"):
        read_pairs(tmp_path / "orphan")


def test_captured_pairs_refuse_uncaptured_scenes_and_too_few_to_hold_out(tmp_path):
    """Every gt scene has a capture (as evaluate --pairs requires), and the validation scenes
    are apart from the training ones, so a single scene (however many captures) is refused."""
    _write_pairs(tmp_path / "uncaptured", ["a", "b", "c"])
    for k in range(2):
        (tmp_path / "uncaptured" / "captures" / f"b@{k}.png").unlink()
    with pytest.raises(InputError, match="captures lacks b") as error:
        read_pairs(tmp_path / "uncaptured")
    assert error.value.field == "--pairs"
    _write_pairs(tmp_path / "one", ["only"])
    with pytest.raises(InputError, match="holds 1 scene") as error:
        read_pairs(tmp_path / "one")
    assert error.value.field == "--pairs" and "at least 2 scenes" in error.value.expected
    _write_pairs(tmp_path / "two", ["a", "b"])
    (tmp_path / "two" / "gt" / "a.tif").write_bytes((tmp_path / "two" / "gt" / "a.png").read_bytes())
    with pytest.raises(InputError, match="a.png and a.tif in .* name one scene"):  # which would it take?
        read_pairs(tmp_path / "two")
    (tmp_path / "two" / "gt" / "a.tif").unlink()
    train, validation = read_pairs(tmp_path / "two")
    assert len(train) == 2 and len(validation) == 2  # scene a's two captures train, scene b's validate
    assert not set(map(bytes, train.clean)) & set(map(bytes, validation.clean))


def _states(run: Path) -> dict:
    return torch.load(run / "model.pt", weights_only=True)["state_dict"]


def test_resume_repeats_an_uninterrupted_run(tmp_path):
    preset = load_reconstruct_preset(TINY)
    whole = train_reconstruction(_design(), CAMERA, preset, tmp_path / "whole").report
    train_reconstruction(_design(), CAMERA, preset, tmp_path / "parts", steps=2)
    resumed = train_reconstruction(_design(), CAMERA, None, tmp_path / "parts", steps=4, resume=True).report
    a, b = _states(tmp_path / "whole"), _states(tmp_path / "parts")
    assert all(torch.equal(a[k], b[k]) for k in a)
    first = json.loads((tmp_path / "whole" / "run.json").read_text())
    assert first["validation"]["final"] == resumed["validation"]["final"]
    assert [v["step"] for v in whole["validation"]["history"]] == [0, 2, 4]  # validate_every = 2
    assert whole["loss_terms"][:2] == ["l1", "ssim"]
    with pytest.raises(InputError, match="not the design the run was made for"):
        train_reconstruction(_design("500nm"), CAMERA, None, tmp_path / "parts", steps=6, resume=True)
    with pytest.raises(InputError, match="below the 4 steps"):
        train_reconstruction(_design(), CAMERA, None, tmp_path / "parts", steps=3, resume=True)
    with pytest.raises(InputError, match="already holds a run"):
        train_reconstruction(_design(), CAMERA, preset, tmp_path / "parts")


def _train_cli(out: Path, ranks: int) -> dict:
    args = [
        "reconstruct",
        "train",
        "hyperbolic:532nm",
        "--f",
        "1mm",
        "--aperture",
        "0.2mm",
        "--preset",
        str(TINY),
        "--steps",
        "3",
    ]
    return _states(run_metalens(args, out, ranks=ranks))


def test_two_process_torchrun_equals_one_process(tmp_path):
    single = _train_cli(tmp_path / "one", 1)
    parallel = _train_cli(tmp_path / "two", 2)
    # the batch of 2 split 1 + 1, gradients summed by all_reduce: only the summation order differs
    for k in single:
        torch.testing.assert_close(parallel[k], single[k], rtol=0, atol=1e-5)
    moved = max(float((single[k] - torch.zeros_like(single[k])).abs().max()) for k in single if k.startswith("head"))
    assert moved > 0  # the head left zero: both runs learned something


def test_trained_on_identical_pairs_the_network_stays_the_identity(tmp_path):
    """Captures equal to their references, no augmentation: the network must not learn to change an
    image (inputs and targets misaligned by a crop, turn or flip would teach it to; so would an
    untrained network that is the identity only up to rounding). The L1 term alone: SSIM's gradient
    at equality is zero only up to rounding (~2e-8), which Adam's normalised steps would turn into
    lr-sized moves (an optimiser property, not the pipeline's)."""
    import cv2

    from metalens_cli.design.scenes import procedural_scene
    from metalens_cli.imaging.restore import load_reconstructor
    from metalens_cli.io.image_files import linear_to_srgb

    rng = np.random.default_rng(4)
    (tmp_path / "pairs" / "gt").mkdir(parents=True)
    (tmp_path / "pairs" / "captures").mkdir()
    for k in range(4):
        image = np.round(linear_to_srgb(procedural_scene((48, 48), rng)) * 255).astype(np.uint8)
        for folder in ("gt", "captures"):
            cv2.imwrite(str(tmp_path / "pairs" / folder / f"s{k}.png"), image.transpose(1, 2, 0)[..., ::-1])
    preset = load_reconstruct_preset(TINY)
    preset = dataclasses.replace(
        preset,
        train=dataclasses.replace(preset.train, steps=6, ssim=0.0, lpips=0.0),
        data=dataclasses.replace(preset.data, noise_sigma=0.0, brightness=0.0, contrast=0.0),
    )
    train_reconstruction(_design(), CAMERA, preset, tmp_path / "run", pairs=tmp_path / "pairs")
    held_out = procedural_scene((64, 80), np.random.default_rng(9))
    out = load_reconstructor(tmp_path / "run")(held_out)
    np.testing.assert_allclose(out, held_out, rtol=0, atol=1e-3)
