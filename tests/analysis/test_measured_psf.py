"""Measured PSF import (analysis.measured_psf, io.psf_manifest) against known synthetic frames:
Gaussian spots integrated over pixels, Poisson photons, dark offset, read noise, 16-bit."""

import math
import re

import cv2
import numpy as np
import pytest
from synthetic import bench_frame, gaussian_spot

from metalens_cli.analysis.measured_psf import ImportSettings, dark_frame, import_psfs
from metalens_cli.analysis.mtf import cube_mtf
from metalens_cli.errors import InputError
from metalens_cli.io.exr import PsfCube
from metalens_cli.io.psf_manifest import read_frame_file, read_manifest

PITCH = 1.85e-6
SHAPE = (160, 170)


def write_bench(folder, spots, rng, exposure="10ms", **noise):
    """Frames (one per (wavelength nm, depth text, spot)) as 16-bit PNGs and their CSV manifest."""
    rows = ["file,wavelength,depth,exposure"]
    for k, (wavelength, depth, spot) in enumerate(spots):
        cv2.imwrite(str(folder / f"frame{k:02d}.png"), bench_frame(spot, rng, **noise))
        rows.append(f"frame{k:02d}.png,{wavelength}nm,{depth},{exposure}")
    (folder / "psf.csv").write_text("\n".join(rows) + "\n")
    return folder / "psf.csv"


def centroid(psf):
    yy, xx = np.indices(psf.shape)
    return (psf * yy).sum() / psf.sum(), (psf * xx).sum() / psf.sum()


@pytest.mark.parametrize("sigma", [1.5, 3.0])
def test_gaussian_spot_gives_its_mtf50_within_3_percent(tmp_path, sigma):
    """A Gaussian of σ pixels has MTF exp(−2π²σ²f²) once the pixel aperture is divided out:
    MTF50 = √(ln 2 / 2π²σ²) cycles/pixel, from noisy 16-bit frames with a dark frame."""
    rng = np.random.default_rng(3)
    spots = [
        (530, "inf", gaussian_spot(*SHAPE, (80.3, 84.6), sigma)),
        (630, "inf", gaussian_spot(*SHAPE, (77.8, 90.2), sigma)),
    ]
    manifest = read_manifest(write_bench(tmp_path, spots, rng, photons=6e5))
    dark = bench_frame(np.zeros(SHAPE), rng, background=0.0)
    cube = import_psfs(manifest, ImportSettings(PITCH), dark_frame(dark[:, :, None].astype(np.float32), 6.0))
    psf_cube = PsfCube(cube.psf, None, cube.wavelengths_m, cube.depths_m, {"pixel_pitch_m": PITCH})
    measured = cube_mtf(psf_cube, remove_pixel_mtf=True).mtf50_lpmm[0]
    expected = math.sqrt(math.log(2) / (2 * math.pi**2 * sigma**2)) / PITCH * 1e-3
    np.testing.assert_allclose(measured, expected, rtol=0.03)


