"""End-to-end learning of the rotation map θ (the paper's Eq. 4, Suppl. Note 4): the session.

Each step (``design.step``) draws everything it needs from (seed, s) alone, so that a resumed
run repeats an uninterrupted one exactly and every data-parallel rank agrees on the shared draws:

1. z_near, z_far uniform in the preset's scene intervals; with ``[optimize] field_angles``, a
   field angle among them, equally likely (a 2-D lens also an azimuth, uniform);
2. per channel, ``wavelengths_per_channel`` wavelengths by stratified importance sampling of S^c
   (with ``spectral_sampling = "bands"``: per filter band, and weights differentiable in a
   filter learned with θ, ``design.filter_learning``);
3. monochromatic PSFs at both depths in one differentiable ``compute_psf`` call, mixed into
   R, G, B (one sampling plan for the whole run, so kernels are built once); off axis by
   ``optics.field.field_psf`` in a window centred on the chief ray (``optics.channel_psf.
   field_channel_stack``), the step's scenes then being what the sensor sees around that field
   point, blurred by its PSF (isoplanatic over the sensor crop);
4. a batch of clean scenes with generated obstructions at z_near (drawn ahead on a background
   thread on the canvas of the step's starting capacities, ``design.scene_pool``), rendered by
   the image formation of ``imaging.formation``;
5. loss (``design.losses``), backward, gradient sum over ranks, AdamW and the LR schedule.

This module holds the session around the steps (``train``, ``time_steps``) and the cost estimate
of a run (``estimate_training``); the fixed validation draws measured at its start and end (the
loss, and what steers θ) are ``design.validation``'s. The core never prints: progress goes to the
``on_step`` callback. The loop around the steps (resume, checkpoints, Ctrl-C: a checkpoint of the
last completed step, then ``TrainingInterrupted``) is ``design.train_loop``'s.
"""

from __future__ import annotations

import dataclasses
import math
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from metalens_cli import arguments
from metalens_cli.design import distributed
from metalens_cli.design.filter_learning import LearnedFilter, filter_columns, learned_filter, make_feasible
from metalens_cli.design.model import PLAN_HEADROOM, build_model, plan_frequency, plan_range
from metalens_cli.design.report import write_results
from metalens_cli.design.rundir import START_THETA, RunDirectory, run_preset_toml
from metalens_cli.design.scene_pool import draws_ahead
from metalens_cli.design.step import (
    Session,
    Windows,
    field_capacities,
    field_training,
    image_pool,
    one_step,
    plan_windows,
    psf_scales,
    scene_pool,
    spectral_source,
)
from metalens_cli.design.train_loop import TrainLoop, checkpoint_to_resume, overrides
from metalens_cli.design.training_camera import training_camera
from metalens_cli.design.validation import STEERING_DRAWS, norms_of, steering, validation_losses
from metalens_cli.io.preset_spectra import preset_sensitivity
from metalens_cli.io.presets import Preset, preset_incidence_factor
from metalens_cli.optics.channel_psf import ENCIRCLED_ENERGY
from metalens_cli.optics.field import ON_AXIS_MARGIN, estimate_field_psf
from metalens_cli.optics.psf import PsfCost
from metalens_cli.optics.sampling import PsfGrid
from metalens_cli.runtime import Stopwatch

FINISH_STEPS = 60  # the end of a run in estimated steps: validation loss (2 × 4 draws) and what steers θ (2 × 8
# draws, each term's gradient: design.validation) at θ_init and θ_final, the results' PSF scan: tests' tiny 30 measured
THETA_GRID_COPIES = 12  # float32 copies of a 2-D θ grid in a step: θ, its gradient, Adam's moments, phase, field
LARGE_GRID_BYTES = 1 << 30  # a 2-D θ grid above this is estimated (and refused) before it is built
FIELD_COLUMNS = ("field_angle_deg", "field_azimuth_deg")  # loss.csv columns of a run with field angles
# an off-axis step's PSF seconds over their forward pass: its backward is one adjoint propagation per PSF
# (7.7 s forward, 7.4 s backward measured on examples/scaled-split-spectrum.toml at 6.75°, 2 cores)
FIELD_BACKWARD = 2.0


