"""The raw-capture evaluation of designs (Suppl. Note 11 protocol), with statistics.

Every design sees the same units: (image, seed) pairs, where a seed draws the depths, the
obstructions and the noise. Per unit and design: the unobstructed and obstructed captures, raw
and (for designs given a reconstruction network) reconstructed, scored against the clean image
(``pipeline.score``: photometric match, then PSNR/SSIM/LPIPS). Reported
per (design, obstruction, condition): the mean over units with a 95 % bootstrap confidence
interval; Δ = obstructed − unobstructed per unit (for LPIPS unobstructed − obstructed, as the
paper defines it: negative is a degradation for every metric); and paired differences between
designs on the same units (raw against raw, recon against recon) and between each design's
recon and raw captures.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import os
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from metalens_cli import arguments
from metalens_cli.analysis.statistics import mean_ci, paired_difference_ci
from metalens_cli.errors import InputError
from metalens_cli.imaging.camera import DEFAULT_READ_ELECTRONS, Camera
from metalens_cli.imaging.channel_psfs import ChannelPsfs
from metalens_cli.imaging.field_formation import DEFAULT_TOLERANCE
from metalens_cli.imaging.formation import check_formation
from metalens_cli.imaging.images import load_images
from metalens_cli.imaging.metrics import DEFAULT_MATCH
from metalens_cli.imaging.model_scores import summarise_model, unit_output
from metalens_cli.imaging.pipeline import (
    CaptureSetup,
    attach_zero_order,
    capture_psfs,
    draw_depths,
    score,
    simulate_captures,
)
from metalens_cli.imaging.targets import check_tasks, draw_targets, layout, task_sizes
from metalens_cli.imaging.task_detection import check_dependencies, score_tasks, to_rgb8
from metalens_cli.imaging.task_scores import compared_pairs, summarise_tasks, unit_tasks
from metalens_cli.imaging.task_truth import truth_of
from metalens_cli.io.atomic import atomic_write
from metalens_cli.optics.two_scale import halo_sampling

CONDITIONS = ("unobstructed", "obstructed")
MIN_UNITS = 20  # fewer units per cell: a warning (bootstrap CIs of a handful of units are wide and unreliable)


@dataclass
class EvaluationSettings:
    """What every unit shares: sensor, depth intervals (m), wavelengths (m), image source,
    obstruction parameters, formation and scoring options, and the camera.

    Attributes:
        pixels: the sensor's side (pixels).
        pixel_pitch_m: sensor pixel pitch (m).
        z_near_interval_m: obstruction depths (lo, hi) (m).
        z_far_interval_m: scene depths (lo, hi) (m).
        wavelengths_m: the wavelengths (m) of the channel quadrature.
        images: the clean images: a named set, a folder or one file.
        limit: at most this many images; None: all.
        obstruction_params: obstruction generator parameters; None: the defaults.
        formation: "physical" or "paper" (:func:`form_image`).
        match: the photometric match before scoring, "lstsq" or "luminance".
        alpha_gain: as in :func:`form_image`.
        photons: without ``light_levels``: full-well electrons of the capture (or before the filter
            with ``photons_before_filter``); None: no shot noise.
        read_noise: without ``light_levels``: read-noise σ, a fraction of full scale.
        photons_before_filter: ``photons`` count the light before each design's filter (its
            throughput passes).
        psf_window: one N × N window (pixels) forced for the channel PSFs; None: each depth in the
            window its light needs (``imaging.channel_psfs``).
        device: torch device.
        field_model: "on-axis", or "auto": PSFs over the field where the sensor outgrows the
            isoplanatic patch.
        field_tolerance: the space-variant formation's tolerance (relative L2,
            ``imaging.field_formation``).
        halo_scale: each PSF's halo convolved in blocks of up to this many pixels
            (``optics.two_scale.halo_sampling``); 1: one scale.
        light_levels: ``imaging.camera``: electrons at full scale before each design's filter, None
            for noise-free; one table per level, the same noise draws at every level.
        read_electrons: read noise (electrons rms) with ``light_levels``.
        zero_order_leak: the analyzer's zero-order leak in 0..1; None: no zero-order light.
        wiener: add the oracle Wiener rows (``imaging.wiener``).
        tasks: vision tasks (``imaging.targets.TASKS``) whose targets are drawn into every clean
            scene before imaging, and whose detectors score every capture (``imaging.task_scores``).
        model: a user's model (``imaging.task_models.TaskModel``) run on every capture and scored
            (``imaging.model_scores``); None: none.
        model_truth: its truth: "clean" (its own output on each clean scene,
            ``imaging.task_truth``), or per image name the labels on the sensor (``label_truths``).
    """

    pixels: int
    pixel_pitch_m: float
    z_near_interval_m: tuple[float, float]
    z_far_interval_m: tuple[float, float]
    wavelengths_m: list[float]
    images: str = "photos"
    limit: int | None = None
    obstruction_params: object = None
    formation: str = "physical"
    match: str = DEFAULT_MATCH
    alpha_gain: float | None = None
    photons: float | None = None
    read_noise: float = 0.0
    photons_before_filter: bool = False  # photons count the light before each design's filter (its throughput passes)
    psf_window: int | None = None
    device: object = "cpu"
    field_model: str = "on-axis"  # "auto": PSFs over the field where the sensor outgrows the isoplanatic patch
    field_tolerance: float = DEFAULT_TOLERANCE  # the space-variant formation's (imaging.field_formation)
    halo_scale: int = 1  # captures with each PSF's halo in blocks of up to this many pixels (optics.two_scale)
    light_levels: list | None = None
    read_electrons: float = DEFAULT_READ_ELECTRONS
    zero_order_leak: float | None = None
    wiener: bool = False
    tasks: tuple[str, ...] = ()
    model: object = None
    model_truth: object = "clean"

    def __post_init__(self) -> None:
        """The sensor, depth intervals and wavelengths, the form and the noise, each checked with
        its field's name (``metalens_cli.arguments``)."""
        arguments.count(self.pixels, "pixels")
        arguments.positive(self.pixel_pitch_m, "pixel_pitch_m")
        arguments.interval(self.z_near_interval_m, "z_near_interval_m")
        arguments.interval(self.z_far_interval_m, "z_far_interval_m", allow_inf=True)
        arguments.lengths(self.wavelengths_m, "wavelengths_m")
        check_formation(self.formation)
        arguments.number(self.read_noise, "read_noise", lo=0.0, form="a standard deviation ≥ 0 (full scale)")
        for name in ("photons", "alpha_gain", "zero_order_leak"):
            if getattr(self, name) is not None:
                arguments.number(getattr(self, name), name, lo=0.0, form="a number ≥ 0")
        arguments.number(self.read_electrons, "read_electrons", lo=0.0, form="read noise ≥ 0 (e⁻)")
        self.tasks = check_tasks(self.tasks)
        check_dependencies(self.tasks)
        for task in self.tasks:
            if not task_sizes(task, (self.pixels, self.pixels)).size:
                raise InputError("--task", f"{task}: no target fits a {self.pixels}² sensor", "a larger --pixels")

    @classmethod
    def from_setup(cls, setup: CaptureSetup, **options) -> EvaluationSettings:
        """The sensor, depth intervals, wavelengths, obstruction parameters and device of
        ``setup``, with the other fields from ``options``."""
        return cls(
            setup.pixels,
            setup.pixel_pitch_m,
            setup.z_near_interval_m,
            setup.z_far_interval_m,
            setup.wavelengths_m,
            obstruction_params=setup.obstruction_params,
            device=setup.device,
            **options,
        )

    def cameras(self) -> list[Camera] | None:
        """One camera per light level (None without ``light_levels``)."""
        if self.light_levels is None:
            return None
        leak = self.zero_order_leak or 0.0
        return [Camera(level, self.read_electrons, leak) for level in self.light_levels]