@pytest.mark.parametrize("offset", [(0.0, 0.0), (0.3, -0.17), (-0.45, 0.5), (0.21, 0.49)])
def test_a_spot_at_a_known_subpixel_offset_is_centred_within_005_px(tmp_path, offset):
    rng = np.random.default_rng(7)
    truth = (81 + offset[0], 77 + offset[1])
    manifest = read_manifest(write_bench(tmp_path, [(530, "45mm", gaussian_spot(*SHAPE, truth, 2.2))], rng))
    cube = import_psfs(manifest, ImportSettings(PITCH, pixels=41))
    assert np.allclose(cube.frames[0]["centre_px"], truth, atol=0.05)
    n = cube.psf.shape[-1]
    assert np.allclose(centroid(cube.psf[0, 0].astype(float)), (n // 2, n // 2), atol=0.05)


@pytest.mark.parametrize("frame", ["float", "16-bit on an offset"])
def test_a_noiseless_simulated_spot_is_the_spot_centred(tmp_path, frame):
    """No noise at all (border σ = 0, a constant border): the PSF is the same spot integrated
    over pixels centred on (N//2, N//2), up to the Fourier shift's and 16-bit rounding's error."""
    spot = gaussian_spot(*SHAPE, (80.3, 77.6), 2.0)
    if frame == "float":
        np.save(tmp_path / "spot.npy", spot.astype(np.float32))
        name = "spot.npy"
    else:
        cv2.imwrite(str(tmp_path / "spot.png"), np.rint(100 + 60000 * spot / spot.max()).astype(np.uint16))
        name = "spot.png"
    (tmp_path / "psf.csv").write_text(f"file,wavelength,depth\n{name},530nm,inf\n")
    cube = import_psfs(read_manifest(tmp_path / "psf.csv"), ImportSettings(PITCH, pixels=41))
    expected = gaussian_spot(41, 41, (20, 20), 2.0)
    np.testing.assert_allclose(cube.psf[0, 0], expected / expected.sum(), atol=2e-4 * expected.max() / expected.sum())
    assert np.allclose(cube.frames[0]["centre_px"], (80.3, 77.6), atol=0.01) and cube.warnings == []


@pytest.mark.parametrize(
    ("values", "settings", "message"),
    [
        (np.full(SHAPE, 1000, np.uint16), {}, "psf.csv line 3: blank.png has no light above the background noise"),
        (
            np.full(SHAPE, 65535, np.uint16),
            {"allow_saturated": True},
            f"blank.png has no light above the background noise ({SHAPE[0] * SHAPE[1]} of its {SHAPE[0] * SHAPE[1]} "
            "pixels saturated)",
        ),
        (np.full(SHAPE, 0.25, np.float32), {}, "psf.csv line 3: blank.npy has no light above the background noise"),
    ],
    ids=["flat", "all saturated", "flat float"],
)
def test_a_frame_without_a_spot_is_refused_naming_its_line(tmp_path, values, settings, message):
    cv2.imwrite(str(tmp_path / "spot.png"), bench_frame(gaussian_spot(*SHAPE, (80, 80), 2.0), np.random.default_rng(8)))
    name = "blank.npy" if values.dtype == np.float32 else "blank.png"
    np.save(tmp_path / name, values) if name.endswith(".npy") else cv2.imwrite(str(tmp_path / name), values)
    (tmp_path / "psf.csv").write_text(f"file,wavelength,depth\nspot.png,530nm,inf\n{name},630nm,inf\n")
    with pytest.raises(InputError, match=re.escape(message)):
        import_psfs(read_manifest(tmp_path / "psf.csv"), ImportSettings(PITCH, **settings))


def test_a_dark_frame_brighter_than_the_frames_is_warned_about_once(tmp_path):
    """The frames sit on a 600-count dark offset: a dark frame of that offset says nothing, one
    of 3000 counts (another exposure or gain) one line for both frames."""
    rng = np.random.default_rng(10)
    spots = [(w, "inf", gaussian_spot(*SHAPE, (80, 80), 2.0)) for w in (530, 630)]
    manifest = read_manifest(write_bench(tmp_path, spots, rng))
    matched, bright = (bench_frame(np.zeros(SHAPE), rng, dark_level=level, background=0.0) for level in (600.0, 3000.0))
    assert (
        import_psfs(manifest, ImportSettings(PITCH), dark_frame(matched[:, :, None].astype(np.float32), 6.0)).warnings
        == []
    )
    said = import_psfs(manifest, ImportSettings(PITCH), dark_frame(bright[:, :, None].astype(np.float32), 6.0)).warnings
    assert len(said) == 1 and "the dark frame is brighter than the background of 2 of 2 frame(s)" in said[0]


def test_peak_centring_puts_the_maximum_on_the_axis_where_the_centroid_does_not(tmp_path):
    """A spot with a faint side lobe: its centroid sits off the peak."""
    spot = 0.8 * gaussian_spot(*SHAPE, (80.0, 80.0), 1.8) + 0.2 * gaussian_spot(*SHAPE, (80.0, 92.0), 2.5)
    manifest = read_manifest(write_bench(tmp_path, [(530, "inf", spot)], np.random.default_rng(1)))
    n = 51
    for centring, on_axis in (("peak", True), ("centroid", False)):
        psf = import_psfs(manifest, ImportSettings(PITCH, pixels=n, centring=centring)).psf[0, 0]
        assert (np.unravel_index(np.argmax(psf), psf.shape) == (n // 2, n // 2)) is on_axis


def test_normalisations_and_the_pitch_through_the_relay(tmp_path):
    manifest = read_manifest(
        write_bench(tmp_path, [(530, "inf", gaussian_spot(*SHAPE, (80, 80), 2.0))], np.random.default_rng(2))
    )
    summed = import_psfs(manifest, ImportSettings(5.5e-6, magnification=2.0))
    peaked = import_psfs(manifest, ImportSettings(5.5e-6, normalization="peak-one"))
    assert summed.psf.sum() == pytest.approx(1.0, abs=1e-5) and peaked.psf.max() == pytest.approx(1.0, abs=1e-6)
    assert summed.pixel_pitch_m == pytest.approx(2.75e-6)
    # the automatic window holds the light: a σ = 2 px spot needs well under 41 pixels, more than 11
    assert 11 < summed.psf.shape[-1] < 41


def test_saturated_frames_are_refused_or_imported_and_reported(tmp_path):
    spot = gaussian_spot(*SHAPE, (80, 80), 1.2)
    path = write_bench(tmp_path, [(530, "inf", spot)], np.random.default_rng(4), photons=4e6)
    with pytest.raises(InputError, match=r"psf.csv line 2: frame00.png has \d+ saturated pixel"):
        import_psfs(read_manifest(path), ImportSettings(PITCH))
    cube = import_psfs(read_manifest(path), ImportSettings(PITCH, allow_saturated=True))
    assert cube.frames[0]["saturated_pixels"] > 0 and "saturated" in cube.warnings[0]
    with pytest.raises(InputError, match="saturated"):  # a 12-bit camera's level, given explicitly
        import_psfs(
            read_manifest(write_bench(tmp_path, [(530, "inf", spot)], np.random.default_rng(4), photons=2e5)),
            ImportSettings(PITCH, saturation=4095),
        )


def test_hot_pixels_are_replaced_and_a_sharp_core_is_kept(tmp_path):
    """Isolated hot pixels in every frame are found without a dark frame; an undersampled but
    bright spot (σ = 0.5 px, peak 20× its neighbours) is not mistaken for one."""
    rng = np.random.default_rng(5)
    hot = [(20, 30), (75, 95), (140, 150)]  # one inside the light's window
    spots = [(w, "inf", gaussian_spot(*SHAPE, (80.0, 80.0), 0.5 if w == 530 else 2.5)) for w in (450, 530, 630)]
    rows = ["file,wavelength,depth"]
    for k, (w, depth, spot) in enumerate(spots):
        frame = bench_frame(spot, rng, photons=5e4)
        for y, x in hot:
            frame[y, x] = 20000
        cv2.imwrite(str(tmp_path / f"f{k}.png"), frame)
        rows.append(f"f{k}.png,{w}nm,{depth}")
    (tmp_path / "psf.csv").write_text("\n".join(rows) + "\n")
    cube = import_psfs(read_manifest(tmp_path / "psf.csv"), ImportSettings(PITCH, pixels=41))
    assert cube.hot_pixels == len(hot)
    sharp = cube.psf[0, 1]
    assert (
        np.unravel_index(np.argmax(sharp), sharp.shape) == (20, 20) and sharp.max() > 0.4
    )  # the core kept (a σ = 0.5 px spot puts 0.47 in its pixel)
    kept = import_psfs(read_manifest(tmp_path / "psf.csv"), ImportSettings(PITCH, pixels=41, hot_pixel_sigma=0))
    assert (
        kept.hot_pixels == 0 and kept.psf[0, 0].max() > 5 * cube.psf[0, 0].max()
    )  # the hot pixel in the window dominates


def test_photon_noise_in_bright_light_is_not_taken_for_hot_pixels(tmp_path):
    """Four bright blurred frames (photon noise far above the background's σ, so about 40 % of
    their pixels stand 6σ over their neighbours' median) and one sharp frame with a speckled
    halo (isolated bright pixels on a dark background, like a lens' faint rings): a speckle that
    also spikes in every blurred frame looks hot in every frame but is isolated in one only.
    Only the planted hot pixels are found."""
    rng = np.random.default_rng(9)
    hot = [(15, 15), (140, 30), (30, 150)]
    angle, radius = rng.uniform(0, 2 * np.pi, 300), rng.uniform(8, 25, 300)
    speckles = (np.rint(80 + radius * np.sin(angle)).astype(int), np.rint(85 + radius * np.cos(angle)).astype(int))
    rows = ["file,wavelength,depth"]
    for k, w in enumerate((450, 500, 550, 600, 650)):
        sharp = w == 550
        frame = bench_frame(
            gaussian_spot(*SHAPE, (80.0, 85.0), 0.8 if sharp else 12.0), rng, photons=2e4 if sharp else 4.5e7
        )
        if sharp:
            frame[speckles] += np.uint16(300)
        for y, x in hot:
            frame[y, x] += 15000
        cv2.imwrite(str(tmp_path / f"f{k}.png"), frame)
        rows.append(f"f{k}.png,{w}nm,inf")
    (tmp_path / "psf.csv").write_text("\n".join(rows) + "\n")
    assert import_psfs(read_manifest(tmp_path / "psf.csv"), ImportSettings(PITCH, pixels=41)).hot_pixels == len(hot)


def test_repeats_are_averaged_after_scaling_by_exposure(tmp_path):
    spot = gaussian_spot(*SHAPE, (80, 80), 2.0)
    rng = np.random.default_rng(6)
    for k, photons in enumerate((2e5, 4e5)):
        cv2.imwrite(str(tmp_path / f"r{k}.png"), bench_frame(spot, rng, photons=photons))
    (tmp_path / "psf.csv").write_text("file,wavelength,depth,exposure\nr0.png,530nm,inf,5ms\nr1.png,530nm,inf,10ms\n")
    cube = import_psfs(read_manifest(tmp_path / "psf.csv"), ImportSettings(PITCH))
    assert cube.psf.shape[:2] == (1, 1) and len(cube.frames) == 2
    assert cube.frames[0]["noise"] > cube.frames[1]["noise"]  # per second: the shorter exposure is noisier


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("file,wavelength\nf.png,530nm\n", "lacks the column(s) depth"),
        ("file,wavelength,depth,gain\n", "unknown column(s) gain"),
        ("file,wavelength,depth\nf.png,530,inf\n", "has no unit"),
        ("file,wavelength,depth\nf.png,20um,inf\n", "20000 nm is not an optical wavelength"),
        ("file,wavelength,depth\nmissing.png,530nm,inf\n", "no such file"),
        ("file,wavelength,depth\nf.png,530nm,inf,extra\n", "4 values for 3 columns"),
        ("file,wavelength,depth,exposure\nf.png,530nm,inf,-1ms\n", "exposure: '-1ms'"),
        ("file,wavelength,depth\nf.png,530nm,inf\nf.png,630nm,45mm\n", "has no frame at 530 nm, depth 45 mm"),
        ("file,wavelength,depth\nf.txt,530nm,inf\n", "is not a frame format"),
        ("file,wavelength,depth\n", "lists no frames"),
        ("file,wavelength,depth,exposure\nf.png,530nm,inf,1e-300\n", "exposure: '1e-300'"),
        (
            "file,wavelength,depth,exposure\nf.png,530nm,inf,\nf.png,530nm,inf,10ms\n",
            "line 2: has no exposure while other frames have one",
        ),
        ("file,wavelength,depth\nf.png,,inf\n", "wavelength is missing"),
    ],
)
def test_bad_manifests_are_one_line_errors(tmp_path, text, message):
    cv2.imwrite(str(tmp_path / "f.png"), np.zeros((20, 20), np.uint16))
    (tmp_path / "f.txt").write_text("x")
    (tmp_path / "psf.csv").write_text(text)
    with pytest.raises(InputError, match=re.escape(message)) as caught:
        read_manifest(tmp_path / "psf.csv")
    assert "\n" not in str(caught.value)


def test_a_byte_order_mark_and_a_stack_without_index(tmp_path):
    cv2.imwrite(str(tmp_path / "f.png"), np.zeros((20, 20), np.uint16))
    (tmp_path / "psf.csv").write_bytes("\ufefffile,wavelength,depth\nf.png,530nm,inf\n".encode("utf-8"))
    assert len(read_manifest(tmp_path / "psf.csv").frames) == 1  # Excel's "CSV UTF-8" starts with a byte-order mark
    np.save(tmp_path / "s.npy", np.zeros((3, 20, 20), np.uint16))
    (tmp_path / "s.csv").write_text("file,wavelength,depth\ns.npy,530nm,inf\n")
    with pytest.raises(
        InputError, match="s.npy is a stack of 3 frames"
    ):  # a dark stack is averaged; a frame must be named
        import_psfs(read_manifest(tmp_path / "s.csv"), ImportSettings(PITCH))


def test_values_overflowing_single_precision_are_refused(tmp_path):
    import OpenEXR

    frame = np.full((64, 64), 1.0, np.float32)
    frame[30:34, 30:34] = 3e38
    OpenEXR.File({"type": OpenEXR.scanlineimage}, {"Y": frame}).write(str(tmp_path / "f.exr"))
    (tmp_path / "psf.csv").write_text("file,wavelength,depth,exposure\nf.exr,530nm,inf,10ms\n")
    with pytest.raises(InputError, match="overflow single precision"):
        import_psfs(read_manifest(tmp_path / "psf.csv"), ImportSettings(PITCH))


def test_a_tilted_background_does_not_pull_the_centroid(tmp_path):
    """Stray light rising 20 counts per pixel across the frame: the plane fitted to the border
    takes it out (a median would leave a ramp that moves the centroid by ~0.4 px)."""
    rng = np.random.default_rng(12)
    truth = (81.2, 77.6)
    spot = gaussian_spot(*SHAPE, truth, 2.2)
    ramp = 20.0 * np.arange(SHAPE[1])[None, :] + np.zeros(SHAPE)
    frame = np.clip(bench_frame(spot, rng).astype(float) + ramp, 0, 65535).astype(np.uint16)
    cv2.imwrite(str(tmp_path / "f.png"), frame)
    (tmp_path / "psf.csv").write_text("file,wavelength,depth\nf.png,530nm,inf\n")
    cube = import_psfs(read_manifest(tmp_path / "psf.csv"), ImportSettings(PITCH, pixels=41))
    assert np.allclose(cube.frames[0]["centre_px"], truth, atol=0.05)


def test_light_in_the_border_and_a_window_too_small_or_too_large_are_said(tmp_path):
    manifest = read_manifest(
        write_bench(
            tmp_path, [(530, "inf", gaussian_spot(*SHAPE, (80, 85), 30.0))], np.random.default_rng(13), photons=5e7
        )
    )
    wide = import_psfs(manifest, ImportSettings(PITCH))
    assert any("border strip bulges" in w for w in wide.warnings)
    narrow = import_psfs(
        read_manifest(
            write_bench(tmp_path, [(530, "inf", gaussian_spot(*SHAPE, (80, 85), 2.0))], np.random.default_rng(14))
        ),
        ImportSettings(PITCH, pixels=3),
    )
    assert any("window keeps" in w for w in narrow.warnings)
    with pytest.raises(InputError, match="larger than the 170 × 160 frames"):
        import_psfs(manifest, ImportSettings(PITCH, pixels=161))


def test_toml_and_pattern_manifests_name_the_same_frames(tmp_path):
    rng = np.random.default_rng(8)
    for name in ("psf_530nm_inf.png", "psf_630nm_inf.png"):
        cv2.imwrite(str(tmp_path / name), bench_frame(gaussian_spot(40, 40, (20, 20), 2.0), rng))
    (tmp_path / "m.toml").write_text(
        'pixel_pitch = "3.45um"\nmagnification = 2\n'
        '[[frame]]\nfile = "psf_530nm_inf.png"\nwavelength = "530nm"\ndepth = "inf"\n'
        '[[frame]]\nfile = "psf_630nm_inf.png"\nwavelength = "630nm"\ndepth = "inf"\n'
    )
    toml = read_manifest(tmp_path / "m.toml")
    pattern = read_manifest(tmp_path, "psf_{wavelength}_{depth}.png")
    assert [(f.path, f.wavelength_m, f.depth_m) for f in toml.frames] == [
        (f.path, f.wavelength_m, f.depth_m) for f in pattern.frames
    ]
    assert toml.settings == {"pixel_pitch_m": 3.45e-6, "magnification": 2.0}
    assert toml.wavelengths_m == [530e-9, 630e-9] and toml.depths_m == [math.inf]


def test_a_frame_of_a_npy_stack(tmp_path):
    stack = np.stack([np.full((20, 20), k, np.uint16) for k in range(3)])
    np.save(tmp_path / "s.npy", stack)
    values, full_scale = read_frame_file(tmp_path / "s.npy", 2, "f")
    assert values.shape == (20, 20, 1) and values.max() == 2 and full_scale == 65535
    assert read_frame_file(tmp_path / "s.npy", None, "dark")[0].max() == 1  # a stack without index: its mean
    with pytest.raises(InputError, match="the stack has 3 frames"):
        read_frame_file(tmp_path / "s.npy", 3, "f")


def _airy_spot(shape, centre, first_zero_px):
    """An Airy pattern (2·J1(v)/v)², its first zero ``first_zero_px`` from ``centre``, sampled at
    pixel centres on 4 × 4 sub-pixels, unit sum: rings separated by dark zeros."""
    from scipy.special import j1

    sub = (np.arange(4) + 0.5) / 4 - 0.5
    yy = np.arange(shape[0])[:, None, None, None] + sub[None, None, :, None] - centre[0]
    xx = np.arange(shape[1])[None, :, None, None] + sub[None, None, None, :] - centre[1]
    v = 3.8317 * np.hypot(yy, xx) / first_zero_px + 1e-12
    spot = ((2 * j1(v) / v) ** 2).mean(axis=(2, 3))
    return spot / spot.sum()


def _ring(shape, centre, radius_px, width_px):
    """A thin annulus (Gaussian profile across it) of unit sum around ``centre``."""
    yy, xx = np.indices(shape)
    ring = np.exp(-0.5 * ((np.hypot(yy - centre[0], xx - centre[1]) - radius_px) / width_px) ** 2)
    return ring / ring.sum()


def test_a_second_spot_is_warned_about_but_rings_around_one_are_not(tmp_path):
    """A ghost at 30 % beside the spot pulls the centroid between them: the import says so. An
    Airy pattern's first ring (cut off by a dark zero), a sharp core inside a bright rim of
    defocused light (half of it, 30 px out) and a lone Gaussian are one spot each."""
    rng = np.random.default_rng(21)
    ghost = 0.77 * gaussian_spot(*SHAPE, (80, 50), 2.0) + 0.23 * gaussian_spot(*SHAPE, (80, 120), 2.0)
    rim = 0.5 * gaussian_spot(*SHAPE, (80, 85), 2.0) + 0.5 * _ring(SHAPE, (80, 85), 30.0, 2.0)
    frames = [
        (530, "inf", ghost),
        (630, "inf", _airy_spot(SHAPE, (80.2, 84.7), 14.0)),
        (450, "inf", rim),
        (500, "inf", gaussian_spot(*SHAPE, (80, 85), 2.0)),
    ]
    cube = import_psfs(read_manifest(write_bench(tmp_path, frames, rng)), ImportSettings(PITCH, pixels=41))
    spots = {f["file"]: f["other_spots"] for f in cube.frames}
    assert len(spots["frame00.png"]) == 1 and np.allclose(spots["frame00.png"][0]["at_px"], (80, 120), atol=0.5)
    assert spots["frame00.png"][0]["share"] == pytest.approx(0.23 / 0.77, rel=0.1)  # light above the detection level
    assert spots["frame01.png"] == spots["frame02.png"] == spots["frame03.png"] == []
    said = [w for w in cube.warnings if "separate spots" in w]
    assert len(said) == 1 and said[0].startswith(
        "psf.csv line 2: 2 separate spots of light (one at row 80, column 120 with "
    )
