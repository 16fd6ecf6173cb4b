"""One training step of ``metalens optimize``: its draws, its PSF windows, its batch, the step itself.

A step s draws everything from (seed, s) alone (``draw_step``, ``draw_field``, ``step_batch``), so
that a resumed run repeats an uninterrupted one and every data-parallel rank agrees on the shared
draws; its PSFs are computed in the windows their light needs (``Windows``, ``step_psfs``), each
as core and halo (``psf_scales``); its batch is drawn ahead where a core is free, while the step
before it runs, on the canvas of the capacities it starts from and cropped to the margin its PSFs
need, else in the step on that margin (``scene_pool``, ``step_canvases``); the step
(``one_step``) forms the batch's captures, takes the loss and updates θ, reading on the host only
what ``HOST_READS`` lists. The session that carries the model and optimiser from step to step is
built in ``design.training``.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import torch

from metalens_cli.design.device_scenes import device_batch
from metalens_cli.design.filter_learning import BandSampler, LearnedFilter, band_sampler, filter_row, split_penalty
from metalens_cli.design.losses import training_loss, weighted_total
from metalens_cli.design.model import PLAN_HEADROOM, build_model, plan_range
from metalens_cli.design.scene_pool import ScenePool
from metalens_cli.design.scenes import FINE_BAND_PX, training_scene
from metalens_cli.design.train_loop import update
from metalens_cli.design.training_camera import TrainingCamera, expose, zero_order_veil
from metalens_cli.errors import InputError, SamplingError
from metalens_cli.imaging.canvas import narrow_margin, sensor_crop
from metalens_cli.imaging.formation import form_image, psf_margin
from metalens_cli.imaging.obstructions import make_obstruction
from metalens_cli.imaging.sample_grid import SampleGrid
from metalens_cli.io.preset_spectra import preset_sensitivity
from metalens_cli.io.presets import DEVICE_OBSTRUCTIONS, WAVELENGTH_MODES
from metalens_cli.optics.blur import psf_window
from metalens_cli.optics.channel_psf import (
    MAX_WINDOW,
    ChannelPsfStack,
    channel_psf_stack,
    field_channel_stack,
    grow_until_held,
)
from metalens_cli.optics.field import field_window
from metalens_cli.optics.sensor import larger_window
from metalens_cli.optics.spectra import sample_wavelengths
from metalens_cli.optics.two_scale import TwoScale, TwoScalePsf, window, window_reach
from metalens_cli.optics.window import crop_window
from metalens_cli.runtime import Stopwatch

IMAGE_TERMS = ("l1", "ssim", "domain_adaptation", "total")  # summed over a rank's share of the batch

# Where a training step reads tensors on the host (on CUDA each read waits for the device), by the
# code that reads ("module path:function" in the package), and why; nowhere else
# (tests/design/test_step_sync.py records them: .item, .tolist, .numpy, .cpu, bool, float, int).
# The step's other waits are its stopwatch's, one a stage on CUDA (``runtime.Stopwatch.lap``).
HOST_READS = {
    "optics/lens.py:__post_init__": "the lens the step builds from θ checks θ finite (one bool)",
    "optics/sampling.py:lens_frequency": "the propagator's sampling check takes θ's steepest phase step on the "
    "host, to refuse a learned θ it cannot sample (SamplingError)",
    "optics/propagate.py:hankel_output_matrix": "the Hankel output rows at the radii of the windows the light "
    "needs are built in float64 by scipy's Bessel functions on the host",
    "optics/channel_psf.py:_radial_stack": "the window rule: each channel's encircled energy, read to choose "
    "each depth's window (a shape), and the light the windows keep and hold (loss.csv)",
    "optics/channel_psf.py:_square_stack": "the same off axis: the concentric squares' energy and the light kept",
    "optics/field.py:_phase_gradient": "off axis: θ's phase gradient at the rays' sites on the host, to trace the "
    "geometric rays whose reach sizes the field point's windows (field_capacities)",
    "optics/field.py:_carrier_free_frequency": "off axis: the lens's largest local frequency, which sets the "
    "field propagator's sampling (a shape)",
    "optics/field.py:_field_asm": "off axis: the window's pixel coordinates (a host grid) for the resampling",
    "imaging/formation.py:check_capture_inputs": "the image formation checks the step's canvases finite",
    "imaging/formation.py:add_noise": "with a camera: the noise checks its photon counts positive",
    "imaging/metrics.py:_check_pair": "SSIM checks its reference (the clean scenes) finite",
    "design/step.py:one_step": "the loss.csv row: the reported terms summed over ranks, one .tolist() after the "
    "update, which is also the finite-loss check",
    "design/train_loop.py:update": "AdamW reads its step count (a host tensor: no wait for the device)",
}


@dataclass(frozen=True)
class StepDraw:
    """The random draws of one step (shared by every rank)."""

    z_near_m: float
    z_far_m: float
    wavelengths_m: np.ndarray
    weights: np.ndarray | torch.Tensor
    throughput: torch.Tensor | None = None  # (3,) the filter's share of each channel's light (band draws)
    field_angle_rad: float = 0.0  # the field point whose PSFs the step uses (optics.field)
    azimuth_rad: float = 0.0


def draw_step(preset, sensitivity, seed: int, step: int) -> StepDraw:
    """Depths, wavelengths and field point of a step; ``sensitivity``: the preset's S^c, or a
    ``BandSampler`` (``spectral_sampling = "bands"``: its weights a tensor, differentiable in its
    filter)."""
    rng, z_near, z_far = _depth_stream(preset, seed, step)
    angle, azimuth = draw_field(preset, seed, step)
    if isinstance(sensitivity, BandSampler):
        return StepDraw(z_near, z_far, *sensitivity.draw(rng), field_angle_rad=angle, azimuth_rad=azimuth)
    sample = sample_wavelengths(
        sensitivity,
        preset.optimize.wavelengths_per_channel,
        rng if preset.optimize.spectral_sampling == "stratified" else None,
    )
    return StepDraw(z_near, z_far, sample.wavelengths_m, sample.weights, field_angle_rad=angle, azimuth_rad=azimuth)


def _depth_stream(preset, seed: int, step: int) -> tuple[np.random.Generator, float, float]:
    """The (seed, step) stream of a step's depths and wavelengths, after its first draws: z_near
    and z_far (m)."""
    rng = np.random.default_rng([seed, step, 3])
    z_near = float(rng.uniform(*preset.scene.z_near_m))
    lo, hi = preset.scene.z_far_m
    z_far = float(rng.uniform(lo, hi)) if math.isfinite(hi) else math.inf
    return rng, z_near, z_far


def near_depth(preset, seed: int, step: int) -> float:
    """z_near (m) of step ``step`` (``draw_step``'s): the depth of its obstructions."""
    return _depth_stream(preset, seed, step)[1]


def field_training(preset) -> bool:
    """Whether the run draws field points off axis (``[optimize] field_angles`` beyond 0)."""
    return any(a > 0 for a in preset.optimize.field_angles_rad)


def draw_field(preset, seed: int, step: int) -> tuple[float, float]:
    """The field point (angle, azimuth; rad) of a step, from its own (seed, step) stream, so that
    the other draws are those of an on-axis run: one of ``optimize.field_angles``, equally likely
    (list an angle twice to weigh it double), and for a 2-D lens an azimuth uniform in [0, 2π)
    (a radial lens's PSFs at other azimuths are rotations of azimuth 0's, and its scenes have no
    preferred direction); (0, 0) for a run on axis."""
    if not field_training(preset):
        return 0.0, 0.0
    rng = np.random.default_rng([seed, step, 7])
    angles = preset.optimize.field_angles_rad
    angle = float(angles[rng.integers(len(angles))])
    azimuth = float(rng.uniform(0, 2 * math.pi)) if preset.lens.parameterization == "2d" and angle > 0 else 0.0
    return angle, azimuth


def spectral_source(preset, band_filter=None):
    """What ``draw_step`` draws from: a ``BandSampler`` for ``spectral_sampling = "bands"`` (of
    ``band_filter`` or the preset's filter), else the preset's S^c."""
    if preset.optimize.spectral_sampling == "bands":
        return band_sampler(preset, band_filter)
    return preset_sensitivity(preset)


@dataclass(frozen=True)
class Windows:
    """Where the next step looks for light (odd sides, pixels): the ``near`` and ``far``
    capacities, the last step's windows (its light, ``optics.channel_psf``) × ``PLAN_HEADROOM``;
    and the ``plan``, the window the radial kernels are built for (≥ both). The capacities follow
    the light up and down (a capacity costs Hankel output rows in proportion to its side); the plan
    only grows, ``PLAN_HEADROOM`` past the capacity that outgrew it, so that the kernels are
    rebuilt rarely (a rebuild costs seconds, a wider plan a few per cent of every step)."""

    near: int
    far: int
    plan: int

    @classmethod
    def fitted(cls, near: int, far: int, plan: int) -> Windows:
        """Capacities ``near``, ``far`` (at most ``MAX_WINDOW``) in ``plan``, grown if they pass it."""
        near, far = min(near, MAX_WINDOW), min(far, MAX_WINDOW)
        if max(near, far) > plan:
            plan = min(larger_window(max(near, far), PLAN_HEADROOM), MAX_WINDOW)
        return cls(near, far, plan)

    def margin(self, scales: TwoScale | None = None) -> int:
        """Canvas margin (pixels) the ``near`` and ``far`` capacities need around the sensor, their
        PSFs sampled as ``scales`` says (None: one scale)."""
        return max(window_reach(n, scales) for n in (self.near, self.far))

    def grown(self, outgrown) -> Windows:
        """The capacities of the depths whose light passed them (``outgrown`` (2, 3)) made larger."""
        near, far = (
            larger_window(n) if grow else n for n, grow in zip((self.near, self.far), np.any(outgrown, axis=1))
        )
        return Windows.fitted(near, far, self.plan)

    def following(self, stack: ChannelPsfStack) -> Windows:
        """The next step's capacities: this step's windows × ``PLAN_HEADROOM``, in the plan."""
        near, far = (larger_window(max(w), PLAN_HEADROOM) for w in stack.windows)
        return Windows.fitted(near, far, self.plan)


def plan_windows(preset, sensitivity) -> Windows:
    """Windows that hold the initial design's light (``optics.blur``) at every wavelength the
    channels respond to (``spectra.WEIGHT_THRESHOLD``) and both ends of each depth interval,
    times ``PLAN_HEADROOM`` for the lens to change; the plan is the larger of them."""
    waves = sensitivity.support()  # the ends of the range bound every ray (optics.blur)
    lens, d, pitch = build_model(preset).lens(), preset.lens.focal_length_m, preset.sensor.pixel_pitch_m
    near, far = preset.scene.z_near_m, preset.scene.z_far_m
    near_px, far_px = (psf_window(lens, waves, list(z), d, pitch, PLAN_HEADROOM) for z in (near, far))
    return Windows(near_px, far_px, max(near_px, far_px))


def field_capacities(lens, preset, wavelengths_m, depths_m, angle: float, windows: Windows) -> list[int]:
    """Windows (pixels) for the PSFs of the field point at ``angle`` at each of the two depths:
    the run's near and far capacities, grown to hold the geometric rays of the shortest and
    longest wavelength (``optics.field.field_window``), at most ``MAX_WINDOW``."""
    ends = [min(wavelengths_m), max(wavelengths_m)]
    d, pitch = preset.lens.focal_length_m, preset.sensor.pixel_pitch_m
    return [
        min(MAX_WINDOW, field_window(lens, ends, z, angle, d, pitch, cap))
        for z, cap in zip(depths_m, (windows.near, windows.far))
    ]


def core_window(preset) -> int | None:
    """The window of each wavelength's own core energy, where the loss asks for it."""
    return preset.loss.sharp_window if preset.loss.sharp_mode in WAVELENGTH_MODES else None


def psf_scales(preset) -> TwoScale:
    """How the step samples its PSFs: ``[optimize] halo_scale``, ``core_pixels``, ``halo_radial_step``,
    ``halo_window_blocks``."""
    o = preset.optimize
    return TwoScale(o.halo_scale, o.core_pixels, o.halo_radial_step, o.halo_window_blocks)


def far_cores(stack: ChannelPsfStack) -> torch.Tensor | None:
    """Each wavelength sample's far core energy (W,), when the stack holds them."""
    return None if stack.cores is None else stack.cores[1]


def step_psfs(
    lens,
    preset,
    draw: StepDraw,
    windows: Windows,
    device,
    watch: Stopwatch | None = None,
    frequency: float | None = None,
) -> tuple[ChannelPsfStack, Windows]:
    """Near and far (3, N, N) PSFs of one step's draw, each depth in the window its light needs
    (``optics.channel_psf``: 99.9 % of the power on the sensor plane), differentiable in θ, the
    step recomputed in larger capacities while its light outgrows them; and the next step's
    windows (``Windows.following``). Off axis: the capacities grown to hold the field point's
    geometric rays, and the windows left as they are (they follow the on-axis light)."""
    if draw.field_angle_rad > 0:
        lams = [float(x) for x in np.ravel(draw.wavelengths_m)]
        zs = [draw.z_near_m, draw.z_far_m]
        stack = field_channel_stack(
            lens, lams, zs, draw.weights,
            field_capacities(lens, preset, lams, zs, draw.field_angle_rad, windows),
            preset.sensor.pixel_pitch_m, draw.field_angle_rad, azimuth_rad=draw.azimuth_rad,
            distance_m=preset.lens.focal_length_m, device=device, core_window=core_window(preset),
            two_scale=psf_scales(preset),
        )  # fmt: skip
        _add_psf_timing(watch, stack)
        return stack, windows
    plan_l, plan_z = plan_range(preset)

    def stack_at(w: Windows) -> ChannelPsfStack:
        stack = channel_psf_stack(
            lens,
            draw.wavelengths_m,
            [draw.z_near_m, draw.z_far_m],
            draw.weights,
            (w.near, w.far),
            preset.sensor.pixel_pitch_m,
            preset.lens.focal_length_m,
            plan_pixels=w.plan,
            device=device,
            plan_wavelengths_m=plan_l,
            plan_depths_m=plan_z,
            plan_frequency=frequency,
            core_window=core_window(preset),
            two_scale=psf_scales(preset),
            radial_margin=preset.optimize.radial_margin,
        )
        _add_psf_timing(watch, stack)
        return stack

    stack, windows = grow_until_held(stack_at, windows, Windows.grown)
    return stack, windows.following(stack)


def _add_psf_timing(watch: Stopwatch | None, stack: ChannelPsfStack) -> None:
    if watch is not None:
        watch.add(stack.timing_s, "psf_")


def scenes_on_device(preset, device) -> bool:
    """Whether a step's scenes and obstructions are drawn with torch on ``device``
    (``design.device_scenes``) rather than with numpy on the host (``[optimize] scene_generator``;
    "auto": on an accelerator, for procedural scenes and obstructions it draws)."""
    o = preset.optimize
    if o.scene_generator != "auto":
        return o.scene_generator == "torch"
    supported = o.images is None and set(o.obstructions) <= set(DEVICE_OBSTRUCTIONS)
    return supported and torch.device(device).type != "cpu"


def step_batch(preset, seed: int, step: int, indices: list[int], z_near_m: float, pool, margin: int, device):
    """Clean scenes, obstruction colours and masks (B, C, H + 2M, W + 2M) on the canvas of
    ``margin`` M for the batch entries ``indices`` on ``device``: with torch there where
    :func:`scenes_on_device` says so (``design.device_scenes.device_batch``), else on the host on
    a thread pool, each scene and each obstruction a task of its own (``rain``, which refracts its
    scene, runs in its scene's task): numpy releases the GIL, and every scene and obstruction draws
    from its own (seed, step, index) stream, so neither the order nor the number of threads
    changes them."""
    if scenes_on_device(preset, device):
        return device_batch(preset, seed, step, indices, z_near_m, margin, device)
    n = preset.sensor.pixels
    kinds = preset.optimize.obstructions
    canvas = (n + 2 * margin, n + 2 * margin)
    grid = scene_grid(preset, canvas, margin)
    kind = {i: kinds[np.random.default_rng([seed, step, i, 13]).integers(len(kinds))] for i in indices}

    def obstruction(index, clean=None):
        return make_obstruction(
            kind[index],
            (n, n),
            z_near_m,
            preset.lens.focal_length_m,
            preset.sensor.pixel_pitch_m,
            [seed, step, index, 17],
            params=preset.obstruction,
            clean=clean,
            margin=margin,
            grid=grid,
        )

    def scene(index):
        clean = training_scene(canvas, seed, step, index, pool, margin, grid)
        return clean, (obstruction(index, clean) if kind[index] == "rain" else None)

    tasks = len(indices) + sum(kind[i] != "rain" for i in indices)
    with ThreadPoolExecutor(max_workers=max(1, min(tasks, torch.get_num_threads()))) as workers:
        scenes = [workers.submit(scene, i) for i in indices]
        separate = {i: workers.submit(obstruction, i) for i in indices if kind[i] != "rain"}
        entries = []
        for i, future in zip(indices, scenes):
            clean, made = future.result()
            if made is None:
                made = separate[i].result()
            entries.append((clean, made.rgb, made.mask))
    return tuple(torch.as_tensor(np.stack(arrays), dtype=torch.float32, device=device) for arrays in zip(*entries))


def scene_grid(preset, canvas: tuple[int, int], margin: int) -> SampleGrid | None:
    """Where a step's procedural scenes and dirt are drawn (``[optimize] scene_blocks``): at the
    pixels within the cores' reach of the field (at least ``design.scenes.FINE_BAND_PX``) and in
    ``halo_scale`` × ``halo_scale`` cells beyond (``imaging.sample_grid``); None: every pixel."""
    o = preset.optimize
    if not o.scene_blocks or o.halo_scale == 1:
        return None
    return SampleGrid.blocks(canvas, margin, o.halo_scale, max(o.core_pixels // 2, FINE_BAND_PX))


def scene_pool(preset, images, shard: list[int], device, end: int, background: bool = True) -> ScenePool:
    """The batches of a run's steps below ``end`` for the batch entries ``shard``
    (``step_batch`` of (seed, step, z_near of the step, margin) with the training ``images`` or
    procedural scenes), drawn ahead on a background thread unless not ``background`` or drawn on
    the run's device (:func:`scenes_on_device`: the device queues that work) (``design.scene_pool``)."""
    seed = preset.optimize.seed
    on_device = scenes_on_device(preset, device)  # then drawn in the step, the device queueing the work

    def draw(step: int, margin: int):
        where = device if on_device else "cpu"
        return step_batch(preset, seed, step, shard, near_depth(preset, seed, step), images, margin, where)

    return ScenePool(draw, device, end, background and not on_device)


def step_canvases(scenes: ScenePool, step: int, reach: int, margin: int, watch: Stopwatch) -> tuple:
    """Clean scenes, obstruction colours and masks of ``step`` on the canvas of ``margin`` (its
    PSFs'): its batch drawn at ``reach`` (the margin of the capacities the step started from,
    ``Windows.margin``), cropped to ``margin`` (``imaging.canvas.narrow_margin``); when the
    step's windows grew past ``reach``, drawn now at ``margin`` (timed as ``scenes_redrawn``; with
    ``reach`` 0, nothing drawn ahead, as ``scenes``).
    ``watch`` times the wait (``scenes``)."""
    if margin > reach:
        batch = scenes.take(step, margin)
        watch.lap("scenes_redrawn" if reach else "scenes")  # reach 0: nothing was drawn ahead
        return batch
    batch = tuple(narrow_margin(x, reach, margin) for x in scenes.take(step, reach))
    watch.lap("scenes")
    return batch


def image_pool(preset, margin: int):
    """Training photographs at twice the canvas size (random crops are resized down to it)."""
    if preset.optimize.images is None:
        return None
    from metalens_cli.imaging.images import load_images

    n = 2 * (preset.sensor.pixels + 2 * margin)
    return [image.linear for image in load_images(preset.optimize.images, (n, n))]


def sensor_psf(psf, preset) -> torch.Tensor:
    """The part of a far PSF on the whole sensor (``sensor.full_pixels``, else the step's crop
    ``sensor.pixels``): the paper's L_bright counts the light on its N sensor pixels. A two-scale
    PSF at the sensor's pixels (``TwoScalePsf.fine``: its halo spread evenly over each block)."""
    n = preset.sensor.full_pixels or preset.sensor.pixels
    if isinstance(psf, TwoScalePsf):
        return psf.fine(min(n, psf.window))
    return crop_window(psf, min(n, psf.shape[-1]))


def noise_seed(seed: int, step: int, shard: list[int]) -> int:
    """The noise stream of batch entries ``shard`` at ``step``."""
    return int(np.random.default_rng([seed, step, 31, *shard]).integers(2**62))


def camera_capture(
    clean,
    colour,
    mask,
    near,
    far,
    margin: int,
    camera: TrainingCamera | None,
    draw: StepDraw,
    seed: int,
    step: int,
    shard: list[int],
) -> torch.Tensor:
    """The obstructed captures (B, 3, H + 2M, W + 2M) of a step's canvases (``imaging.formation.
    form_image``) as ``camera`` takes them: the zero order's veil, then shot and read noise of the
    draw's filter share (``design.training_camera``), from the noise stream of ``shard``."""
    capture = form_image(clean, colour, mask, near, far, margin).obstructed
    if camera is None:
        return capture
    if camera.zero_order is not None:
        capture = capture + zero_order_veil(clean, colour, mask, camera.zero_order)
    return expose(capture, camera, draw.throughput, noise_seed(seed, step, shard))


@dataclass
class Session:
    """What every step needs: the model, its optimiser and schedule, spectra, scenes and plan
    (built by ``design.training``)."""

    model: torch.nn.Module
    optimizer: torch.optim.Optimizer
    scheduler: object
    sensitivity: object
    features: object
    pool: list | None
    shard: list[int]
    frequency: float
    windows: Windows  # follows the light; its plan grows when the light or the lens outgrows it (saved in checkpoints)
    notes: list[str]
    scenes: ScenePool  # the batches, drawn ahead (``scene_pool``)
    band_filter: LearnedFilter | None = None  # the filter learned with θ ([filter] learn = true)
    incidence: float = 1.0  # its bands' blue shift over the cone (analysis.bands)
    camera: TrainingCamera | None = None  # the light, noise and zero order the captures carry (design.training_camera)


def one_step(session: Session, preset, step: int, ctx, watch: Stopwatch) -> tuple[dict, dict, torch.Tensor]:
    """Training step ``step`` (0-based) of ``session`` on this rank (``ctx``, ``design.distributed``).

    Draws the step (``draw_step``), computes its near and far channel PSFs (``step_psfs``),
    forms this rank's share of the batch as obstructed captures with the preset's noise, takes
    the loss (``design.losses.training_loss``, and a learned filter's split and light terms),
    back-propagates, sums gradients over ranks and updates θ (``design.train_loop.update``).
    ``watch`` collects the seconds of each stage (on CUDA each waits for the device). The step's
    batch was drawn ahead (``session.scenes``, ``step_canvases``); it asks for the next step's.

    Host reads (``HOST_READS``; nothing else leaves the run's device): θ's finiteness and steepest
    phase step (the lens and the propagator's sampling checks), the radii of the Hankel output
    rows, the encircled energy that chooses the PSF windows and the light they hold, the
    finiteness checks of the canvases (image formation) and of SSIM's reference, AdamW's host
    step count, and one ``.tolist()`` of the reported loss terms after the update (the loss.csv
    row and the finite-loss check: a diverged step raises after its update).

    Returns:
        The loss.csv row (the terms summed over the whole batch, the draws, the windows and the
        light they hold), the PSF plan's grid description, and the first scene's
        clean | obstruction | capture strip (3, H, 3W) for the run's samples.
    """
    o = preset.optimize
    draw = draw_step(preset, session.sensitivity, o.seed, step)
    scales = psf_scales(preset)
    # drawn ahead, the step's batch is drawn on the canvas of its capacities, before its PSFs say what they need;
    # drawn in the step, on the canvas its PSFs need (0: no canvas drawn ahead)
    reach = session.windows.margin(scales) if session.scenes.background else 0
    session.scenes.prefetch(step, reach)  # already asked for by the step before, but for a run's first step
    session.optimizer.zero_grad(set_to_none=True)
    watch.restart()
    try:
        stack, session.windows = step_psfs(
            session.model.lens(), preset, draw, session.windows, ctx.device, watch, session.frequency
        )
    except SamplingError as error:  # the initial design passed these checks: the learned θ outgrew them
        raise InputError(
            "optimize.learning_rate",
            f"at step {step + 1} the learned lens scatters light beyond what the "
            f"propagator can sample ({error.message})",
            'a smaller learning rate or a smooth θ (theta_basis = "spline")',
        ) from error
    near, far = stack.psfs
    margin = psf_margin(near, far)
    watch.lap("psf")
    clean, colour, mask = step_canvases(session.scenes, step, reach, margin, watch)
    session.scenes.prefetch(step + 1, session.windows.margin(scales))  # drawn while this step forms and backs up
    capture = camera_capture(clean, colour, mask, near, far, margin, session.camera, draw, o.seed, step, session.shard)
    clean, colour, mask = (sensor_crop(x, margin) for x in (clean, colour, mask))
    grey = colour[0] * mask[0] + 0.5 * (1 - mask[0])
    sample = torch.cat([clean[0], grey, capture[0]], dim=-1).detach()  # rank 0's shard starts at scene 0
    share = len(session.shard) / o.batch_size
    loss, parts = training_loss(
        capture,
        clean,
        sensor_psf(far, preset),
        preset.loss,
        session.features,
        image_share=share,
        psf_share=1 / ctx.world,
        cores_far=far_cores(stack),
    )
    if session.band_filter is not None:
        loss = loss + _filter_terms(session, preset, draw, parts, loss.device).to(loss.dtype) / ctx.world
    watch.lap("formation_loss")
    loss.backward()
    watch.lap("backward")
    names = sorted(parts)
    reported = torch.stack([parts[k].detach() * (share if k in IMAGE_TERMS else 1 / ctx.world) for k in names]).double()
    update(session.optimizer, session.scheduler, reported, ctx)  # 'total' mixes shares: recomputed from the parts
    if session.band_filter is not None:
        session.band_filter.project(preset.filter, preset.sensor.wavelength_range_m)
    watch.lap("update")
    values = dict(zip(names, reported.tolist()))  # the step's one read of its loss, summed over ranks
    total = weighted_total(values, preset.loss, preset.filter)
    if not all(map(math.isfinite, [total, *values.values()])):  # every rank reads the sum: all stop here
        raise InputError(
            "optimize.learning_rate",
            f"training diverged at step {step + 1}: the loss is {total}",
            "a smaller learning rate or loss weights",
        )
    values["total"] = total
    row = {"step": step + 1, "lr": session.optimizer.param_groups[0]["lr"], **values}
    return {**row, **_step_record(session, preset, draw, stack)}, stack.grid, sample


def _filter_terms(session: Session, preset, draw: StepDraw, parts: dict, device) -> torch.Tensor:
    """The learned filter's weighted split-spectrum and light terms, their values put in ``parts``
    (the filter lives on the host; its terms join the loss on the run's ``device``)."""
    parts["split"] = split_penalty(session.band_filter, preset, session.incidence).to(device)
    parts["light"] = session.sensitivity.light_loss(draw.throughput).to(device)
    return preset.filter.split_weight * parts["split"] + preset.filter.light_weight * parts["light"]


def _step_record(session: Session, preset, draw: StepDraw, stack: ChannelPsfStack) -> dict:
    """The loss.csv columns of a step beyond its loss: depths (m), windows (px), the light each
    channel PSF keeps and holds, the learned filter's bands and the field point (deg)."""
    near, far = stack.psfs
    light = {
        f"{name}_{depth}_{c}": float(k)
        for name, values in (("kept", stack.kept), ("held", stack.held))
        for i, depth in enumerate(("near", "far"))
        for c, k in zip("RGB", values[i])
    }
    field = (
        {"field_angle_deg": math.degrees(draw.field_angle_rad), "field_azimuth_deg": math.degrees(draw.azimuth_rad)}
        if field_training(preset)
        else {}
    )
    return {
        "z_near_m": draw.z_near_m,
        "z_far_m": draw.z_far_m,
        "window_near": window(near),
        "window_far": window(far),
        "plan_window": session.windows.plan,
        **light,
        **(filter_row(session.band_filter) if session.band_filter is not None else {}),
        **field,
    }