@dataclass
class Evaluation:
    """Results: ``rows`` (design, capture, obstruction, condition, metric means, ``<metric>_ci``, n;
    ``light`` with light levels), ``deltas``, ``comparisons`` (paired design differences),
    ``verdicts`` (per pair of designs over the light levels, :func:`verdicts`), ``units`` (every
    score), ``psfs`` (per design and seed: depths, windows, kept light), ``images`` (names),
    ``panels`` (first image and seed, for figures), ``warnings``, ``notes``, ``cameras`` (each
    level's label, the designs' budgets and Wiener μ), for captured pairs ``alignments``, with
    tasks their ``tasks`` rows and ``task_comparisons`` (``imaging.task_scores``), and with a
    user's model its ``model`` rows and ``model_comparisons`` (``imaging.model_scores``)."""

    rows: list[dict] = field(default_factory=list)
    deltas: list[dict] = field(default_factory=list)
    comparisons: list[dict] = field(default_factory=list)
    verdicts: list[dict] = field(default_factory=list)
    units: list[dict] = field(default_factory=list)
    psfs: list[dict] = field(default_factory=list)
    images: list[str] = field(default_factory=list)
    panels: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    cameras: list[dict] = field(default_factory=list)
    alignments: list[dict] = field(default_factory=list)
    tasks: list[dict] = field(default_factory=list)
    task_comparisons: list[dict] = field(default_factory=list)
    model: list[dict] = field(default_factory=list)
    model_comparisons: list[dict] = field(default_factory=list)


