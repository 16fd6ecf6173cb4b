"""Registration of captures onto references (imaging.registration): a known homography and smooth
ripple recovered, refinement shown to matter, blur and colour changes tolerated, unrelated images
refused, warps saved and reloaded exactly."""

import math

import cv2
import numpy as np
import pytest
from synthetic import texture, warp

from metalens_cli.errors import InputError, ResultFailed
from metalens_cli.imaging import registration
from metalens_cli.imaging.registration import Registration, expand_flow, load_warp, register, save_warp
from metalens_cli.io.warp_files import node_positions

SIDE = 320
ANGLE = math.radians(4)
# target pixel → reference pixel (the camera's view of the scene): rotation, zoom, shift, perspective
CAMERA = np.array(
    [
        [1.04 * math.cos(ANGLE), -1.04 * math.sin(ANGLE), 12.0],
        [1.04 * math.sin(ANGLE), 1.04 * math.cos(ANGLE), -9.0],
        [3e-5, -2e-5, 1.0],
    ]
)
GAIN, BIAS = np.array([0.7, 0.5, 0.8], np.float32), 0.04


def psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    return 10 * math.log10(1 / float(np.mean((a[mask] - b[mask]) ** 2)))


@pytest.fixture(scope="module")
def scene():
    return texture(SIDE, SIDE, 0)


@pytest.fixture(scope="module")
def rippled(scene):
    """A target with the camera's homography and a 3-pixel smooth ripple, registered by flow."""
    target = warp(scene, CAMERA, ripple_px=3.0)
    return target, register(scene, target, refine="flow")


def test_recovers_the_homography(scene):
    target = warp(scene, CAMERA)
    r = register(scene, target, refine="none")
    assert r.flow is None and r.refine == "none" and r.inliers >= 100 and r.residual_px < 0.3
    # H maps reference → target, the inverse of the camera's target → reference map
    grid = np.stack(np.meshgrid(np.linspace(0, SIDE - 1, 9), np.linspace(0, SIDE - 1, 9)), axis=-1).reshape(-1, 2)
    there = cv2.perspectiveTransform(grid[None], r.homography)
    back = cv2.perspectiveTransform(there, CAMERA)[0]
    assert np.abs(back - grid).max() < 0.2
    mask = r.valid_mask()
    assert mask.mean() > 0.9 and psnr(r.apply(target), scene, mask) > 40


def test_flow_recovers_a_smooth_warp_and_matters(scene, rippled):
    target, flow = rippled
    mask = flow.valid_mask()
    flat = register(scene, target, refine="none")
    with_flow, without = psnr(flow.apply(target), scene, mask), psnr(flat.apply(target), scene, flat.valid_mask())
    assert with_flow >= 30 and with_flow > without + 10
    report = flow.to_report()
    assert (
        report["refine"] == "flow"
        and 1.0 < report["flow_rms_px"] < 5
        and report["refined_residual_px"] < 0.5 * report["residual_px"]
    )
    assert any("--refine flow" in w for w in flat.warnings()) and flow.warnings() == []


def test_thin_plate_spline_recovers_a_smooth_warp(scene, rippled):
    target, _ = rippled
    r = register(scene, target, refine="tps")
    assert r.refine == "tps" and r.flow.shape == (SIDE, SIDE, 2)
    assert psnr(r.apply(target), scene, r.valid_mask()) >= 30


def test_blurred_dimmer_recoloured_target(scene):
    blurred = cv2.GaussianBlur(scene, (0, 0), 1.5)
    target = warp(blurred, CAMERA, ripple_px=2.0) * GAIN + BIAS
    r = register(scene, target)
    aligned = (r.apply(target) - BIAS) / GAIN
    assert psnr(aligned, blurred, r.valid_mask()) >= 30


def test_unrelated_images_are_refused(scene):
    with pytest.raises(ResultFailed) as failure:
        register(scene, texture(SIDE, SIDE, 1), field="shot.png")
    message = str(failure.value)
    assert message.startswith("shot.png: only ") and "REFERENCE" in message and "\n" not in message


def test_uniform_and_bad_arrays(scene):
    with pytest.raises(ResultFailed, match="uniform"):
        register(scene, np.full((SIDE, SIDE, 3), 0.5, np.float32))
    bad = [np.zeros(SIDE), np.zeros((8, 8)), np.full((64, 64), np.nan), np.zeros((64, 64, 3), dtype=bool), "image.png"]
    for array in bad:
        with pytest.raises(InputError):
            register(scene, array)
    with pytest.raises(InputError, match="refine"):
        register(scene, scene, refine="spline")


def test_degenerate_homographies_are_refused():
    points = np.array([[0, 0], [300, 0], [0, 300], [300, 300]], np.float32)
    cases = {
        "mirrors": np.diag([-1.0, 1.0, 1.0]) + np.array([[0, 0, 319], [0, 0, 0], [0, 0, 0]]),
        "scale change": np.diag([10.0, 10.0, 1.0]),
        "stretches": np.diag([3.0, 0.5, 1.0]),
        "horizon": np.array([[1, 0, 0], [0, 1, 0], [-0.004, 0, 1.0]]),
        "covers only": np.array([[1, 0, 300], [0, 1, 300], [0, 0, 1.0]]),
    }
    for why, homography in cases.items():
        with pytest.raises(ResultFailed, match=why):
            registration._check_homography(homography, points, (SIDE, SIDE), (SIDE, SIDE), "TARGET")
    with pytest.raises(ResultFailed, match="cover only 0.0 %"):
        registration._check_homography(np.eye(3), points / 100, (SIDE, SIDE), (SIDE, SIDE), "TARGET")


