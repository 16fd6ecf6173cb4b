"""Training losses of Suppl. Note 4, as pure torch functions (differentiable, batched).

L = w_l1·L1 + w_ssim·(1 − SSIM) + w_da·L_DA  (image terms, capture against clean scene; linear
                                              values, or with ``loss.space = "metric"`` the
                                              evaluation's matched sRGB values)
  + w_bright·L_bright + w_sharp·L_sharp         (PSF terms, far PSF)

The paper writes L_bright = 3N/ΣP − 1 and L_sharp = N/Σ_{|i|,|j|≤2} P(x_c+i, y_c+j) − 1 for a
3-channel far PSF P scaled so that ΣP = 3N when no light leaves the N-pixel sensor. Our PSFs are
fractions of the aperture power (each channel sums to 1 when nothing is lost), i.e. P/N, so
the N cancels: L_bright = 3/ΣP − 1 (0 when every channel keeps all its light) and
L_sharp = 1/Σ_window P − 1 over the central w × w pixels of all channels (w = 5 in the paper);
``loss.sharp_mode = "per_channel"`` averages 1/E_c − 1 over the channels instead, ``"log"`` takes
−mean_c log E_c, ``"log_wavelength"`` −mean_λ log E_λ over the step's wavelength samples, each
monochromatic far PSF's own core, and ``"harmonic_wavelength"`` log mean_λ 1/E_λ (see ``sharp_loss``).
"""

from __future__ import annotations

import torch

from metalens_cli.errors import InputError
from metalens_cli.imaging.metrics import metric_view, ssim
from metalens_cli.io.presets import SHARP_MODES, WAVELENGTH_MODES


def l1_loss(captured: torch.Tensor, clean: torch.Tensor) -> torch.Tensor:
    """Mean absolute difference per batch entry of (..., 3, H, W) images."""
    return (captured - clean).abs().mean(dim=(-3, -2, -1))


def ssim_loss(captured: torch.Tensor, clean: torch.Tensor) -> torch.Tensor:
    """1 − SSIM per batch entry (Gaussian window 11, σ 1.5; images in 0..1)."""
    return 1 - ssim(captured, clean)


def bright_loss(psf_far: torch.Tensor) -> torch.Tensor:
    """3/ΣP − 1 for a (..., 3, N, N) far PSF in fractions of the aperture power."""
    return psf_far.shape[-3] / psf_far.sum(dim=(-3, -2, -1)) - 1


def sharp_loss(
    psf_far: torch.Tensor, window: int = 5, mode: str = "total", cores: torch.Tensor | None = None
) -> torch.Tensor:
    """Energy E_c in the central ``window`` × ``window`` pixels (axis at N//2) of each channel c.

    ``total`` (the paper's): 1/Σ_c E_c − 1, which rewards the channels' sum, so the cheapest
    channel can take all the gain. ``per_channel``: mean_c (1/E_c) − 1 (0 when every channel keeps
    all its light in the window), whose gradient is largest for the weakest channel.
    ``log``: −mean_c log E_c, the same balance between channels with gradient −1/(3E_c) instead
    of −1/(3E_c²): at E_c of a few per cent, 20-50× closer to the image terms' scale.
    ``log_wavelength``: −mean_λ log E_λ over ``cores`` (W,), each wavelength sample's energy in its
    own central window (``optics.channel_psf``): a lens cannot raise the mean of E_λ over the
    spectrum (docs/training.md), and for a given mean this is lowest when E_λ is flat.
    ``harmonic_wavelength``: log mean_λ (1/E_λ), minus the log of the harmonic mean: its gradient
    weighs each wavelength by (1/E_λ²) / Σ_μ (1/E_μ), so the weakest wavelengths steer most, while
    the scale stays that of a logarithm (a flat E_λ = E gives −log E, as ``log_wavelength`` does).
    """
    if mode in WAVELENGTH_MODES:
        if cores is None:
            raise InputError(
                "loss.sharp_mode",
                f"{mode} needs each wavelength's core energy",
                "cores from optics.channel_psf_stack(..., core_window=k)",
            )
        if mode == "log_wavelength":
            return -torch.log(cores).mean(dim=-1)
        return torch.log((1 / cores).mean(dim=-1))
    n0, n1 = psf_far.shape[-2:]
    lo0, lo1 = n0 // 2 - window // 2, n1 // 2 - window // 2
    core = psf_far[..., lo0 : lo0 + window, lo1 : lo1 + window].sum(dim=(-2, -1))
    if mode == "total":
        return 1 / core.sum(dim=-1) - 1
    if mode == "per_channel":
        return (1 / core).mean(dim=-1) - 1
    if mode == "log":
        return -torch.log(core).mean(dim=-1)
    raise InputError("loss.sharp_mode", f"unknown mode {mode!r}", ", ".join(SHARP_MODES))


def training_loss(
    captured: torch.Tensor,
    clean: torch.Tensor,
    psf_far: torch.Tensor,
    weights,
    features=None,
    image_share: float = 1.0,
    psf_share: float = 1.0,
    cores_far: torch.Tensor | None = None,
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """Weighted total and its parts (each a scalar: image terms averaged over the batch).

    ``weights``: a ``LossConfig``. ``features``: a DeepLabv3+ feature extractor for L_DA, or None.
    ``image_share``/``psf_share`` scale the image and PSF terms in the total only (data-parallel
    ranks: the local fraction of the global batch, and 1/world size), never the reported parts.
    ``cores_far``: each wavelength's far core energy (the ``WAVELENGTH_MODES`` of ``sharp_mode``).
    With ``weights.space = "metric"`` the image terms compare what the evaluation scores
    (``imaging.metrics.metric_view``: the capture matched to the scene by least squares, both
    sRGB-encoded): 1 − SSIM is then 1 − the evaluation's SSIM of the capture.
    """
    if weights.space == "metric":
        captured, clean = metric_view(captured, clean)
    parts = {"l1": l1_loss(captured, clean).mean(), "ssim": ssim_loss(captured, clean).mean()}
    if features is not None:
        from metalens_cli.design.features import feature_l1

        parts["domain_adaptation"] = feature_l1(features, captured, clean)
    parts["bright"] = bright_loss(psf_far)
    parts["sharp"] = sharp_loss(psf_far, weights.sharp_window, weights.sharp_mode, cores_far)
    image, psf = weighted_terms(parts, weights)
    parts["total"] = image + psf
    return image_share * image + psf_share * psf, parts


def weighted_terms(parts: dict, weights) -> tuple:
    """(image, PSF): the weighted sums of the image terms (L1, 1 − SSIM, L_DA when present) and of
    the PSF terms (L_bright, L_sharp) of ``parts`` (tensors or floats), ``weights`` a ``LossConfig``."""
    image = weights.l1 * parts["l1"] + weights.ssim * parts["ssim"]
    if "domain_adaptation" in parts:
        image = image + weights.domain_adaptation * parts["domain_adaptation"]
    return image, weights.bright * parts["bright"] + weights.sharp * parts["sharp"]


def weighted_total(parts: dict, weights, band_filter=None) -> float:
    """A step's reported total: its weighted image and PSF terms (:func:`weighted_terms`) and, for
    a filter learned with θ (``band_filter``, a ``FilterConfig``), its split and light penalties."""
    image, psf = weighted_terms(parts, weights)
    total = image + psf
    if band_filter is not None and "split" in parts:
        total = total + band_filter.split_weight * parts["split"] + band_filter.light_weight * parts["light"]
    return total