def design_photons(design, settings: EvaluationSettings):
    """The full-well electrons of a design's captures: ``settings.photons``, or with
    ``photons_before_filter`` that many times each channel's filter throughput (3,)
    (``io.preset_spectra.channel_throughput``: designs with other filters at the same light)."""
    if not settings.photons or not settings.photons_before_filter:
        return settings.photons
    from metalens_cli.io.preset_spectra import channel_throughput

    return settings.photons * channel_throughput(design.preset)


def metric_names(lpips_model) -> tuple[str, ...]:
    """The metric keys in report order: ``psnr_db`` (dB), ``ssim``, and ``lpips`` when an LPIPS
    model is given."""
    return ("psnr_db", "ssim", "lpips") if lpips_model is not None else ("psnr_db", "ssim")


def delta(metric: str, unobstructed: float, obstructed: float) -> float:
    """Δ of one unit: obstructed − unobstructed, or unobstructed − obstructed for LPIPS (lower is better)."""
    return unobstructed - obstructed if metric == "lpips" else obstructed - unobstructed


HELD_OUT_SCENES = 4  # dead-leaves charts the Wiener μ is chosen on
HELD_OUT_FIRST = 10_000  # their chart indices: far from any evaluated chart's


def expose(image: np.ndarray, counts, read_electrons: float, generator: int) -> np.ndarray:
    """A noise-free linear capture (3, H, W) exposed with ``counts`` (3,) electrons at full scale
    per channel (None: returned as it is) and ``read_electrons`` rms, seeded by ``generator``."""
    if counts is None:
        return image
    from metalens_cli.imaging.formation import add_noise

    x = torch.as_tensor(image, dtype=torch.float64)
    n = torch.as_tensor(np.asarray(counts, dtype=float), dtype=torch.float64).reshape(-1, 1, 1)
    return add_noise(x, n, read_noise=read_electrons / n, generator=generator).numpy().astype(np.float32)


def held_out_wiener(design, psfs: ChannelPsfs, cameras, budget, settings: EvaluationSettings) -> list:
    """One :class:`~metalens_cli.imaging.wiener.WienerFilter` per camera (None: noise-free) for ``design``: its far
    PSFs, μ chosen on ``HELD_OUT_SCENES`` dead-leaves charts captured through it (unobstructed,
    the evaluation's formation, noise drawn apart from the evaluation's)."""
    from metalens_cli.imaging.camera import electrons
    from metalens_cli.imaging.images import chart
    from metalens_cli.imaging.wiener import WienerFilter, choose_mu

    sensor = (settings.pixels, settings.pixels)
    scenes = [chart(HELD_OUT_FIRST + k, sensor, psfs.margin) for k in range(HELD_OUT_SCENES)]
    clear = [
        c.unobstructed
        for c in simulate_captures(scenes, "fence", psfs, design.focal_length_m, settings.pixel_pitch_m, 0)
    ]
    base = WienerFilter.of(psfs.far, sensor)  # the transfer function once; μ per camera
    filters = []
    for camera in cameras:
        if camera is None:
            noisy = clear
        else:
            counts = electrons(budget, camera)
            noisy = [expose(x, counts, camera.read_electrons, 10**6 + k) for k, x in enumerate(clear)]
        mu, _ = choose_mu(base, noisy, [scene.sensor for scene in scenes])
        filters.append(dataclasses.replace(base, mu=mu))
    return filters


