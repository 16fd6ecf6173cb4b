"""The optimisation loop on a tiny camera (tests/design/tiny.toml): loss, resume, Ctrl-C, outputs."""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import numpy as np
import pytest
import torch

from metalens_cli.design.model import build_model
from metalens_cli.design.step import step_batch
from metalens_cli.design.train_loop import TrainingInterrupted
from metalens_cli.design.training import time_steps, train
from metalens_cli.design.validation import validation_loss
from metalens_cli.io.designs import resolve_design
from metalens_cli.io.presets import load_preset

TINY = Path(__file__).with_name("tiny.toml")


@pytest.fixture(scope="module")
def tiny():
    return load_preset(TINY)


def test_training_lowers_the_validation_loss(tiny, tmp_path):
    # 12 steps at lr 0.05 on fixed held-out draws: the loss must fall, by more than the
    # float32 noise of the PSFs (~1e-6)
    preset = dataclasses.replace(tiny, optimize=dataclasses.replace(tiny.optimize, steps=12, t_max=12))
    summary = train(preset, tmp_path / "run")
    before, after = summary.report["validation_loss"]["initial"], summary.report["validation_loss"]["final"]
    assert after < before - 1e-3
    assert len(summary.history) == 12 and all(np.isfinite(row["total"]) for row in summary.history)


