"""Image metrics: PSNR, SSIM and the global gain/bias photometric match (Suppl. Note 11).

Torch functions on (..., C, H, W) images with values nominally in 0..1 (``data_range`` 1);
differentiable (SSIM is used as a loss by ``optimize``). Means are over channels and pixels.
The photometric match maps an estimate onto its reference with one gain a and bias b per image,
the same for every channel: by default (``lstsq``) by least squares over all pixels and
channels; or (``luminance``, the paper's Suppl. Note 11) from the mean and standard deviation
of the Rec. 709 luminance Y = 0.2126 R + 0.7152 G + 0.0722 B of linear RGB.

Why least squares by default: it is the best global exposure and black level for the estimate,
so an obstruction drawn independently of the scene cannot lower the expected (linear) error —
the obstructed capture (1 − α)·U + L averages, over the obstruction's placement, to an affine
function of U plus a non-negative variance. The luminance match stretches a blurred capture's
contrast to the scene's whatever the capture holds: its gain exceeds the least-squares one by
1/ρ (ρ: the capture's correlation with the scene), so halo, colour offsets (each channel's
offset from the luminance mean) and the obstruction's own pattern are amplified with the
scene, and an obstruction moves those amplified errors by chance in either direction
(docs/images.md, "the fence that helps").
LPIPS (:mod:`metalens_cli.imaging.lpips`) needs network weights that this package does not ship;
:func:`lpips_note` says why it is skipped when they are not present locally.
"""

from __future__ import annotations

import torch

from metalens_cli import arguments
from metalens_cli.errors import InputError
from metalens_cli.imaging.images import LUMA_709

SSIM_WINDOW, SSIM_SIGMA, SSIM_K1, SSIM_K2 = 11, 1.5, 0.01, 0.03  # Wang et al. 2004
MATCH_METHODS = ("lstsq", "luminance")
DEFAULT_MATCH = "lstsq"
PSNR_CEILING_DB = 100.0  # an exact match: MSE 0 (see reported_psnr)


def psnr(estimate: torch.Tensor, reference: torch.Tensor, *, data_range: float = 1.0) -> torch.Tensor:
    """10·log10(range² / MSE) in dB, per leading batch entry (the MSE over the last three axes,
    never pooled over the batch): scikit-image's ``peak_signal_noise_ratio`` of each image.

    Args:
        estimate: images, finite.
        reference: images of the same shape, finite.
        data_range: the images' full scale (1 for images in 0..1), positive.

    Returns:
        PSNR in dB per image (inf for an exact match).

    Shape:
        - Input: :math:`(..., C, H, W)` both.
        - Output: :math:`(...)`

    Examples:
        >>> import torch
        >>> reference = torch.full((2, 3, 4, 4), 0.5, dtype=torch.float64)
        >>> estimate = reference.clone()
        >>> estimate[0] += 0.1
        >>> estimate[1] += 0.01
        >>> [round(v, 4) for v in psnr(estimate, reference).tolist()]
        [20.0, 40.0]
    """
    _check_pair(estimate, reference, data_range)
    mse = ((estimate - reference) ** 2).mean(dim=(-3, -2, -1))
    return 10 * torch.log10(data_range**2 / mse)


def _check_pair(estimate, reference, data_range) -> None:
    """Two image tensors (..., C, H, W) of one shape, finite, and a positive data range."""
    for name, image in (("estimate", estimate), ("reference", reference)):
        arguments.instance(image, name, torch.Tensor, "an image tensor (..., C, H, W)")
        arguments.array(image, name, ndim=tuple(range(3, 9)), form="an image tensor (..., C, H, W)")
    arguments.same_shape(estimate, reference, ("estimate", "reference"))
    arguments.positive(data_range, "data_range", unit="the images' full scale")


def gaussian_window(
    size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA, dtype=torch.float64, device="cpu"
) -> torch.Tensor:
    """Normalised 1-D Gaussian of ``size`` taps."""
    x = torch.arange(size, dtype=dtype, device=device) - (size - 1) / 2
    g = torch.exp(-(x**2) / (2 * sigma**2))
    return g / g.sum()