def evaluate(
    designs,
    kinds: list[str],
    seeds: list[int],
    settings: EvaluationSettings,
    *,
    lpips_model=None,
    on_progress: Callable[[int, int], None] | None = None,
    reconstructors: list | None = None,
) -> Evaluation:
    """Score every design on the same (image, seed) units for every obstruction kind, under every
    camera of ``settings``.

    Designs without a preset are imaged with the nanofin efficiency of the first design that has
    one (``imaging.camera.efficiency_sources``).

    Args:
        designs: the resolved designs (:func:`resolve_design`).
        kinds: obstruction kinds.
        seeds: seeds; each (image, seed) is one unit, shared by every design.
        settings: the :class:`EvaluationSettings`.
        lpips_model: an ``imaging.lpips.Lpips`` to score LPIPS too; None: PSNR (dB) and SSIM only.
        on_progress: ``on_progress(done, total)`` reports progress.
        reconstructors: one per design, a callable mapping a linear (3, H, W) capture to its
            reconstruction (``imaging.restore.Reconstructor``) or None; designs with one are
            scored on their ``recon`` captures as well as their ``raw`` ones (and ``wiener`` ones
            with ``settings.wiener``).

    Returns:
        ``Evaluation``: per-cell rows of metric means with confidence intervals, paired design
        comparisons and verdicts, every unit's scores, the PSFs used, warnings and notes.
    """
    from metalens_cli.imaging.camera import channel_budget, efficiency_sources, electrons

    arguments.instance(settings, "settings", EvaluationSettings, "EvaluationSettings")
    if not arguments.instance(designs, "designs", (list, tuple), "a list of Designs (ml.resolve_design)"):
        raise InputError("designs", "is empty", "at least one Design")
    if settings.wiener and settings.light_levels is None and (settings.photons or settings.read_noise):
        raise InputError(
            "--wiener", "with --photons or --read-noise", "--light LEVELS (the camera the filter is chosen for)"
        )
    out = Evaluation()
    shared, warnings, notes = efficiency_sources(designs)
    out.warnings += warnings
    out.notes += notes
    designs = [dataclasses.replace(d, efficiency=shared) if d.preset is None else d for d in designs]
    recon = list(reconstructors) if reconstructors is not None else [None] * len(designs)
    cameras = settings.cameras()
    levels = cameras or [None]  # None: the legacy noise of photons and read_noise, inside the captures
    budgets = [channel_budget(d, settings.zero_order_leak or 0.0) for d in designs]
    psfs: dict[tuple[int, int], ChannelPsfs] = {}
    for d, design in enumerate(designs):
        at_depths: dict[tuple[float, float], ChannelPsfs] = {}  # seeds drawing the same depths share them
        for seed in seeds:
            z_near, z_far = draw_depths(settings.z_near_interval_m, settings.z_far_interval_m, seed)
            p = at_depths.get((z_near, z_far))
            if p is None:
                p = capture_psfs(
                    design,
                    z_near,
                    z_far,
                    settings.wavelengths_m,
                    settings.pixel_pitch_m,
                    settings.pixels,
                    field_model=settings.field_model,
                    field_tolerance=settings.field_tolerance,
                    two_scale=halo_sampling(settings.halo_scale),
                    device=settings.device,
                    window=settings.psf_window,
                )
                attach_zero_order(p, design, settings.pixel_pitch_m, settings.zero_order_leak or 0.0)
            psfs[d, seed] = at_depths[z_near, z_far] = p
            out.psfs.append(
                {
                    "design": design.spec,
                    "seed": seed,
                    "z_near_m": z_near,
                    "z_far_m": z_far,
                    **p.report(),
                    "seconds": p.seconds,
                }
            )
            out.warnings += [f"{design.spec}, seed {seed}: {w}" for w in p.warnings()]
    photons = [design_photons(design, settings) for design in designs]
    margin = max(p.margin for p in psfs.values())  # one canvas for all: every design sees the same scene
    images = load_images(settings.images, (settings.pixels, settings.pixels), settings.limit, margin)
    out.images = [image.name for image in images]
    sensor = (settings.pixels, settings.pixels)
    targets = {(seed, i): layout(settings.tasks, sensor, seed, i) for seed in seeds for i in range(len(images))}
    outcomes: dict[tuple, dict] = {}  # task outcomes, keyed as scores
    ceiling: dict[tuple, dict] = {}  # (seed, image index) → the clean scene's task outcomes
    model = settings.model
    model_outputs: dict[tuple, object] = {}  # what each capture's model output keeps, keyed as scores
    model_clean: dict[tuple, object] = {}  # (seed, image index) → the same of the clean scene
    model_truth: dict[tuple, object] = {}  # (seed, image index) → the truth
    metrics = metric_names(lpips_model)
    captures_of = [
        ["raw", *(["wiener"] if settings.wiener else []), *(["recon"] if r is not None else [])] for r in recon
    ]
    scores: dict[tuple, dict] = {}
    total, done = len(designs) * len(kinds) * len(seeds), 0
    out.panels = {design.spec: [] for design in designs}
    obstructions: dict = {}  # generated once, shared by the designs (same seed, depths and canvas)
    units: dict[tuple, list] = {}  # (kind, seed, design) → its units, listed in that order at the end
    for d, design in enumerate(designs):  # one design's capture transforms held at a time
        chosen = held_out_wiener(design, psfs[d, seeds[0]], levels, budgets[d], settings) if settings.wiener else None
        # μ per camera from the first seed's PSFs; each seed's own far PSFs in its filters
        wieners = None if chosen is None else {(seeds[0], li): w for li, w in enumerate(chosen)}
        for seed in seeds[1:] if chosen else []:
            for li, w in enumerate(chosen):
                wieners[seed, li] = w if psfs[d, seed] is psfs[d, seeds[0]] else _for_seed(w, psfs[d, seed])
        out.cameras.append(
            {
                "design": design.spec,
                "throughput": budgets[d].throughput.tolist(),
                "zero_order": budgets[d].zero_order.tolist() if settings.zero_order_leak else [0.0, 0.0, 0.0],
                **({"wiener_mu": [w.mu.tolist() for w in chosen]} if chosen else {}),
            }
        )
        for kind in kinds:
            for seed in seeds:
                scenes = [
                    draw_targets(image, targets[seed, i]) for i, image in enumerate(images)
                ]  # as is without tasks
                captures = simulate_captures(
                    scenes,
                    kind,
                    psfs[d, seed],
                    design.focal_length_m,
                    settings.pixel_pitch_m,
                    seed,
                    params=settings.obstruction_params,
                    formation=settings.formation,
                    alpha_gain=settings.alpha_gain,
                    photons=None if cameras else photons[d],
                    read_noise=0.0 if cameras else settings.read_noise,
                    obstructions=obstructions,
                )
                for index, c in enumerate(captures):
                    if settings.tasks and (seed, index) not in ceiling:
                        ceiling[seed, index] = score_tasks(c.clean, targets[seed, index], settings.tasks)
                    if model is not None and (seed, index) not in model_truth:
                        on_clean = model(to_rgb8(c.clean))
                        model_truth[seed, index] = truth_of(model, on_clean, settings.model_truth, c.name)
                        model_clean[seed, index] = unit_output(model.kind, on_clean, model_truth[seed, index])
                    for li, camera in enumerate(levels):
                        if camera is None:
                            clear, obstructed = c.unobstructed, c.obstructed
                        else:
                            counts = electrons(budgets[d], camera)
                            noise = seed * 1000 + 2 * index  # the same draws at every level and for every design
                            clear = expose(c.unobstructed, counts, camera.read_electrons, noise + 1)
                            obstructed = expose(c.obstructed, counts, camera.read_electrons, noise)
                        estimates = {"raw": lambda x: x}
                        if wieners is not None:
                            estimates["wiener"] = wieners[seed, li]
                        if recon[d] is not None:
                            estimates["recon"] = recon[d]
                        for capture, restore in estimates.items():
                            key = (li, capture, d, "unobstructed", seed, index)  # the same for every obstruction kind
                            if key not in scores:
                                restored = restore(clear)
                                scores[key] = score(restored, c.clean, lpips_model, settings.match)
                                if settings.tasks:
                                    outcomes[key] = score_tasks(restored, targets[seed, index], settings.tasks)
                                if model is not None:
                                    model_outputs[key] = unit_output(
                                        model.kind, model(to_rgb8(restored)), model_truth[seed, index]
                                    )
                            estimate = restore(obstructed)
                            scores[li, capture, d, kind, seed, index] = score(
                                estimate, c.clean, lpips_model, settings.match
                            )
                            if settings.tasks:
                                outcomes[li, capture, d, kind, seed, index] = score_tasks(
                                    estimate, targets[seed, index], settings.tasks
                                )
                            if model is not None:
                                model_outputs[li, capture, d, kind, seed, index] = unit_output(
                                    model.kind, model(to_rgb8(estimate)), model_truth[seed, index]
                                )
                            units.setdefault((kind, seed, d), []).append(
                                {
                                    "design": design.spec,
                                    "capture": capture,
                                    "obstruction": kind,
                                    "seed": seed,
                                    "image": c.name,
                                    **({} if camera is None else {"light": camera.label()}),
                                    "unobstructed": scores[key],
                                    "obstructed": scores[li, capture, d, kind, seed, index],
                                    **(
                                        {
                                            "tasks": unit_tasks(
                                                targets[seed, index],
                                                outcomes[key],
                                                outcomes[li, capture, d, kind, seed, index],
                                            )
                                        }
                                        if settings.tasks
                                        else {}
                                    ),
                                }
                            )
                            if seed == seeds[0] and index == 0 and li == len(levels) - 1:
                                panels = out.panels[design.spec]
                                if capture == "raw" and not panels:
                                    panels += [("clean", c.clean), ("unobstructed", clear)]
                                prefix = "" if capture == "raw" else f"{capture}, "
                                panels.append((f"{prefix}obstructed: {kind}", estimate))
                done += 1
                if on_progress is not None:
                    on_progress(done, total)
        for seed in seeds:
            psfs[d, seed].transforms.clear()
    out.units = [unit for kind in kinds for seed in seeds for d in range(len(designs)) for unit in units[kind, seed, d]]
    specs = [design.spec for design in designs]
    for li, camera in enumerate(levels):
        view = {key[1:]: value for key, value in scores.items() if key[0] == li}
        first = (len(out.rows), len(out.deltas), len(out.comparisons))
        summarise(out, specs, captures_of, kinds, seeds, len(images), metrics, view)
        if camera is not None:
            for entries, start in zip((out.rows, out.deltas, out.comparisons), first):
                for entry in entries[start:]:
                    entry["light"] = camera.label()
        if settings.tasks:
            rows, comparisons = summarise_tasks(
                settings.tasks,
                specs,
                captures_of,
                kinds,
                [(seed, index) for seed in seeds for index in range(len(images))],
                {key[1:]: value for key, value in outcomes.items() if key[0] == li},
                ceiling,
                targets,
                None if camera is None else camera.label(),
            )
            out.tasks += rows
            out.task_comparisons += comparisons
        if model is not None:
            rows, comparisons = summarise_model(
                model.kind,
                specs,
                captures_of,
                kinds,
                [(seed, index) for seed in seeds for index in range(len(images))],
                {key[1:]: value for key, value in model_outputs.items() if key[0] == li},
                model_clean,
                model_truth,
                None if camera is None else camera.label(),
            )
            out.model += rows
            out.model_comparisons += comparisons
    if cameras:
        out.verdicts = verdicts(specs, captures_of, kinds, seeds, len(images), cameras, scores)
    warn_few_units(
        out,
        len(images) * len(seeds),
        f"{len(images)} image(s) × {len(seeds)} seed(s)",
        "add seeds (--seed 0:4) or images",
    )
    return out