@dataclass
class RunSummary:
    """What ``train`` returns (rank 0 also wrote it into ``run.json``)."""

    run_dir: Path
    steps: int
    resumed_from: int
    history: list[dict]
    seconds_per_step: float | None
    theta: np.ndarray
    report: dict = field(default_factory=dict)


def _scheduler(optimizer, o):
    if o.scheduler == "cosine":
        return torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=o.t_max)
    return torch.optim.lr_scheduler.LambdaLR(optimizer, lambda _: 1.0)


def estimate_training(preset) -> tuple[int, float | None]:
    """(peak bytes, seconds) of a run of ``preset``: one step's PSFs (``optics.psf.estimate_psf``
    at the plan's wavelength range, kept for the backward pass: ×2) and its batch of captures on
    the canvas (about 20 float32 planes of 3 channels per image, forward and backward); time from
    the PSF plan (×3 with its backward pass) and the canvas FFTs, times the steps plus
    ``FINISH_STEPS`` for what follows them. With field angles, the off-axis steps' PSFs at the
    largest angle (``optics.field.estimate_field_psf`` with its backward pass, × ``FIELD_BACKWARD``
    in time), in the share of steps drawn off axis.
    A 2-D θ grid over 1 GiB is estimated alone, without building anything (time None)."""
    from metalens_cli.optics.psf import FFT_RATE, estimate_psf

    o = preset.optimize
    if preset.lens.parameterization == "2d":  # before building it: the θ grid alone can exceed the machine
        side = o.design_grid or math.ceil(preset.lens.aperture_m / preset.nanofin.pitch_m) + 1
        grid_bytes = THETA_GRID_COPIES * 4 * side**2
        if grid_bytes > LARGE_GRID_BYTES:
            return grid_bytes, None
    windows = plan_windows(preset, preset_sensitivity(preset))
    lo, hi = plan_range(preset)[0]
    waves = list(np.linspace(lo, hi, 3 * o.wavelengths_per_channel))
    zs = [preset.scene.z_near_m[0], preset.scene.z_far_m[0]]
    grid = PsfGrid(waves, zs, max(windows.near, windows.far), preset.sensor.pixel_pitch_m, preset.lens.focal_length_m)
    psf = estimate_psf(build_model(preset).lens(), grid)
    scales = psf_scales(preset)
    canvas = preset.sensor.pixels + 2 * windows.margin(scales)
    # the FFT grids of a capture: one canvas, or the core's and the halo's blocks (imaging.formation)
    grids = [canvas] if scales.single else [preset.sensor.pixels + scales.core_pixels, canvas / scales.scale]
    captures = o.batch_size * 20 * 3 * canvas**2 * 4
    psf_seconds, psf_bytes = 3 * (psf.seconds - psf.setup_seconds), 2 * psf.memory_bytes  # with the backward pass
    if field_training(preset):
        off = sum(a > 0 for a in o.field_angles_rad) / len(o.field_angles_rad)
        field = estimate_field_psf_step(preset, windows, waves)
        psf_seconds = (1 - off) * psf_seconds + off * FIELD_BACKWARD * field.seconds
        psf_bytes = max(psf_bytes, field.memory_bytes)
    ffts = sum(n**2 * max(math.log2(n), 1) for n in grids)
    per_step = psf_seconds + o.batch_size * 8 * 3 * ffts / FFT_RATE
    return psf_bytes + captures, psf.setup_seconds + (o.steps + FINISH_STEPS) * per_step


def estimate_field_psf_step(preset, windows: Windows, wavelengths_m) -> PsfCost:
    """An off-axis step's PSFs at the largest field angle (``optics.field.estimate_field_psf``
    with its backward pass): seconds of the forward pass, bytes with what the backward keeps."""
    angle, lens = max(preset.optimize.field_angles_rad), build_model(preset).lens()
    zs = [preset.scene.z_near_m[0], preset.scene.z_far_m[0]]
    window = max(field_capacities(lens, preset, wavelengths_m, zs, angle, windows))
    grid = PsfGrid(wavelengths_m, zs, window, preset.sensor.pixel_pitch_m, preset.lens.focal_length_m)
    return estimate_field_psf(lens, grid, angle, oversample=ON_AXIS_MARGIN, backward=True)