def _filter(x: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
    """Separable 'valid' Gaussian filtering of (B, C, H, W), each channel on its own."""
    c = x.shape[1]
    x = torch.nn.functional.conv2d(x, g.view(1, 1, -1, 1).expand(c, 1, -1, 1), groups=c)
    return torch.nn.functional.conv2d(x, g.view(1, 1, 1, -1).expand(c, 1, 1, -1), groups=c)


def ssim(
    estimate: torch.Tensor,
    reference: torch.Tensor,
    *,
    data_range: float = 1.0,
    window: int = SSIM_WINDOW,
    sigma: float = SSIM_SIGMA,
) -> torch.Tensor:
    """Mean SSIM (Wang et al. 2004: Gaussian window 11 taps, σ 1.5, K1 0.01, K2 0.03, population
    covariances), over 'valid' window positions (no padding) and channels; one value per leading
    batch entry.

    With the default window it equals scikit-image's ``structural_similarity(x, y,
    gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=data_range,
    channel_axis=0)`` to round-off (tests/imaging/test_metrics.py).

    Args:
        estimate: images, finite, at least ``window`` pixels on each side.
        reference: images of the same shape, finite.
        data_range: the images' full scale (1 for images in 0..1), positive.
        window: Gaussian window taps.
        sigma: Gaussian window σ (pixels).

    Returns:
        Mean SSIM per image (1 for identical images).

    Shape:
        - Input: :math:`(..., C, H, W)` both.
        - Output: :math:`(...)`

    Examples:
        >>> import torch
        >>> x = torch.rand(1, 3, 16, 16, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
        >>> [round(v, 6) for v in ssim(x, x).tolist()]
        [1.0]
    """
    _check_pair(estimate, reference, data_range)
    arguments.count(window, "window")
    arguments.positive(sigma, "sigma", unit="pixels")
    if min(estimate.shape[-2:]) < window:
        raise InputError("estimate", f"{tuple(estimate.shape[-2:])} pixels", f"images at least {window} × {window}")
    lead = estimate.shape[:-3]
    x = estimate.reshape(-1, *estimate.shape[-3:])
    y = reference.reshape(-1, *reference.shape[-3:]).to(x.dtype)
    g = gaussian_window(window, sigma, x.dtype, x.device)
    c1, c2 = (SSIM_K1 * data_range) ** 2, (SSIM_K2 * data_range) ** 2
    # the five local moments in one grouped convolution per axis (3-4× faster than five)
    mx, my, mxx, myy, mxy = _filter(torch.cat([x, y, x * x, y * y, x * y], dim=1), g).chunk(5, dim=1)
    sxx, syy, sxy = mxx - mx * mx, myy - my * my, mxy - mx * my
    s = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
    return s.mean(dim=(-3, -2, -1)).reshape(lead)


def photometric_match(estimate: torch.Tensor, reference: torch.Tensor, method: str = "luminance"):
    """A global gain a and bias b per leading batch entry; returns (a·estimate + b, a, b), with a
    and b of shape ``estimate.shape[:-3]``, applied to every channel.

    ``luminance`` (Suppl. Note 11; RGB images): a = σ_Y(reference)/σ_Y(estimate) and
    b = μ_Y(reference) − a·μ_Y(estimate) over the pixels of Y = 0.2126 R + 0.7152 G + 0.0722 B.
    ``lstsq``: a and b minimising ‖a·estimate + b − reference‖² over all pixels and channels.
    Degenerate cases (σ at round-off: ≤ 64 ε·max |value|): a flat estimate gets a = 0,
    b = μ(reference); a flat reference (a uniform grey wall) gets the exposure only,
    a = μ(reference)/μ(estimate), b = 0 (a = 0 for a black estimate), since a free gain would
    flatten whatever the estimate shows, an obstruction included, into a perfect match.
    """
    dims = (-3, -2, -1)
    if method == "luminance":
        if estimate.shape[-3] != 3 or reference.shape[-3] != 3:
            raise InputError(
                "photometric match",
                f"{estimate.shape[-3]} and {reference.shape[-3]} channels",
                "RGB images (3 channels) for the luminance match",
            )
        w = torch.tensor(LUMA_709, dtype=estimate.dtype, device=estimate.device).view(3, 1, 1)
        x, y = (estimate * w).sum(-3, keepdim=True), (reference * w).sum(-3, keepdim=True)
    elif method == "lstsq":
        x, y = estimate, reference
    else:
        raise InputError("photometric match", repr(method), " or ".join(MATCH_METHODS))
    mx, my = x.mean(dim=dims, keepdim=True), y.mean(dim=dims, keepdim=True)
    dx, dy = x - mx, y - my
    sx, sy = (dx * dx).mean(dim=dims, keepdim=True).sqrt(), (dy * dy).mean(dim=dims, keepdim=True).sqrt()
    eps = 64 * torch.finfo(sx.dtype).eps
    flat_x, flat_y = sx <= eps * x.abs().amax(dim=dims, keepdim=True), sy <= eps * y.abs().amax(dim=dims, keepdim=True)
    safe_sx = torch.where(flat_x, torch.ones_like(sx), sx)
    gain = sy / safe_sx if method == "luminance" else (dx * dy).mean(dim=dims, keepdim=True) / safe_sx**2
    gain = torch.where(flat_x, torch.zeros_like(gain), gain)
    bias = my - gain * mx
    exposure = torch.where(mx > 0, my / torch.where(mx > 0, mx, torch.ones_like(mx)), torch.zeros_like(mx))
    gain, bias = torch.where(flat_y, exposure, gain), torch.where(flat_y, torch.zeros_like(bias), bias)
    return gain * estimate + bias, gain.reshape(estimate.shape[:-3]), bias.reshape(estimate.shape[:-3])


def metric_view(estimate: torch.Tensor, reference: torch.Tensor, match: str = DEFAULT_MATCH):
    """The images the evaluation scores (``imaging.pipeline.score``): ``estimate`` matched to
    ``reference`` (:func:`photometric_match`), both clipped to 0..1 and sRGB-encoded; differentiable
    (zero gradient where a value is clipped), so a training loss on them is the metric.

    Args:
        estimate: linear RGB (..., 3, H, W), e.g. a capture.
        reference: the clean linear image, same shape.
        match: ``lstsq`` or ``luminance`` (:data:`MATCH_METHODS`).

    Returns:
        (estimate, reference) in sRGB display values 0..1.
    """
    from metalens_cli.io.image_files import srgb_encode_tensor

    matched = photometric_match(estimate, reference, match)[0]
    return srgb_encode_tensor(matched.clamp(0, 1)), srgb_encode_tensor(reference.clamp(0, 1))


def lpips_note(directory=None) -> str | None:
    """None when LPIPS weights are present locally; else the one-line reason it is skipped
    (see :func:`metalens_cli.imaging.lpips.find_lpips_weights`)."""
    from metalens_cli.imaging.lpips import find_lpips_weights

    return find_lpips_weights(directory)[1]


def reported_psnr(value: float) -> float:
    """PSNR for reports and statistics: capped at ``PSNR_CEILING_DB``, which an estimate equal
    to its reference (MSE 0, PSNR +∞: a uniform grey wall imaged as uniform grey) reaches. It
    lies above real differences: a 16-bit image off by one code everywhere scores 96.3 dB."""
    return min(float(value), PSNR_CEILING_DB)