def _for_seed(wiener, psfs: ChannelPsfs):
    """``wiener``'s μ with the far PSFs of another seed's depths."""
    from metalens_cli.imaging.wiener import WienerFilter

    return WienerFilter.of(psfs.far, wiener.sensor_hw, wiener.mu)


def verdicts(specs, captures_of, kinds, seeds, n_images: int, cameras, scores) -> list[dict]:
    """The first design against each other one, per capture both have and obstruction kind: the
    paired obstructed PSNR difference at every finite light level and where it stops being
    positive (``analysis.statistics.crossover``), with the noise-free difference beside it."""
    from metalens_cli.analysis.statistics import crossover

    finite = sorted((c.light, li) for li, c in enumerate(cameras) if c.light is not None)
    free = [li for li, c in enumerate(cameras) if c.light is None]
    units = [(seed, index) for seed in seeds for index in range(n_images)]
    out = []
    for other in range(1, len(specs)):
        for capture in [c for c in captures_of[0] if c in captures_of[other]]:
            for kind in kinds:

                def difference(li, capture=capture, kind=kind, other=other):
                    return [
                        scores[li, capture, 0, kind, s, i]["psnr_db"]
                        - scores[li, capture, other, kind, s, i]["psnr_db"]
                        for s, i in units
                    ]

                entry = {"design": specs[0], "versus": specs[other], "capture": capture, "obstruction": kind}
                entry["metric"], entry["condition"] = "psnr_db", "obstructed"
                if free:
                    stats = mean_ci(difference(free[0]), metric="psnr_db difference")
                    entry["noise_free"] = {"difference": stats["mean"], "ci": stats["ci"]}
                if len(finite) >= 2:
                    entry.update(crossover([level for level, _ in finite], [difference(li) for _, li in finite]))
                    entry["verdict"] = verdict_text(entry)
                out.append(entry)
    return out