def test_time_steps_reports_cost_and_writes_nothing(tiny, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    report = time_steps(tiny, steps=2)
    assert report["steps"] == 2 and report["parameters"] == build_model(tiny).theta.numel()
    assert 0 < report["seconds_per_step"] and 0 < report["first_step_s"]
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    assert 0 < report["cpu_seconds_per_step"] <= cores * report["seconds_per_step"] + 0.05  # the same step's
    assert {"psf", "scenes", "formation_loss", "backward", "update"} <= set(report["seconds_by_stage"])
    assert list(tmp_path.iterdir()) == []


def test_run_directory_contents(tiny, tmp_path):
    summary = train(tiny, tmp_path / "run", steps=3)
    run = tmp_path / "run"
    for name in (
        "preset.toml",
        "theta.npy",
        "theta_radial.csv",
        "theta.png",
        "psf.exr",
        "loss.csv",
        "loss.png",
        "steering.png",
        "run.json",
    ):
        assert (run / name).is_file(), name
    assert sorted(p.name for p in (run / "samples").iterdir()) == ["step_000003.png"]
    report = json.loads((run / "run.json").read_text())
    assert report["settings"]["steps"] == 3 and report["cost"]["seconds_per_step_median"] > 0
    assert len(report["psf"]["energy_center_5x5"]) == 2  # near and far
    assert report["efficiency"]["source"] == "table"  # which η the run used
    steering = report["validation_loss"]["steering"]  # what steers θ, at the start and the end
    for stage in ("initial", "final"):
        assert steering[stage]["draws"] == 8 and -1 <= steering[stage]["cosine_image_psf"] <= 1
        assert {"l1", "ssim", "bright", "sharp", "image", "psf"} <= set(steering[stage]["terms"])
    assert report["validation_loss"]["gradient_norms"]["final"]["sharp"] > 0
    theta = np.load(run / "theta.npy")
    np.testing.assert_array_equal(theta, summary.theta)
    # the run directory is a design spec carrying its lens and preset
    design = resolve_design(str(run))
    assert design.kind == "run" and design.preset.name == "tiny" and design.preset.optimize.steps == 3
    np.testing.assert_array_equal(design.lens.theta.numpy(), theta)


def test_resume_equals_uninterrupted_run(tiny, tmp_path):
    straight = train(tiny, tmp_path / "a", steps=6)
    train(tiny, tmp_path / "b", steps=3)
    resumed = train(tiny, tmp_path / "b", steps=6, resume=True)
    assert resumed.resumed_from == 3
    # identical draws (a function of seed and step) and restored optimiser state: bit-identical
    np.testing.assert_array_equal(resumed.theta, straight.theta)
    assert [r["total"] for r in resumed.history] == [r["total"] for r in straight.history]


def test_ctrl_c_writes_a_checkpoint_and_resume_continues(tiny, tmp_path):
    straight = train(tiny, tmp_path / "a", steps=5)

    def interrupt(done, total, row):
        if done == 2:
            raise KeyboardInterrupt

    with pytest.raises(TrainingInterrupted) as stop:
        train(tiny, tmp_path / "b", steps=5, on_step=interrupt)
    assert stop.value.step == 2 and stop.value.checkpoint.is_file()
    resumed = train(tiny, tmp_path / "b", steps=5, resume=True)
    np.testing.assert_array_equal(resumed.theta, straight.theta)


def test_fresh_run_refuses_an_existing_run(tiny, tmp_path):
    train(tiny, tmp_path / "run", steps=1)
    with pytest.raises(Exception, match="already holds a run"):
        train(tiny, tmp_path / "run", steps=1)


def test_validation_loss_is_deterministic(tiny):
    model = build_model(tiny)
    assert validation_loss(model, tiny, 2) == validation_loss(model, tiny, 2)


def test_theta_before_and_after_is_validated_on_the_same_scenes(tiny, monkeypatch):
    """A run's θ before and after training have different PSF windows, so alone each would draw
    its validation scenes on the canvas of its own margin, which are other scenes;
    ``validation_losses`` draws one batch on the larger canvas and crops it to each design's
    margin, so both are scored on the same scene (the sensor crops equal, bit for bit)."""
    from metalens_cli.design import validation

    start, defocused = build_model(tiny), build_model(tiny)
    with torch.no_grad():
        defocused.theta.mul_(0.8)  # a longer focal length: wider blur, larger windows
    seen = []

    def recording(capture, clean, *args, **kwargs):
        seen.append(clean.clone())
        return loss_of(capture, clean, *args, **kwargs)

    loss_of = validation.training_loss
    monkeypatch.setattr(validation, "training_loss", recording)
    validation.validation_loss(start, tiny, 1)
    validation.validation_loss(defocused, tiny, 1)
    assert not torch.equal(seen[0], seen[1])  # alone: two canvases, two scenes
    seen.clear()
    together = validation.validation_losses([(start, tiny), (defocused, tiny)], 1)
    assert torch.equal(seen[0], seen[1])
    assert together[0] != together[1] and all(np.isfinite(together))
    with pytest.raises(ValueError, match="same seed and the same scene settings"):
        other = dataclasses.replace(tiny, optimize=dataclasses.replace(tiny.optimize, seed=tiny.optimize.seed + 1))
        validation.validation_losses([(start, tiny), (start, other)], 1)


@pytest.mark.parametrize("cover, expected", [(0.0, 0.37), (1.0, 0.0)])
def test_validated_on_one_cropped_batch_a_grey_wall_stays_grey_and_a_cover_hides_it(tiny, monkeypatch, cover, expected):
    """Through ``validation_losses``' shared batch (drawn on the larger margin, cropped to each
    design's): a grey wall images as that grey and an opaque cover hides it, for both designs."""
    from metalens_cli.design import validation

    start, defocused = build_model(tiny), build_model(tiny)
    with torch.no_grad():
        defocused.theta.mul_(0.8)  # larger windows: the batch is cropped for the other design
    margins, captures = [], []

    def walls(preset, seed, step, indices, z_near_m, pool, margin, device):
        margins.append(margin)
        n = preset.sensor.pixels + 2 * margin
        grey = torch.full((len(indices), 3, n, n), 0.37)
        return grey, torch.zeros_like(grey), torch.full((len(indices), 1, n, n), cover)

    def recording(capture, clean, *args, **kwargs):
        captures.append(capture.detach())
        return loss_of(capture, clean, *args, **kwargs)

    loss_of = validation.training_loss
    monkeypatch.setattr(validation, "step_batch", walls)
    monkeypatch.setattr(validation, "training_loss", recording)
    validation.validation_losses([(start, tiny), (defocused, tiny)], 1)
    assert len(captures) == 2 and len(margins) == 1
    for capture in captures:
        assert capture.shape[-1] == tiny.sensor.pixels
        assert float((capture - expected).abs().max()) < 1e-5


@pytest.mark.parametrize("degrees", [0.0, 4.0])
def test_gradient_reaches_every_ring_inside_the_pupil(tiny, degrees):
    """On axis (radial Hankel path) and off axis (shifted angular spectrum over the whole grid)."""
    import math

    from metalens_cli.design.step import draw_step, plan_windows, spectral_source, step_psfs
    from metalens_cli.optics.window import crop_window

    model = build_model(tiny)
    sensitivity = spectral_source(tiny)
    draw = dataclasses.replace(draw_step(tiny, sensitivity, 0, 0), field_angle_rad=math.radians(degrees))
    near, far = step_psfs(model.lens(), tiny, draw, plan_windows(tiny, sensitivity), "cpu")[0].psfs
    (crop_window(near, 15).sum() + crop_window(far, 5).sum()).backward()
    grad = model.theta.grad
    inside = np.arange(grad.numel()) * tiny.nanofin.pitch_m < tiny.lens.aperture_m / 2
    assert torch.all(torch.isfinite(grad))
    assert (grad[torch.from_numpy(inside)] != 0).float().mean() > 0.99


def test_step_windows_follow_the_light_when_theta_is_perturbed(tiny):
    """A rippled θ (the roughness per-sample Adam steps make) scatters light: the step's windows
    grow with it, and planned windows too small for the light grow until every channel keeps
    99.9 % of its light on the sensor plane."""
    from metalens_cli.design.step import Windows, draw_step, plan_windows, step_psfs
    from metalens_cli.io.preset_spectra import preset_sensitivity
    from metalens_cli.optics.channel_psf import ENCIRCLED_ENERGY

    sensitivity = preset_sensitivity(tiny)
    draw = draw_step(tiny, sensitivity, 0, 0)
    model = build_model(tiny)
    planned = plan_windows(tiny, sensitivity)
    smooth, _ = step_psfs(model.lens(), tiny, draw, planned, "cpu")
    with torch.no_grad():
        k = torch.arange(model.theta.numel(), dtype=torch.float64)
        model.theta += 0.3 * torch.sin(2 * np.pi * k / 6)  # ±0.3 rad over 6 rings: ±0.16 rad/µm of slope
    rough, grown = step_psfs(model.lens(), tiny, draw, planned, "cpu")
    assert all(max(r) > max(s) for r, s in zip(rough.windows, smooth.windows))
    assert grown.plan >= planned.plan and not rough.outgrown.any()
    assert np.all(rough.held >= ENCIRCLED_ENERGY - 2e-4)  # pixel integral against the disc rule
    small, regrown = step_psfs(build_model(tiny).lens(), tiny, draw, Windows(9, 9, 9), "cpu")
    assert regrown.plan > 9 and not small.outgrown.any()
    assert small.windows == smooth.windows  # the light decides, not the plan
    # the next step looks within its light × the headroom: capacities come down with the light, the plan stays
    calm, after = step_psfs(build_model(tiny).lens(), tiny, draw, grown, "cpu")
    assert calm.windows == smooth.windows
    assert max(after.near, after.far) < max(grown.near, grown.far) and after.plan == grown.plan
    assert after.near >= max(calm.windows[0]) and after.far >= max(calm.windows[1])


def test_the_radial_margin_key_reaches_the_steps_propagator(tiny):
    """``[optimize] radial_margin`` 0.1 plans the step's Hankel transform for half the doubled
    margin of every other radial PSF (fewer samples, a shorter support radius; its error budget is
    tested in tests/optics/test_channel_psf.py); 0.1 is the default's plan itself."""
    from metalens_cli.design.step import draw_step, plan_windows, step_psfs
    from metalens_cli.io.preset_spectra import preset_sensitivity

    sensitivity = preset_sensitivity(tiny)
    draw, lens = draw_step(tiny, sensitivity, 0, 0), build_model(tiny).lens()
    windows = plan_windows(tiny, sensitivity)
    with torch.no_grad():
        stacks = {
            m: step_psfs(lens, dataclasses.replace(tiny, optimize=dataclasses.replace(tiny.optimize, radial_margin=m)),
                         draw, windows, "cpu")[0]
            for m in (0.1, 0.2)
        }  # fmt: skip
        default = step_psfs(lens, tiny, draw, windows, "cpu")[0]
    assert stacks[0.1].grid == default.grid
    narrow, wide = stacks[0.1].grid, stacks[0.2].grid
    assert narrow["hankel_samples"] < wide["hankel_samples"]
    assert narrow["support_radius_m"] < wide["support_radius_m"]


def test_through_a_narrower_margins_psfs_a_grey_wall_stays_grey_and_a_cover_hides_it(tiny):
    """The step's PSFs with ``radial_margin`` 0.1 (the default): a grey wall images as that grey, an
    opaque cover hides the scene, and no channel gains light: each keeps at most what it keeps with
    the doubled margin 0.2, and never more than reaches the sensor plane (the edge diffraction it
    drops is lost)."""
    from metalens_cli.design.step import draw_step, plan_windows, step_psfs
    from metalens_cli.imaging.formation import form_image, psf_margin
    from metalens_cli.io.preset_spectra import preset_sensitivity

    sensitivity = preset_sensitivity(tiny)
    draw, lens = draw_step(tiny, sensitivity, 0, 0), build_model(tiny).lens()
    windows = plan_windows(tiny, sensitivity)
    assert tiny.optimize.radial_margin == 0.1
    wide_preset = dataclasses.replace(tiny, optimize=dataclasses.replace(tiny.optimize, radial_margin=0.2))
    with torch.no_grad():
        narrow, _ = step_psfs(lens, tiny, draw, windows, "cpu")
        wide, _ = step_psfs(lens, wide_preset, draw, windows, "cpu")
    near, far = narrow.psfs
    m, n = psf_margin(near, far), tiny.sensor.pixels
    grey = torch.full((1, 3, n + 2 * m, n + 2 * m), 0.37)
    clear, opaque = torch.zeros(1, 1, *grey.shape[-2:]), torch.ones(1, 1, *grey.shape[-2:])
    wall = form_image(grey, torch.zeros_like(grey), clear, near, far, m).obstructed
    assert float((wall - 0.37).abs().max()) < 1e-5
    cover = form_image(grey, torch.zeros_like(grey), opaque, near, far, m).obstructed
    assert float(cover.abs().max()) < 1e-6
    assert np.all(narrow.kept <= wide.kept + 1e-6) and np.all(narrow.kept <= narrow.on_sensor + 1e-6)
    assert np.all(narrow.on_sensor <= 1 + 1e-6)


def test_gradient_norms_of_each_term(tiny):
    """Every weighted term has a finite, positive gradient norm, and a term weighted 0 has none."""
    from metalens_cli.design.validation import term_gradient_norms

    norms = term_gradient_norms(build_model(tiny), tiny, draws=1)
    assert {"l1", "ssim", "bright", "sharp"} <= set(norms) and all(np.isfinite(v) and v > 0 for v in norms.values())
    silent = dataclasses.replace(tiny, loss=dataclasses.replace(tiny.loss, sharp=0.0))
    assert term_gradient_norms(build_model(silent), silent, draws=1)["sharp"] == 0.0


@pytest.mark.parametrize("mode", ["log_wavelength", "harmonic_wavelength"])
def test_per_wavelength_sharpness_steers_the_lens(tiny, tmp_path, mode):
    """sharp_mode on each wavelength's own core: the loss sees each wavelength's core (a finite,
    positive gradient through it), and an even window, which has no centre pixel, is refused."""
    from metalens_cli.design.validation import term_gradient_norms
    from metalens_cli.errors import InputError
    from metalens_cli.io.presets import to_toml

    spectral = dataclasses.replace(tiny, loss=dataclasses.replace(tiny.loss, sharp_mode=mode))
    norms = term_gradient_norms(build_model(spectral), spectral, draws=1)
    assert np.isfinite(norms["sharp"]) and norms["sharp"] > 0
    assert norms["sharp"] != term_gradient_norms(build_model(tiny), tiny, draws=1)["sharp"]
    even = tmp_path / "even.toml"
    even.write_text(to_toml(spectral, loss={"sharp_window": 4}))
    with pytest.raises(InputError, match="loss.sharp_window"):
        load_preset(even)


def test_gradient_norm_ratio_at_theta_init_is_the_documented_one():
    """docs/training.md: at θ_init of the quick split-spectrum preset (spline θ, −log E) the PSF
    terms' gradient is 10²-10³ times the image terms' (per-channel 1/E: 10⁵-10⁶). A change of
    loss form, weights or basis that moves it out of that range must update the document."""
    import math

    from metalens_cli.design.model import plan_frequency
    from metalens_cli.design.validation import term_gradient_norms

    preset = load_preset(Path(__file__).parents[2] / "presets" / "quick-split-spectrum.toml")
    norms = term_gradient_norms(build_model(preset), preset, draws=1, frequency=plan_frequency(preset))
    ratio = math.hypot(norms["sharp"], norms["bright"]) / math.hypot(norms["l1"], norms["ssim"])
    assert 1e2 <= ratio <= 1e3


def test_the_time_estimate_counts_what_follows_the_steps(tiny, tmp_path):
    """A one-step run is mostly its end (validation and gradient norms at θ_init and θ_final,
    the results): its estimate stays within the 10× that docs/failures.md calls a bug (it was 35×
    short before FINISH_STEPS)."""
    import time

    from metalens_cli.design.training import estimate_training

    one = dataclasses.replace(tiny, optimize=dataclasses.replace(tiny.optimize, steps=1))
    start = time.perf_counter()
    train(one, tmp_path / "run", steps=1)
    measured = time.perf_counter() - start
    estimated = estimate_training(one)[1]
    assert measured / 10 < estimated < 10 * measured, (estimated, measured)


def test_a_batch_is_the_same_on_any_number_of_threads(tiny):
    """Scenes and obstructions are separate tasks (rain inside its scene's task): one thread or
    two, the same batch, element for element."""
    preset = dataclasses.replace(
        tiny, optimize=dataclasses.replace(tiny.optimize, obstructions=("rain", "dirt", "fence"))
    )
    threads = torch.get_num_threads()
    try:
        batches = []
        for n in (1, 2):
            torch.set_num_threads(n)
            batches.append(step_batch(preset, 0, 3, [0, 1, 2, 3], 0.045, None, 12, "cpu"))
    finally:
        torch.set_num_threads(threads)
    assert all(torch.equal(a, b) for a, b in zip(*batches))


def test_a_lens_that_outgrows_the_propagator_ends_the_run_with_its_step(tiny, monkeypatch):
    """When the learned θ scatters light past what the radial propagator can sample (here its
    limit is lowered under the plan after setup), the run stops with the step and what to change
    (the learning rate, a smooth θ), not with advice about the aperture that passed at the start."""
    from metalens_cli.design import distributed
    from metalens_cli.design.step import one_step
    from metalens_cli.design.training import _session
    from metalens_cli.errors import InputError
    from metalens_cli.optics import sampling
    from metalens_cli.runtime import Stopwatch

    with distributed.session(torch.device("cpu")) as ctx:
        session = _session(tiny, ctx)
        monkeypatch.setattr(sampling, "MAX_HANKEL_SIZE", 8)
        with pytest.raises(InputError, match="at step 5 the learned lens scatters light") as caught:
            one_step(session, tiny, 4, ctx, Stopwatch())
    assert caught.value.field == "optimize.learning_rate" and "theta_basis" in caught.value.expected


def _over_field(preset, *degrees):
    import math

    angles = tuple(math.radians(a) for a in degrees)
    return dataclasses.replace(preset, optimize=dataclasses.replace(preset.optimize, field_angles_rad=angles))


def test_field_angles_are_drawn_beside_the_on_axis_draws(tiny):
    """A run over the field draws one of its angles per step, equally likely, from a stream of
    its own: depths and wavelengths are those of the same run on axis. A radial lens keeps
    azimuth 0; a 2-D one draws it, uniform, for the steps off axis."""
    import math

    from metalens_cli.design.step import draw_step, spectral_source

    field = _over_field(tiny, 0, 3, 5)
    angles = []
    for step in range(60):
        axis, off = draw_step(tiny, spectral_source(tiny), 0, step), draw_step(field, spectral_source(field), 0, step)
        assert (off.z_near_m, off.z_far_m) == (axis.z_near_m, axis.z_far_m) and axis.field_angle_rad == 0
        np.testing.assert_array_equal(off.wavelengths_m, axis.wavelengths_m)
        assert off.azimuth_rad == 0
        angles.append(round(math.degrees(off.field_angle_rad), 9))
    counts = [angles.count(a) for a in (0, 3, 5)]
    assert sum(counts) == 60 and min(counts) >= 10  # each about 20 of 60
    grid = _over_field(dataclasses.replace(tiny, lens=dataclasses.replace(tiny.lens, parameterization="2d")), 0, 5)
    draws = [draw_step(grid, spectral_source(grid), 0, step) for step in range(40)]
    azimuths = [d.azimuth_rad for d in draws if d.field_angle_rad > 0]
    assert all(d.azimuth_rad == 0 for d in draws if d.field_angle_rad == 0)
    assert len(set(azimuths)) == len(azimuths) > 5 and all(0 <= a < 2 * math.pi for a in azimuths)


def test_an_off_axis_step_close_to_the_axis_is_the_on_axis_step(tiny):
    """10⁻⁶° off axis (the chief ray 17 pm from the axis) the step's PSFs come from the 2-D shifted
    angular spectrum over the whole meta-atom grid, its windows from concentric squares; on axis
    from the radial Hankel path and the disc rule. The two independent paths agree: per-wavelength
    core energies (what L_sharp sees) within 5e-4 relative, the centre of each channel PSF within
    1e-3 (relative L2; 2.5e-4 and 9e-5 measured at 530 nm, near and far). Measured once against
    the direct Rayleigh-Sommerfeld sum (522 nm, 11.5 mm, 5 × 5 core): the shifted angular spectrum
    3e-5 from it, the radial path 4.3e-4 (at the far depth both within 1.5e-5). At 10⁻³° the
    17-nm shift alone moves the tiny lens's sharp core by ~1 %."""
    import math

    from metalens_cli.design.step import draw_step, plan_windows, spectral_source, step_psfs
    from metalens_cli.optics.window import crop_window

    preset = dataclasses.replace(tiny, loss=dataclasses.replace(tiny.loss, sharp_mode="log_wavelength"))
    sensitivity = spectral_source(preset)
    draw = draw_step(preset, sensitivity, 0, 0)
    windows = plan_windows(preset, sensitivity)
    lens = build_model(preset).lens()
    axis, _ = step_psfs(lens, preset, draw, windows, "cpu")
    off = dataclasses.replace(draw, field_angle_rad=math.radians(1e-6))
    near_axis, kept = step_psfs(lens, preset, off, windows, "cpu")
    assert kept == windows  # off-axis steps leave the run's windows to the on-axis light
    assert near_axis.grid["kind"] == "asm-shifted" and axis.grid["kind"] == "radial"
    for a, b in zip(axis.cores, near_axis.cores):
        np.testing.assert_allclose(b.detach().numpy(), a.detach().numpy(), rtol=5e-4)
    for a, b in zip(axis.psfs, near_axis.psfs):
        a, b = crop_window(a.detach(), 31).double(), crop_window(b.detach(), 31).double()
        assert float(torch.linalg.vector_norm(b - a) / torch.linalg.vector_norm(a)) < 1e-3
    assert np.all(near_axis.kept <= near_axis.on_sensor + 1e-9)
    assert np.all(near_axis.kept >= 0.999 * near_axis.on_sensor)


def test_a_run_over_the_field_logs_its_field_points_and_resumes_exactly(tiny, tmp_path, monkeypatch):
    """loss.csv gains the field point of each step (the draw's); θ moves on off-axis steps; and
    a resumed run repeats an uninterrupted one bit for bit. The run skips its steering diagnostic
    as a 2-D θ too large for it does (off-axis draws cost seconds each; it is tested on axis), and
    its run.json says so."""
    import csv
    import math

    from metalens_cli.design import validation
    from metalens_cli.design.step import draw_field

    monkeypatch.setattr(validation, "MAX_STEERING_PARAMETERS", 0)
    field = _over_field(tiny, 0, 4)
    straight = train(field, tmp_path / "a", steps=4)
    train(field, tmp_path / "b", steps=2)
    resumed = train(field, tmp_path / "b", steps=4, resume=True)
    np.testing.assert_array_equal(resumed.theta, straight.theta)
    assert [r["total"] for r in resumed.history] == [r["total"] for r in straight.history]
    with open(tmp_path / "a" / "loss.csv") as f:
        rows = list(csv.DictReader(f))
    logged = [float(r["field_angle_deg"]) for r in rows]
    assert logged == pytest.approx([math.degrees(draw_field(field, 0, s)[0]) for s in range(4)])
    assert any(a > 0 for a in logged)
    steer = json.loads((tmp_path / "a" / "run.json").read_text())["validation_loss"]["steering"]
    assert all("skipped" in steer[k] for k in ("initial", "final"))
