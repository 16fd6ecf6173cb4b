"""From a design to captures: channel PSFs at the near and far depths, then image formation.

Shared by ``metalens simulate`` and ``metalens evaluate`` (and usable from Python). Depths are
drawn once per run from the configured intervals with the run's seed.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from metalens_cli import arguments
from metalens_cli.constants import PAPER_Z_FAR_M, PAPER_Z_NEAR_M
from metalens_cli.errors import InputError
from metalens_cli.imaging.channel_psfs import ChannelPsfs, ZeroOrder, channel_psfs
from metalens_cli.imaging.field_formation import DEFAULT_TOLERANCE, field_transform, form_image_field
from metalens_cli.imaging.field_psfs import estimate_field_psfs, field_channel_psfs, field_dependence
from metalens_cli.imaging.formation import (
    add_noise,
    canvas_margin,
    form_image,
    psf_transform,
    transform,
    zero_order_light,
)
from metalens_cli.imaging.metrics import DEFAULT_MATCH
from metalens_cli.imaging.obstructions import Obstruction, make_obstruction
from metalens_cli.io.presets import ObstructionConfig
from metalens_cli.io.resources import Estimate

DEFAULT_Z_NEAR_M = PAPER_Z_NEAR_M  # Suppl. Note 4
DEFAULT_Z_FAR_M = PAPER_Z_FAR_M
DEFAULT_WAVELENGTHS = "400:700:5nm"


@dataclass(frozen=True)
class CaptureSetup:
    """What simulate, evaluate and reconstruct train capture with (SI metres): the designs, the
    sensor crop, the depth intervals [lo, hi], the wavelengths integrated over, the torch device
    and the obstruction parameters in force (None: the defaults)."""

    designs: list
    pixels: int
    pixel_pitch_m: float
    z_near_interval_m: tuple[float, float]
    z_far_interval_m: tuple[float, float]
    wavelengths_m: list[float]
    device: object  # torch.device
    obstruction_params: ObstructionConfig | None


def draw_depths(z_near_m: tuple[float, float], z_far_m: tuple[float, float], seed: int) -> tuple[float, float]:
    """One near and one far depth, uniform in their intervals (a single length: that length)."""
    rng = np.random.default_rng([seed, 1])
    near, far = float(rng.uniform(*z_near_m)), float(rng.uniform(*z_far_m))
    if not near < far:
        raise InputError(
            "--z-near", f"obstruction at {near} m is not in front of the scene at {far} m", "z-near below z-far"
        )
    return near, far


FIELD_MODELS = ("on-axis", "auto")


def capture_psfs(
    design,
    z_near_m: float,
    z_far_m: float,
    wavelengths_m,
    pixel_pitch_m: float,
    sensor_pixels: int,
    *,
    field_model: str = "on-axis",
    device="cpu",
    window: int | None = None,
    field_tolerance: float = DEFAULT_TOLERANCE,
    two_scale=None,
) -> ChannelPsfs:
    """:func:`channel_psfs` (``two_scale``: captures with core and halo, ``optics.two_scale``), and
    with ``field_model`` "auto" the field PSF set
    (``imaging.field_psfs``) when the isoplanatic test says the ``sensor_pixels``² sensor spans
    more than the lens's patch (``field_test`` says which and why); "on-axis": one PSF per depth.
    ``field_tolerance``: the relative L2 error of the field transforms the captures will use."""
    if field_model not in FIELD_MODELS:
        raise InputError("--field", f"{field_model!r}", " or ".join(FIELD_MODELS))
    psfs = channel_psfs(
        design, z_near_m, z_far_m, wavelengths_m, pixel_pitch_m, device=device, window=window, two_scale=two_scale
    )
    psfs.field_tolerance = field_tolerance
    if field_model == "on-axis":
        psfs.field_test = {"requested": "on-axis", "model": "on-axis"}
        return psfs
    test = field_dependence(design, sensor_pixels, pixel_pitch_m)
    psfs.field_test = {"requested": "auto", "model": "field" if test["field_dependent"] else "on-axis", **test}
    if test["field_dependent"]:
        psfs.field_psfs = field_channel_psfs(
            design, z_near_m, z_far_m, wavelengths_m, pixel_pitch_m, sensor_pixels, device=device
        )
        psfs.seconds += psfs.field_psfs.seconds
    return psfs


def attach_zero_order(psfs: ChannelPsfs, design, pixel_pitch_m: float, zero_order_leak: float) -> ChannelPsfs:
    """Give ``psfs`` the zero-order light of ``design`` behind an analyzer that passes
    ``zero_order_leak`` of it (``imaging.camera.channel_budget``); 0 gives none."""
    from metalens_cli.imaging.camera import channel_budget
    from metalens_cli.optics.zero_order import zero_order_psf

    if zero_order_leak == 0:
        return psfs
    budget = channel_budget(design, zero_order_leak)
    dev, dt = psfs.near.device, psfs.near.dtype
    discs = [
        torch.as_tensor(zero_order_psf(design.lens.aperture_m, design.focal_length_m, z, pixel_pitch_m), dtype=dt)
        .to(dev)
        .unsqueeze(0)
        for z in (psfs.z_near_m, psfs.z_far_m)
    ]
    psfs.zero_order = ZeroOrder(torch.as_tensor(budget.zero_order, dtype=dt, device=dev).reshape(3, 1, 1), *discs)
    return psfs


def estimate_captures(
    design,
    z_near_m: float,
    z_far_m: float,
    wavelengths_m,
    pixel_pitch_m: float,
    pixels: int,
    images: int,
    *,
    window: int | None = None,
    zero_order: bool = False,
) -> tuple[int, float, float]:
    """(peak bytes, seconds of :func:`channel_psfs`, seconds of :func:`simulate_captures`) for
    ``images`` images of ``pixels``² on the sensor, from the PSF plan (``optics.psf.estimate_psf``) and the
    canvas the windows need: each image's canvas holds about a dozen float32 planes of 3 channels
    (scene, obstruction, α, their spectra, the captures) while it is formed, and costs about two
    canvas FFT passes per channel with its obstruction (0.42 s measured for a 1414² canvas against
    0.63 s estimated; ten passes, the old rate, estimated 3.2 s). ``zero_order``: the zero-order
    discs widen the canvas and add four passes (α over the canvas, three disc blurs)."""
    from metalens_cli.optics.blur import psf_window
    from metalens_cli.optics.psf import FFT_RATE, estimate_psf
    from metalens_cli.optics.sampling import PsfGrid
    from metalens_cli.optics.zero_order import zero_order_radius_m

    d = design.focal_length_m
    windows = [
        window or psf_window(design.lens, list(wavelengths_m), [z], d, pixel_pitch_m) for z in (z_near_m, z_far_m)
    ]
    psf = estimate_psf(design.lens, PsfGrid(list(wavelengths_m), [z_near_m, z_far_m], max(windows), pixel_pitch_m, d))
    margin = canvas_margin(*windows)
    if zero_order:
        disc = zero_order_radius_m(design.lens.aperture_m, d, z_near_m)
        margin = max(margin, math.ceil(disc / pixel_pitch_m))
    canvas = pixels + 2 * margin
    planes = 12 * 3 * canvas**2 * 8
    kept = 6 * 3 * pixels**2 * 4 * images
    passes = 2 + (4 if zero_order else 0)
    return (
        psf.memory_bytes + planes + kept,
        psf.seconds,
        images * passes * 3 * canvas**2 * max(math.log2(canvas), 1) / FFT_RATE,
    )


def estimate_capture_runs(
    setup: CaptureSetup,
    what: str,
    depths_m: tuple[float, float],
    images: int,
    *,
    window: int | None = None,
    seeds: int = 1,
    kinds: int = 1,
    field_model: str = "on-axis",
    zero_order: bool = False,
) -> Estimate:
    """The cost of capturing ``images`` images through every design of ``setup`` at ``depths_m``
    (near, far) for each of ``seeds`` seeds and ``kinds`` obstruction kinds (:func:`estimate_captures`):
    the PSFs once per design and seed, the captures per kind too; the memory of the largest
    design. ``what`` names the job; ``window``: :func:`channel_psfs`'s; ``field_model`` "auto" adds
    the field PSF sets where the isoplanatic test asks for them (an upper bound: they may be cached);
    ``zero_order``: the captures image the zero-order light too."""
    costs = [
        estimate_captures(
            design,
            *depths_m,
            setup.wavelengths_m,
            setup.pixel_pitch_m,
            setup.pixels,
            images,
            window=window,
            zero_order=zero_order,
        )
        for design in setup.designs
    ]
    if field_model == "auto":
        for i, design in enumerate(setup.designs):
            if field_dependence(design, setup.pixels, setup.pixel_pitch_m)["field_dependent"]:
                memory, seconds = estimate_field_psfs(
                    design, setup.pixels, setup.pixel_pitch_m, depths_m, setup.wavelengths_m
                )
                costs[i] = (max(costs[i][0], memory), costs[i][1] + seconds, costs[i][2])
    return Estimate(
        what,
        max(memory for memory, _, _ in costs),
        "--psf-pixels" if window else "--pixels",
        seeds * sum(psf + kinds * captures for _, psf, captures in costs),
    )


@dataclass
class SimulatedCapture:
    """Linear (3, H, W) float32 numpy images of one clean image under one obstruction."""

    name: str
    clean: np.ndarray
    obstruction: Obstruction
    unobstructed: np.ndarray
    obstructed: np.ndarray
    alpha: np.ndarray
    seconds: float
    alpha_coverage: float = field(default=0.0)


def simulate_captures(
    images,
    obstruction_spec: str,
    psfs: ChannelPsfs,
    focal_length_m: float,
    pixel_pitch_m: float,
    seed: int,
    *,
    params: ObstructionConfig | None = None,
    formation: str = "physical",
    alpha_gain: float | None = None,
    photons=None,
    read_noise: float = 0.0,
    obstructions: dict | None = None,
    on_progress: Callable[[int, int], None] | None = None,
) -> list[SimulatedCapture]:
    """For each clean image (on a canvas whose margin covers ``psfs.margin``): an obstruction on
    the same canvas (seed + image index), the unobstructed capture P̂_far ∗ I_clean and the
    obstructed capture (``imaging.formation``); noise (if any) seeded the same way.

    Args:
        images: the clean images on their canvases (``imaging.images.load_images``).
        obstruction_spec: the obstruction kind to generate.
        psfs: the design's near and far channel PSFs and their margin.
        focal_length_m: focal length (m), which sizes the obstruction on the cover glass.
        pixel_pitch_m: sensor pixel pitch (m).
        seed: the base seed; image i uses seed + i.
        params: obstruction generator parameters (``[obstruction]``); None: the defaults.
        formation: "physical" or "paper" (:func:`form_image`).
        alpha_gain: as in :func:`form_image`.
        photons: full-well electrons, one count or one per channel R, G, B
            (``imaging.formation.add_noise``); None: no shot noise.
        read_noise: read-noise σ, a fraction of full scale.
        obstructions: a dict shared by calls that differ only in the design (same images, seed
            and depths), so each obstruction is generated once.
        on_progress: ``on_progress(done, total)`` is called before the first image and after each
            one.

    Returns:
        One ``SimulatedCapture`` per image: linear (3, H, W) float32 numpy images (clean,
        unobstructed, obstructed, α), the obstruction and the seconds taken.
    """
    arguments.instance(psfs, "psfs", ChannelPsfs, "ChannelPsfs (channel_psfs)")
    arguments.positive(focal_length_m, "focal_length_m")
    arguments.positive(pixel_pitch_m, "pixel_pitch_m")
    arguments.count(seed, "seed", lo=0)
    captures = []
    report = on_progress or (lambda done, total: None)
    report(0, len(images))
    dev, dt = psfs.near.device, psfs.near.dtype
    counts = (
        torch.as_tensor(np.asarray(photons, dtype=float), dtype=dt, device=dev).reshape(-1, 1, 1)
        if np.ndim(photons)
        else photons
    )
    for index, image in enumerate(images):
        sensor = image.sensor.shape[-2:]
        transforms = _capture_transforms(psfs, tuple(sensor))  # made once, timed apart (field_test)
        start = time.perf_counter()
        key = (obstruction_spec, seed, index, psfs.z_near_m, focal_length_m)
        obstruction = (obstructions or {}).get(key) or make_obstruction(
            obstruction_spec,
            sensor,
            psfs.z_near_m,
            focal_length_m,
            pixel_pitch_m,
            [seed, index],
            params=params,
            clean=image.linear,
            margin=image.margin,
        )
        if obstructions is not None:
            obstructions[key] = obstruction
        form = form_image if psfs.field_psfs is None else form_image_field
        formed = time.perf_counter()
        with torch.no_grad():
            capture = form(
                torch.as_tensor(image.linear, dtype=dt, device=dev),
                torch.as_tensor(obstruction.rgb, dtype=dt, device=dev),
                torch.as_tensor(obstruction.mask, dtype=dt, device=dev),
                *transforms,
                image.margin,
                formation=formation,
                alpha_gain=alpha_gain,
            )
            obstructed, unobstructed = capture.obstructed, capture.unobstructed
            if psfs.zero_order is not None:
                zero = psfs.zero_order
                stray = zero_order_light(
                    torch.as_tensor(image.linear, dtype=dt, device=dev),
                    torch.as_tensor(obstruction.rgb, dtype=dt, device=dev),
                    torch.as_tensor(obstruction.mask, dtype=dt, device=dev),
                    psfs.near,
                    *_zero_order_transforms(psfs, tuple(sensor)),
                    image.margin,
                    formation=formation,
                )
                obstructed, unobstructed = obstructed + zero.scale * stray[0], unobstructed + zero.scale * stray[1]
            if np.any(photons) or read_noise:
                obstructed = add_noise(obstructed, counts, read_noise=read_noise, generator=seed * 1000 + 2 * index)
                unobstructed = add_noise(
                    unobstructed, counts, read_noise=read_noise, generator=seed * 1000 + 2 * index + 1
                )
        alpha = capture.alpha.cpu().numpy().astype(np.float32)
        unobstructed, obstructed = (x.cpu().numpy().astype(np.float32) for x in (unobstructed, obstructed))
        _record_formation(psfs, time.perf_counter() - formed)
        captures.append(
            SimulatedCapture(
                image.name,
                image.sensor,
                obstruction,
                unobstructed,
                obstructed,
                alpha,
                time.perf_counter() - start,
                float(alpha.mean()),
            )
        )
        report(index + 1, len(images))
    return captures


def _record_formation(psfs: ChannelPsfs, seconds: float) -> None:
    """Add one capture's image formation (both captures of an image, noise included; seconds) to
    ``psfs.formation_seconds`` and its count and median to ``psfs.field_test`` (the report)."""
    psfs.formation_seconds.append(seconds)
    if psfs.field_test is not None:
        psfs.field_test["formation"] = {
            "captures": len(psfs.formation_seconds),
            "median_seconds": float(np.median(psfs.formation_seconds)),
        }


def _zero_order_transforms(psfs: ChannelPsfs, sensor: tuple[int, int]) -> tuple:
    """The transforms of the zero-order discs for ``sensor`` images, made once (``psfs.transforms``)."""
    key = ("zero-order", sensor)
    if key not in psfs.transforms:
        psfs.transforms[key] = tuple(
            psf_transform(disc, sensor) for disc in (psfs.zero_order.near, psfs.zero_order.far)
        )
    return psfs.transforms[key]


def _capture_transforms(psfs: ChannelPsfs, sensor: tuple[int, int]) -> tuple:
    """The near and far transforms a capture reuses, made once per sensor size and kept in
    ``psfs.transforms``: of the on-axis PSFs, or of the field PSF sets (``imaging.field_formation``;
    the expansion's measured error, size and cost go into ``psfs.field_test``). A transform whose
    eigen-PSFs would not fit the memory then free is refused before it is built."""
    if sensor in psfs.transforms:
        return psfs.transforms[sensor]
    if psfs.field_psfs is None:
        transforms = tuple(transform(p, sensor) for p in psfs.capture_forms())
    else:
        from metalens_cli.machine import device_memory

        start = time.perf_counter()
        transforms = []
        for s in (psfs.field_psfs.near, psfs.field_psfs.far):
            free = device_memory(s.psfs.device)[0]
            limit = None if free is None else int(0.9 * free)
            transforms.append(field_transform(s, sensor, tolerance=psfs.field_tolerance, max_bytes=limit))
        transforms = tuple(transforms)
        psfs.field_test["expansion"] = {
            which: {
                "error": t.error,
                "tolerance": t.tolerance,
                "eigen_psfs": len(t.term_tile),
                "support_px": t.support,
                "windows_px": {str(side): count for side, count in t.windows.items()},
            }
            for which, t in zip(("near", "far"), transforms)
        }
        psfs.field_test["expansion"]["seconds"] = time.perf_counter() - start
    psfs.transforms[sensor] = transforms
    return transforms


def score(estimate_linear: np.ndarray, clean_linear: np.ndarray, lpips_model=None, match: str = DEFAULT_MATCH) -> dict:
    """PSNR (dB) and SSIM of a capture against the clean image after the global gain/bias
    match (``match``: least squares, or the paper's luminance mean/std match of Suppl. Note 11;
    see ``imaging.metrics``),
    computed on sRGB-encoded images clipped to 0..1 (display values), PSNR capped at 100 dB for
    an exact match (``metrics.reported_psnr``); also ``lpips`` on the same images when
    ``lpips_model`` (:class:`~metalens_cli.imaging.lpips.Lpips`) is given."""
    from metalens_cli.imaging.metrics import photometric_match, psnr, reported_psnr, ssim
    from metalens_cli.io.image_files import linear_to_srgb

    estimate = torch.as_tensor(estimate_linear, dtype=torch.float64)
    clean = torch.as_tensor(clean_linear, dtype=torch.float64)
    matched, gain, bias = photometric_match(estimate, clean, match)
    x = torch.as_tensor(linear_to_srgb(matched.numpy()), dtype=torch.float64)
    y = torch.as_tensor(linear_to_srgb(clean.numpy()), dtype=torch.float64)
    out = {"psnr_db": reported_psnr(psnr(x, y)), "ssim": float(ssim(x, y)), "gain": float(gain), "bias": float(bias)}
    if lpips_model is not None:
        from metalens_cli.imaging.lpips import lpips_distance

        with torch.no_grad():
            out["lpips"] = float(lpips_distance(lpips_model, x, y))
    return out