def verdict_text(entry: dict) -> str:
    """One line: at which light levels the first design wins (its paired CI above 0)."""
    levels, wins = entry["levels"], entry["wins"]
    span = f"{levels[0]:g}-{levels[-1]:g} e⁻"
    lo, hi = entry["crossover_ci"]
    if all(wins):
        return f"wins at every light level ({span}; whole CI above 0)"
    if entry["above"]:
        return f"does not win at any light level of {span} (mean difference ≤ 0 at {levels[-1]:g} e⁻)"
    if entry["below"]:
        won = [f"{v:g}" for v, w in zip(levels, wins) if w]
        return f"ahead at every light level of {span} in the mean; CI above 0 at {', '.join(won) or 'none'} e⁻"
    return (
        f"wins above {entry['crossover']:.0f} e⁻ [95 % CI {lo:.0f}, {hi:.0f}] (the crossover); "
        f"at {levels[0]:g} e⁻ the difference is {entry['means'][0]:+.2f} dB"
    )


def warn_few_units(out: Evaluation, units: int, what: str, advice: str) -> None:
    """A warning in ``out`` when a cell has fewer than ``MIN_UNITS`` units."""
    if units < MIN_UNITS:
        out.warnings.append(
            f"{units} units per cell ({what}), fewer than {MIN_UNITS}: the confidence intervals are wide "
            f"and unreliable; {advice}"
        )


