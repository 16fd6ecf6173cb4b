"""Fixed validation draws of a run: its loss, and what steers θ (each term's gradient over draws).

The draws are those of training steps no run takes (``VALIDATION_STEP`` on), each with the whole
batch and the run's camera (``design.training_camera``), and θ before and after training are
scored on the same scenes (:func:`validation_losses`, whatever their PSF windows): the difference
measures progress without sampling noise.

What steers θ. Under Adam each parameter moves by its gradient's running mean over the root of its
running mean square, so a term steers a parameter when its gradient points the same way from draw
to draw, whatever its size: its signal-to-noise ratio μ/σ over draws, not its norm. From D draws
g_1 … g_D of a term's gradient, with mean m_i and unbiased variance s_i² per parameter i,

    SNR²_i ≈ (D − 3)/(D − 1) · m_i²/s_i² − 1/D

is unbiased for μ_i²/σ_i² when the draws are Gaussian (D > 3): E[m_i²] = μ_i² + σ_i²/D, m_i and
s_i² are independent, and E[1/s_i²] = (D − 1)/((D − 3)·σ_i²). Summaries over the parameters: the
root of the mean SNR²_i (``rms_snr``, its square unbiased for the mean of μ²/σ²), the median of
√max(SNR²_i, 0) (``median_snr``) and the share of parameters with SNR²_i > 1. The cosine between
the image terms' and the PSF terms' mean gradients says whether they pull θ the same way.
"""

from __future__ import annotations

import math

import torch

from metalens_cli.design.losses import training_loss
from metalens_cli.design.step import (
    camera_capture,
    draw_step,
    far_cores,
    image_pool,
    plan_windows,
    psf_scales,
    sensor_psf,
    spectral_source,
    step_batch,
    step_psfs,
)
from metalens_cli.design.training_camera import training_camera
from metalens_cli.imaging.canvas import narrow_margin, sensor_crop
from metalens_cli.imaging.formation import psf_margin

VALIDATION_STEP = 10**9  # draws for the fixed validation loss start here, far from any training step
GRADIENT_TERMS = ("l1", "ssim", "domain_adaptation", "bright", "sharp")
IMAGE_TERMS, PSF_TERMS = ("l1", "ssim", "domain_adaptation"), ("bright", "sharp")
STEERING_DRAWS = 8  # draws of the steering measure at the start and the end of a run (D > 3)
MAX_STEERING_PARAMETERS = 10_000_000  # above this (a 2-D θ), the per-draw gradients are not kept


def validation_parts(model, preset, draws: int, device, frequency: float | None, features=None):
    """For each of the ``draws`` fixed validation draws (step numbers no training step uses):
    the weighted loss and its parts on the whole batch (``design.losses.training_loss``)."""
    for (parts,) in _validation_draws([(model, preset)], draws, device, frequency, features):
        yield parts


def _validation_draws(designs, draws: int, device, frequency: float | None, features=None):
    """For each of the ``draws`` validation draws, the loss parts of each (model, preset) of
    ``designs`` on one batch: drawn on the canvas of the largest margin their PSFs need and cropped
    to each design's (``imaging.canvas.narrow_margin``), so that designs whose windows differ (a
    run's θ before and after training) are scored on the same scenes, whatever their windows."""
    first = designs[0][1]
    if any(_scenes_of(preset) != _scenes_of(first) for _, preset in designs):
        raise ValueError("designs validated on the same scenes need the same seed and the same scene settings")
    o = first.optimize
    states = []
    for model, preset in designs:
        sensitivity = spectral_source(preset)
        states.append([model, preset, sensitivity, plan_windows(preset, sensitivity)])
    pool = image_pool(first, states[0][3].margin(psf_scales(first)))
    cameras = [training_camera(preset) for _, preset in designs]
    for k in range(draws):
        step = VALIDATION_STEP + k
        formed = []
        for state in states:
            model, preset, sensitivity, windows = state
            draw = draw_step(preset, sensitivity, o.seed, step)
            stack, state[3] = step_psfs(model.lens(), preset, draw, windows, device, frequency=frequency)
            formed.append((draw, stack, psf_margin(*stack.psfs)))
        reach = max(margin for *_, margin in formed)
        batch = step_batch(first, o.seed, step, list(range(o.batch_size)), formed[0][0].z_near_m, pool, reach, device)
        parts = []
        for (_, preset, _, _), camera, (draw, stack, margin) in zip(states, cameras, formed):
            clean, colour, mask = (narrow_margin(x, reach, margin) for x in batch)
            near, far = stack.psfs
            capture = camera_capture(clean, colour, mask, near, far, margin, camera, draw, o.seed, step, [0])
            parts.append(
                training_loss(
                    capture,
                    sensor_crop(clean, margin),
                    sensor_psf(far, preset),
                    preset.loss,
                    features,
                    cores_far=far_cores(stack),
                )
            )
        yield parts


def _scenes_of(preset) -> tuple:
    """What a step's batch is drawn from (``design.step.step_batch``), but for its margin."""
    o = preset.optimize
    grid = (o.scene_blocks, o.halo_scale, o.core_pixels)
    return (o.seed, o.batch_size, o.obstructions, o.images, grid, preset.sensor, preset.scene, preset.obstruction)