def test_flow_nodes_expand_exactly():
    rng = np.random.default_rng(0)
    shape = (37, 50)
    rows, columns = node_positions(shape[0], 4), node_positions(shape[1], 4)
    assert rows.tolist() == [0, 4, 8, 12, 16, 20, 24, 28, 32, 36] and columns[-2:].tolist() == [48, 49]
    nodes = rng.normal(size=(rows.size, columns.size, 2)).astype(np.float32)
    flow = expand_flow(nodes, 4, shape)
    assert flow.shape == (*shape, 2) and flow.dtype == np.float32
    assert np.array_equal(flow[rows][:, columns], nodes)
    assert np.allclose(flow[0, 2], 0.5 * (nodes[0, 0] + nodes[0, 1]))
    assert np.array_equal(expand_flow(flow, 1, shape), flow)


def test_apply_channels_and_outside(rippled):
    target, r = rippled
    mask = r.valid_mask()
    many = np.concatenate([target, target[:, :, :2]], axis=2)
    out = r.apply(many)
    assert out.shape == (SIDE, SIDE, 5) and out.dtype == np.float32
    assert np.array_equal(out[:, :, 3], r.apply(target[:, :, 0])) and np.array_equal(out[:, :, :3], r.apply(target))
    assert np.array_equal(r.apply(target[:, :, :1])[:, :, 0], out[:, :, 0])
    assert not mask.all() and np.all(out[~mask] == 0) and out[mask].min() >= target.min()
    with pytest.raises(InputError, match="320 × 320"):
        r.apply(target[:100])


@pytest.mark.parametrize("refine", ["flow", "tps", "none"])
def test_save_and_load_reproduce_apply(tmp_path, scene, rippled, refine):
    target, r = rippled
    if refine != "flow":
        r = register(scene, target, refine=refine)
    path = tmp_path / "warp.npz"
    save_warp(path, r)
    loaded = load_warp(path)
    assert np.array_equal(loaded.apply(target), r.apply(target)) and np.array_equal(loaded.valid_mask(), r.valid_mask())
    assert loaded.to_report() == r.to_report() and loaded.flow_step == r.flow_step
    assert [p.name for p in tmp_path.iterdir()] == ["warp.npz"]  # no temporary file left


def test_a_registration_with_a_dense_flow_saves_exactly(tmp_path):
    flow = np.random.default_rng(1).normal(size=(40, 48, 2)).astype(np.float32)
    r = Registration(np.eye(3), flow, (40, 48), (40, 48), 50, 40, 0.5, "flow")
    save_warp(tmp_path / "w.npz", r)
    assert np.array_equal(load_warp(tmp_path / "w.npz").flow, flow)


def test_load_warp_refuses_what_is_not_a_warp(tmp_path, rippled):
    _, r = rippled
    good = tmp_path / "good.npz"
    save_warp(good, r)
    fields = dict(np.load(good))

    def variant(name, **changes):
        path = tmp_path / name
        np.savez(path, **{**fields, **changes})
        return path

    text = tmp_path / "notes.npz"
    text.write_text("not a zip")
    missing = tmp_path / "missing.npz"
    np.savez(missing, **{k: v for k, v in fields.items() if k != "homography"})
    cases = [
        (tmp_path / "absent.npz", "no such file"),
        (text, "not a readable warp file"),
        (missing, "has no 'homography'"),
        (variant("format.npz", format=np.array("metalens-warp/9")), "format"),
        (variant("nan.npz", homography=np.full((3, 3), np.nan)), "not finite"),
        (variant("nodes.npz", flow_nodes=fields["flow_nodes"][:-1]), "do not match"),
        (variant("refine.npz", refine=np.array("magic")), "unknown refine"),
        (variant("object.npz", matches=np.array([1, 2])), "'matches'"),
    ]
    for path, text_in_message in cases:
        with pytest.raises(InputError) as failure:
            load_warp(path)
        assert failure.value.field == "--warp" and text_in_message in failure.value.message, (
            path.name,
            str(failure.value),
        )


@pytest.mark.parametrize(
    ("homography", "why"),
    [
        ([[-1.0, 0, 255], [0, 1, 0], [0, 0, 1]], "mirrors"),
        ([[1e-9, 0, 0], [0, 1e-9, 0], [0, 0, 1]], "scale change"),
        ([[1.0, 0, 0], [0, 1, 0], [-0.01, 0, 1]], "horizon"),
    ],
)
def test_a_degenerate_saved_warp_is_refused(tmp_path, homography, why):
    """A warp file is input: --warp refuses what registration itself would never produce."""
    from metalens_cli.errors import InputError
    from metalens_cli.imaging.registration import Registration, load_warp, save_warp

    path = tmp_path / "w.npz"
    save_warp(path, Registration(np.array(homography), None, (256, 256), (256, 256), 100, 80, 0.5, "none"))
    with pytest.raises(InputError, match=why):
        load_warp(path)
