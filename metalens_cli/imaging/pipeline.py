"""From a design to captures: channel PSFs at the near and far depths, then image formation.

Shared by ``metalens simulate`` and ``metalens evaluate`` (and usable from Python). Depths are
drawn once per run from the configured intervals with the run's seed.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch

from metalens_cli.imaging.formation import form_image, add_noise, psf_spectrum, normalize_psf
from metalens_cli.imaging.obstructions import Obstruction, make_obstruction
from metalens_cli.io.presets import ObstructionConfig

DEFAULT_Z_NEAR_M = (0.040, 0.050)  # PHYSICS.md, Suppl. Note 4
DEFAULT_Z_FAR_M = (1.0, 20.0)
DEFAULT_WAVELENGTHS = "400:700:5nm"


@dataclass
class ChannelPsfs:
    """R, G, B PSFs (torch, (3, N, N)) at the near and far depths, and their window energies."""

    near: torch.Tensor
    far: torch.Tensor
    z_near_m: float
    z_far_m: float
    energy_near: list[float]
    energy_far: list[float]
    coverage: list[float]
    seconds: float


def draw_depths(z_near_m: tuple[float, float], z_far_m: tuple[float, float], seed: int) -> tuple[float, float]:
    """One near and one far depth, uniform in their intervals (a single length: that length)."""
    rng = np.random.default_rng([seed, 1])
    return float(rng.uniform(*z_near_m)), float(rng.uniform(*z_far_m))


def channel_weights(design, wavelengths_m):
    """(3, W) R, G, B quadrature weights: the preset's S^c, or the default camera without a filter."""
    from metalens_cli.optics.spectra import camera_response, preset_sensitivity, quadrature_weights, spectral_sensitivity, wavelength_grid

    if design.preset is not None:
        sensitivity = preset_sensitivity(design.preset)
    else:
        grid = wavelength_grid()
        sensitivity = spectral_sensitivity(grid, camera_response(grid))
    return quadrature_weights(sensitivity, np.asarray(wavelengths_m, dtype=float))


def channel_psfs(design, z_near_m: float, z_far_m: float, wavelengths_m, pixels: int, pixel_pitch_m: float,
                 normalization: str = "aperture", dtype=torch.float32, device="cpu") -> ChannelPsfs:
    """Monochromatic PSFs at both depths in one ``compute_psf`` call, mixed into R, G, B."""
    from metalens_cli.optics.psf import compute_psf
    from metalens_cli.optics.spectra import mix_channels

    start = time.perf_counter()
    weights = channel_weights(design, wavelengths_m)
    result = compute_psf(design.lens, list(wavelengths_m), [z_near_m, z_far_m], pixels, pixel_pitch_m,
                         design.focal_length_m, "auto", dtype, device)
    rgb = normalize_psf(mix_channels(result.psf, weights.weights), normalization)
    energy = rgb.detach().sum(dim=(-2, -1)).cpu().tolist()
    return ChannelPsfs(rgb[0], rgb[1], z_near_m, z_far_m, energy[0], energy[1], [float(c) for c in weights.coverage],
                       time.perf_counter() - start)


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


def simulate_captures(images, obstruction_spec: str, psfs: ChannelPsfs, focal_length_m: float, pixel_pitch_m: float,
                      seed: int, params: ObstructionConfig | None = None, alpha_gain: float | None = None,
                      photons: float | None = None, read_noise: float = 0.0) -> list[SimulatedCapture]:
    """For each clean image: an obstruction (seed + image index), the unobstructed capture
    P_far ∗ I_clean and the obstructed capture; noise (if any) seeded the same way."""
    captures = []
    spectra = None
    for index, image in enumerate(images):
        start = time.perf_counter()
        shape = image.linear.shape[-2:]
        obstruction = make_obstruction(obstruction_spec, shape, psfs.z_near_m, focal_length_m, pixel_pitch_m,
                                       [seed, index], params, clean=image.linear)
        dev, dt = psfs.near.device, psfs.near.dtype
        if spectra is None or spectra[0].image_hw != tuple(shape):
            spectra = (psf_spectrum(psfs.near, tuple(shape)), psf_spectrum(psfs.far, tuple(shape)))
        with torch.no_grad():
            capture = form_image(torch.as_tensor(image.linear, dtype=dt, device=dev),
                                 torch.as_tensor(obstruction.rgb, dtype=dt, device=dev),
                                 torch.as_tensor(obstruction.mask, dtype=dt, device=dev), spectra[0], spectra[1], alpha_gain)
            obstructed, unobstructed = capture.image, capture.unobstructed
            if photons or read_noise:
                obstructed = add_noise(obstructed, photons, read_noise, seed * 1000 + 2 * index)
                unobstructed = add_noise(unobstructed, photons, read_noise, seed * 1000 + 2 * index + 1)
        alpha = capture.alpha.cpu().numpy().astype(np.float32)
        captures.append(SimulatedCapture(image.name, image.linear, obstruction, unobstructed.cpu().numpy().astype(np.float32),
                                         obstructed.cpu().numpy().astype(np.float32), alpha, time.perf_counter() - start,
                                         float(alpha.mean())))
    return captures


def score(estimate_linear: np.ndarray, clean_linear: np.ndarray, lpips_model=None) -> dict:
    """PSNR (dB) and SSIM of a capture against the clean image after the global gain/bias
    match (Suppl. Note 11), computed on sRGB-encoded images clipped to 0..1 (display values);
    also ``lpips`` on the same images when ``lpips_model`` (:class:`~metalens_cli.imaging.lpips.Lpips`) is given."""
    from metalens_cli.imaging.images import linear_to_srgb
    from metalens_cli.imaging.metrics import photometric_match, psnr, ssim

    estimate = torch.as_tensor(estimate_linear, dtype=torch.float64)
    clean = torch.as_tensor(clean_linear, dtype=torch.float64)
    matched, gain, bias = photometric_match(estimate, clean)
    x = torch.as_tensor(linear_to_srgb(matched.numpy()), dtype=torch.float64)
    y = torch.as_tensor(linear_to_srgb(clean.numpy()), dtype=torch.float64)
    out = {"psnr_db": float(psnr(x, y)), "ssim": float(ssim(x, y)), "gain": float(gain), "bias": float(bias)}
    if lpips_model is not None:
        from metalens_cli.imaging.lpips import lpips_distance

        with torch.no_grad():
            out["lpips"] = float(lpips_distance(lpips_model, x, y))
    return out