def _features(preset, notes: list[str]):
    if preset.loss.domain_adaptation <= 0:
        return None
    from metalens_cli.design.features import find_deeplab_weights, load_feature_extractor

    path, note = find_deeplab_weights(preset.loss.domain_adaptation_weights)
    if path is None:
        notes.append(note)
        return None
    return load_feature_extractor(path)


def train(
    preset,
    run_dir: str | Path,
    *,
    steps: int | None = None,
    seed: int | None = None,
    device: str | torch.device = "cpu",
    resume: bool = False,
    on_step: Callable[[int, int, dict], None] | None = None,
) -> RunSummary:
    """Learn θ for ``preset`` into ``run_dir`` (see ``design.rundir`` for its files).

    ``steps``/``seed`` override the preset's; ``resume`` continues from the newest checkpoint in
    ``run_dir`` with the preset saved there (``steps`` may extend it). Under torchrun the run is
    data-parallel and only rank 0 writes.

    Args:
        preset: the :class:`Preset` (:func:`load_preset`).
        run_dir: the run directory to write (θ, checkpoints, loss.csv, run.json).
        steps: override the preset's step count (with ``resume``: may extend the run).
        seed: override the preset's seed.
        device: torch device.
        resume: continue from the newest checkpoint in ``run_dir`` with the preset saved there.
        on_step: ``on_step(done, total, row)`` reports each step.

    Returns:
        ``RunSummary`` (rank 0 also wrote it into ``run.json``): the run directory, steps,
        the step resumed from, the loss history, seconds per step, the learned θ (rad) and the report.
    """
    arguments.instance(preset, "preset", Preset, "a Preset (ml.load_preset)")
    run_dir = arguments.path(run_dir, "run_dir", "a run directory")
    for name, value in (("steps", steps), ("seed", seed)):
        if value is not None:
            arguments.count(value, name, lo=0)
    device = arguments.device(device)
    with distributed.session(device) as ctx:
        return _train(preset, RunDirectory(run_dir), steps, seed, ctx, resume, on_step)


def _session(preset, ctx, prefetch: bool = False, end: int | None = None) -> Session:
    """The session of a run of ``preset`` on ``ctx``; its scenes drawn ahead on a background
    thread with ``prefetch`` (then close ``session.scenes``), for steps below ``end`` (the
    preset's steps)."""
    o = preset.optimize
    model = build_model(preset).to(ctx.device)
    notes: list[str] = []
    incidence = preset_incidence_factor(preset)
    band_filter = _filter_start(preset, incidence, notes)
    groups = [{"params": list(model.parameters())}]
    if band_filter is not None:
        groups.append(
            {"params": list(band_filter.parameters()), "lr": preset.filter.learning_rate, "weight_decay": 0.0}
        )
    optimizer = torch.optim.AdamW(groups, lr=o.learning_rate, weight_decay=o.weight_decay)
    sensitivity = spectral_source(preset, band_filter)
    windows = plan_windows(preset, sensitivity)
    images, shard = image_pool(preset, windows.margin(psf_scales(preset))), ctx.shard(o.batch_size)
    return Session(
        model,
        optimizer,
        _scheduler(optimizer, o),
        sensitivity,
        _features(preset, notes),
        images,
        shard,
        plan_frequency(preset),
        windows,
        notes,
        scene_pool(preset, images, shard, ctx.device, o.steps if end is None else end, prefetch),
        band_filter=band_filter,
        incidence=incidence,
        camera=training_camera(preset),
    )