def summarise(
    out: Evaluation, specs: list[str], captures_of: list, kinds, seeds, n_images: int, metrics, scores
) -> None:
    """Fill ``out.rows``, ``deltas`` and ``comparisons`` from ``scores[(capture, design index,
    condition or "unobstructed", seed, image index)]`` (metric dicts) over the units (seed,
    image); designs named ``specs``, each scored on the captures ``captures_of[d]`` lists ("raw",
    then "wiener" and "recon" where they were made). Design against design on the same capture;
    each design's restorations against its raw capture (and recon against wiener)."""
    from metalens_cli.imaging.metrics import PSNR_CEILING_DB

    exact = sum(1 for value in scores.values() if value["psnr_db"] >= PSNR_CEILING_DB)
    if exact:
        out.warnings.append(
            f"{exact} score(s) match their reference exactly; their PSNR is reported as the {PSNR_CEILING_DB:g} dB "
            "ceiling"
        )
    units = [(seed, index) for seed in seeds for index in range(n_images)]
    cells = [(capture, d) for d in range(len(specs)) for capture in captures_of[d]]

    def values(capture, d, kind, condition, metric):
        return [
            scores[(capture, d, "unobstructed" if condition == "unobstructed" else kind, seed, index)][metric]
            for seed, index in units
        ]

    def deltas(capture, d, kind, metric):
        return [
            delta(metric, u, o)
            for u, o in zip(
                values(capture, d, kind, "unobstructed", metric), values(capture, d, kind, "obstructed", metric)
            )
        ]

    for kind in kinds:
        for capture, d in cells:
            for condition in CONDITIONS:
                row = {
                    "design": specs[d],
                    "capture": capture,
                    "obstruction": kind,
                    "condition": condition,
                    "n": len(units),
                }
                for metric in metrics:
                    stats = mean_ci(values(capture, d, kind, condition, metric), metric=metric)
                    row[metric], row[f"{metric}_ci"] = stats["mean"], stats["ci"]
                out.rows.append(row)
            entry = {"design": specs[d], "capture": capture, "obstruction": kind, "n": len(units)}
            for metric in metrics:
                stats = mean_ci(deltas(capture, d, kind, metric), metric=f"delta_{metric}")
                entry[f"delta_{metric}"], entry[f"delta_{metric}_ci"] = stats["mean"], stats["ci"]
            out.deltas.append(entry)
        # design against design on the same kind of capture, and each design's recon against its raw
        for first_cell, second_cell in compared_pairs(cells):
            for condition in (*CONDITIONS, "delta"):
                for metric in metrics:
                    if condition == "delta":
                        first, second = deltas(*first_cell, kind, metric), deltas(*second_cell, kind, metric)
                    else:
                        first, second = (values(*cell, kind, condition, metric) for cell in (first_cell, second_cell))
                    stats = paired_difference_ci(first, second, metric=metric)
                    out.comparisons.append(
                        {
                            "design": specs[first_cell[1]],
                            "capture": first_cell[0],
                            "versus": specs[second_cell[1]],
                            "versus_capture": second_cell[0],
                            "obstruction": kind,
                            "condition": condition,
                            "metric": metric,
                            "difference": stats["mean"],
                            "ci": stats["ci"],
                            "n": stats["n"],
                        }
                    )