def term_gradients(model, preset, draws: int, device="cpu", frequency: float | None = None, features=None):
    """For each of the ``draws`` validation draws: {term: ∂(w_t·L_t)/∂c}, c the optimiser's
    parameters flattened into one float64 vector (P,) (a term weighted 0 gives zeros)."""
    w = preset.loss
    params = [p for p in model.parameters() if p.requires_grad]
    for _, parts in validation_parts(model, preset, draws, device, frequency, features):
        terms = [t for t in GRADIENT_TERMS if t in parts]
        gradients = {}
        for i, t in enumerate(terms):
            grads = torch.autograd.grad(
                getattr(w, t) * parts[t], params, retain_graph=i < len(terms) - 1, allow_unused=True
            )
            gradients[t] = torch.cat(
                [(torch.zeros_like(p) if g is None else g).detach().double().reshape(-1) for p, g in zip(params, grads)]
            ).cpu()
        yield gradients


def term_gradient_norms(
    model, preset, draws: int = 4, device="cpu", frequency: float | None = None, features=None
) -> dict[str, float]:
    """‖∂(w_t·L_t)/∂c‖₂ for each weighted loss term t, mean over the ``draws`` fixed validation
    draws (the whole batch each): how large each term's pull on θ is (docs/training.md)."""
    sums: dict[str, float] = {}
    for gradients in term_gradients(model, preset, draws, device, frequency, features):
        for t, g in gradients.items():
            sums[t] = sums.get(t, 0.0) + float(g.norm()) / draws
    return sums


def snr_summary(samples: torch.Tensor) -> dict:
    """Signal-to-noise summaries of ``samples`` (D, P): D draws of a gradient of P parameters
    (module docstring). Returns ``mean_snr2`` (the unbiased mean of SNR²_i, which may be negative
    by chance), ``rms_snr``, ``median_snr``, ``share_above_1`` (of parameters with
    SNR² > 1; parameters whose gradient never varies are left out) and ``mean_norm`` (the mean of
    the draws' L2 norms)."""
    d = samples.shape[0]
    if d <= 3:
        raise ValueError(f"the SNR estimate needs more than 3 draws, got {d}")
    x = samples.double()
    m, s2 = x.mean(dim=0), x.var(dim=0, unbiased=True)
    varying = s2 > 0
    if not bool(varying.any()):
        nothing = {"mean_snr2": None, "rms_snr": None, "median_snr": None, "share_above_1": None}
        return {**nothing, "mean_norm": float(x.norm(dim=1).mean())}
    snr2 = (d - 3) / (d - 1) * m[varying] ** 2 / s2[varying] - 1 / d
    return {
        "mean_snr2": float(snr2.mean()),
        "rms_snr": math.sqrt(max(float(snr2.mean()), 0.0)),
        "median_snr": float(snr2.clamp_min(0).sqrt().median()),
        "share_above_1": float((snr2 > 1).double().mean()),
        "mean_norm": float(x.norm(dim=1).mean()),
    }


def cosine(a: torch.Tensor, b: torch.Tensor) -> float | None:
    """cos ∠(a, b) of two vectors; None when either is zero."""
    na, nb = float(a.norm()), float(b.norm())
    return None if na == 0 or nb == 0 else float(a @ b) / (na * nb)


def steering(
    model, preset, draws: int = STEERING_DRAWS, device="cpu", frequency: float | None = None, features=None
) -> dict:
    """What steers θ at ``model``'s lens over ``draws`` validation draws (module docstring): per
    weighted term and for the image and PSF terms' sums, :func:`snr_summary`; the cosine between
    the image and PSF sums' mean gradients; the parameter count. A θ with more than
    ``MAX_STEERING_PARAMETERS`` parameters is not measured (``{"parameters": P, "skipped": why}``)."""
    count = sum(p.numel() for p in model.parameters() if p.requires_grad)
    if count > MAX_STEERING_PARAMETERS:
        return {"parameters": count, "skipped": f"{count} parameters: the per-draw gradients would not fit"}
    samples: dict[str, list[torch.Tensor]] = {}
    for gradients in term_gradients(model, preset, draws, device, frequency, features):
        for t, g in gradients.items():
            samples.setdefault(t, []).append(g)
        for group, terms in (("image", IMAGE_TERMS), ("psf", PSF_TERMS)):
            present = [gradients[t] for t in terms if t in gradients]
            samples.setdefault(group, []).append(torch.stack(present).sum(dim=0))
    stacked = {t: torch.stack(v) for t, v in samples.items()}
    return {
        "draws": draws,
        "parameters": count,
        "terms": {t: snr_summary(v) for t, v in stacked.items()},
        "cosine_image_psf": cosine(stacked["image"].mean(dim=0), stacked["psf"].mean(dim=0)),
    }


def validation_loss(model, preset, draws: int = 4, device="cpu", frequency: float | None = None) -> float:
    """Mean weighted loss (without L_DA) over ``draws`` fixed draws that training never uses, the
    scenes drawn on the canvas ``model``'s PSFs need (:func:`validation_losses` compares designs on
    the same scenes)."""
    return validation_losses([(model, preset)], draws, device, frequency)[0]


def validation_losses(designs, draws: int = 4, device="cpu", frequency: float | None = None) -> list[float]:
    """:func:`validation_loss` of each (model, preset) of ``designs`` on the same scenes (drawn on
    the canvas of the largest margin any of them needs): a run's θ before and after training,
    whose PSF windows differ, compared on one set of scenes."""
    with torch.no_grad():
        totals = [
            [float(total) for total, _ in parts] for parts in _validation_draws(designs, draws, device, frequency)
        ]
    return [sum(column) / len(column) for column in zip(*totals)]


def norms_of(report: dict) -> dict[str, float]:
    """The mean gradient norm of each weighted term in a :func:`steering` report."""
    return {t: v["mean_norm"] for t, v in report.get("terms", {}).items() if t in GRADIENT_TERMS}