def _filter_start(preset, incidence: float, notes: list[str]) -> LearnedFilter | None:
    """The filter to learn (``[filter] learn = true``), within its limits and, while the
    conditions' penalty is on, meeting them (``design.filter_learning.make_feasible``)."""
    if preset.filter is None or not preset.filter.learn:
        return None
    band_filter = LearnedFilter(preset.filter)
    band_filter.project(preset.filter, preset.sensor.wavelength_range_m)
    if preset.filter.split_weight > 0:
        start = make_feasible(band_filter, preset, incidence)
        if start["steps"]:
            notes.append(
                f"the starting filter failed the split-spectrum conditions (penalty {start['penalty_before_nm2']:.3g} "
                f"nm²): moved to {_bands_text(band_filter)} in {start['steps']} penalty-only steps (penalty "
                f"{start['penalty_after_nm2']:.3g} nm²) before θ learned"
            )
    return band_filter


def time_steps(preset, steps: int = 3, device: str | torch.device = "cpu", prefetch: bool | None = None) -> dict:
    """Run ``steps`` training steps of ``preset`` without a run directory and report their cost:
    seconds per step (median over the steps after the first, which builds the kernels), seconds by
    stage (totals over the steps), the first step's seconds, the process's CPU seconds per step
    (median over the same steps, every thread: on a CPU, the step can take no less than this over
    the cores it has), the number of θ parameters, the last step's PSF windows and, on CUDA, the
    peak memory (bytes). ``prefetch``: each step's scenes drawn ahead (``design.scene_pool``);
    without it, in the step; None: as a run would (``draws_ahead``)."""
    with distributed.session(torch.device(device)) as ctx:
        session = _session(preset, ctx, draws_ahead(ctx.device) if prefetch is None else prefetch, steps)
        if ctx.device.type == "cuda":
            torch.cuda.reset_peak_memory_stats(ctx.device)
        watch = Stopwatch(ctx.device)
        seconds, cpu_seconds = [], []
        row: dict = {}
        with session.scenes:
            for step in range(steps):
                t0, c0 = time.perf_counter(), time.process_time()
                row = one_step(session, preset, step, ctx, watch)[0]
                if ctx.device.type == "cuda":
                    torch.cuda.synchronize(ctx.device)
                seconds.append(time.perf_counter() - t0)
                cpu_seconds.append(time.process_time() - c0)
        report = {
            "steps": steps,
            "first_step_s": seconds[0],
            "seconds_per_step": statistics.median(seconds[1:] or seconds),
            "cpu_seconds_per_step": statistics.median(cpu_seconds[1:] or cpu_seconds),
            "seconds_by_stage": watch.times,
            "parameters": sum(p.numel() for p in session.model.parameters()),
            "windows_px": {"near": row.get("window_near"), "far": row.get("window_far")},
            "device": str(ctx.device),
            "threads": torch.get_num_threads(),
        }
        if ctx.device.type == "cuda":
            report["peak_memory_bytes"] = torch.cuda.max_memory_allocated(ctx.device)
        return report