def evaluation_report(result: Evaluation, extra: dict, notes: list[str], csv_path=None, plot_path=None) -> dict:
    """The JSON report of an evaluation: rows, deltas, comparisons, units, images, the confidence
    level, ``extra`` (what was evaluated and how), ``notes``, warnings and the files written."""
    return {
        "rows": result.rows,
        "deltas": result.deltas,
        "comparisons": result.comparisons,
        "units": result.units,
        "images": result.images,
        "confidence": 0.95,
        **({"tasks": result.tasks, "task_comparisons": result.task_comparisons} if result.tasks else {}),
        **({"model": result.model, "model_comparisons": result.model_comparisons} if result.model else {}),
        **extra,
        "notes": notes,
        "warnings": result.warnings,
        **({"csv": str(csv_path)} if csv_path else {}),
        **({"plot": str(plot_path)} if plot_path else {}),
    }


def write_rows_csv(path: str | os.PathLike[str], rows: list[dict], metrics=("psnr_db", "ssim")) -> None:
    """The rows of an evaluation as CSV, atomically: (light, when rows have one,) design, capture,
    obstruction, condition, n, then per metric its mean and the bounds of its confidence interval."""
    keys = (["light"] if any("light" in row for row in rows) else []) + [
        "design",
        "capture",
        "obstruction",
        "condition",
        "n",
    ]
    columns = keys + [c for m in metrics for c in (m, f"{m}_lo", f"{m}_hi")]
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow(
            {
                **{k: row[k] for k in keys},
                **{
                    c: v
                    for m in metrics
                    for c, v in ((m, row[m]), (f"{m}_lo", row[f"{m}_ci"][0]), (f"{m}_hi", row[f"{m}_ci"][1]))
                },
            }
        )
    with atomic_write(path) as temporary:
        temporary.write_text(buffer.getvalue(), encoding="utf-8")