def _train(preset, run: RunDirectory, steps, seed, ctx, resume, on_step) -> RunSummary:
    """The run (``design.train_loop``); on --resume the checkpoint is checked
    (``RunDirectory.latest_checkpoint``, ``Checkpoint.restore``) before preset.toml is rewritten."""
    if resume:
        run.check_resumable()
        preset = run.load_preset()
    given = overrides(steps, seed)
    preset = dataclasses.replace(preset, optimize=dataclasses.replace(preset.optimize, **given))
    o = preset.optimize
    if preset.filter is not None and preset.filter.learn:
        run.columns = run.columns + filter_columns(len(preset.filter.centers_m))
    if field_training(preset):
        run.columns = run.columns + FIELD_COLUMNS
    checkpoint = checkpoint_to_resume(run, resume, o.steps)
    session = _session(preset, ctx, prefetch=draws_ahead(ctx.device))
    if ctx.is_main and not resume:
        start = {} if o.init_from is None else {START_THETA: Path(o.init_from)}
        run.create(run_preset_toml(preset), copies=start)
    model = session.model
    loop = TrainLoop(
        run,
        ctx,
        o.steps,
        o.checkpoint_every,
        _modules(session),
        lambda: _windows_state(session),
        lambda state: _load_windows(session, state),
    )
    loop.resume(checkpoint, run_preset_toml(preset) if resume and given else None)
    watch = Stopwatch(ctx.device)
    grid: dict = {}
    sample = None

    def run_step(step: int) -> dict:
        nonlocal grid, sample
        row, grid, sample = one_step(session, preset, step, ctx, watch)
        return row

    def after_step(done: int) -> None:
        if done % o.sample_every == 0:
            _write_sample(run, sample, done - 1)

    with session.scenes:  # the worker stops with the steps, whether they finish or not
        loop.train(run_step, on_step, after_step)
    history, start = loop.history, loop.start
    theta = model.full_theta().detach().cpu().numpy()
    summary = RunSummary(run.path, o.steps, start, history, _seconds_per_step(history[start:]), theta)
    if ctx.is_main:
        learned, filter_report = preset, None
        if session.band_filter is not None:  # checked (and snapped) before anything is written with it
            learned, filter_report = learned_filter(run, preset, session.band_filter)
        start_model = build_model(preset).to(ctx.device)
        steer = {
            "initial": steering(start_model, preset, STEERING_DRAWS, ctx.device, session.frequency, session.features),
            "final": steering(model, learned, STEERING_DRAWS, ctx.device, session.frequency, session.features),
        }
        initial, final = validation_losses([(start_model, preset), (model, learned)], 4, ctx.device, session.frequency)
        validation = {
            "draws": 4,
            "initial": initial,  # both on the same scenes (design.validation.validation_losses)
            "final": final,
            "gradient_norms": {k: norms_of(v) for k, v in steer.items()},
            "steering": steer,
        }
        summary.report = _finish(
            run,
            learned,
            model,
            summary,
            grid,
            watch.times,
            session.notes,
            ctx,
            validation,
            session.windows,
            filter_report,
        )
    return summary


def _bands_text(band_filter: LearnedFilter) -> str:
    centres, widths, _ = band_filter.values()
    return ", ".join(f"{(c - w / 2) * 1e9:.1f}-{(c + w / 2) * 1e9:.1f} nm" for c, w in zip(centres, widths))


def _modules(session: Session) -> dict:
    """What a checkpoint holds the state dicts of: θ, the learned filter, optimiser and schedule."""
    learned = {"filter": session.band_filter} if session.band_filter is not None else {}
    return {"model": session.model, **learned, "optimizer": session.optimizer, "scheduler": session.scheduler}


def _windows_state(session: Session) -> dict:
    """The windows the run has come to (px), kept in its checkpoints."""
    return {"windows": [session.windows.near, session.windows.far, session.windows.plan]}


def _load_windows(session: Session, state: dict) -> None:
    """The windows a checkpoint's ``state`` kept (older runs: the capacities alone; older still: none)."""
    if "windows" in state:
        near, far, *plan = state["windows"]
        session.windows = Windows(near, far, plan[0] if plan else max(near, far))


def _seconds_per_step(rows: list[dict]) -> float | None:
    return statistics.median(r["seconds"] for r in rows) if rows else None


def _write_sample(run: RunDirectory, sample: torch.Tensor, step: int) -> None:
    """clean | obstruction over grey | capture of the step's first scene, sRGB PNG."""
    from metalens_cli.io.image_files import linear_to_srgb, write_png

    (run.path / "samples").mkdir(exist_ok=True)  # a resumed run killed while its folder was being made
    write_png(run.path / "samples" / f"step_{step + 1:06d}.png", linear_to_srgb(np.clip(sample.cpu().numpy(), 0, 1)))


def _finish(
    run: RunDirectory,
    preset,
    model,
    summary: RunSummary,
    grid: dict,
    timing: dict,
    notes: list[str],
    ctx,
    validation: dict,
    windows: Windows,
    filter_report: dict | None,
) -> dict:
    """theta, psf.exr, loss.csv/png, theta.png, filter.png and run.json."""
    return write_results(
        run,
        preset,
        summary,
        grid,
        timing,
        notes,
        ctx.world,
        str(ctx.device),
        torch.get_num_threads(),
        validation,
        {
            "planned_px": {"near": windows.near, "far": windows.far, "plan": windows.plan},
            "headroom": PLAN_HEADROOM,
            "rule": f"each step: the window holding {ENCIRCLED_ENERGY} of each channel's power on the sensor plane",
        },
        filter_report,
    )
