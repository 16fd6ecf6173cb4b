"""Image formation through a lens with a near obstruction (Suppl. Note 4), on a canvas.

Two forms, channel-wise with the R, G, B PSFs, α = m ∗ P̂_near:

- ``physical`` (default): I = P̂_near ∗ (m ⊙ I_obs) + (1 − α) ⊙ (P̂_far ∗ I_clean)
- ``paper`` (the paper's literal form): I = α ⊙ (P̂_near ∗ I_obs) + (1 − α) ⊙ (P̂_far ∗ I_clean)

m is the obstruction's coverage in 0..1 and I_obs its radiance (0 where nothing is). α is the
fraction of the cone of light from a far scene point that the cover blocks, so P̂ is the PSF
normalised to unit sum (its window holds the light: see ``optics.blur``): full opaque coverage
gives α = 1 and no far light. The obstruction's own light in the physical form is premultiplied
(it emits only where it is). The two forms agree where m is 0 or 1 over a whole near blur; they
differ at partial coverage (soft edges, semi-opaque drops, wires thinner than the blur), where
the paper's form spreads the obstruction's full colour with weight α instead of blurring only
the light it emits.

Canvas convention (every function here is pure torch: batched, differentiable, any device):

- Inputs are canvases (..., C, H + 2M, W + 2M): the sensor's H × W field with a margin of M
  pixels of scene (or obstruction) on every side; the output is the central H × W crop. Each
  PSF needs M ≥ N//2 of its N × N window (the axis at pixel (N//2, N//2)), so that no kept pixel
  sees past the canvas; a larger margin is trimmed to what each PSF needs.
- Each convolution is circular on an FFT grid L ≥ its (trimmed) canvas, L the next
  2·3·5·7-smooth size: wrap-around reaches only the margin, never the kept pixels.
- Images are linear radiance; masks (..., 1, H, W) or (..., 3, H, W).

Two-scale PSFs (``optics.two_scale.TwoScalePsf``): the core is convolved on the sensor's grid as
above; the halo on the grid of s × s pixel blocks, the canvas averaged over its blocks, the result
interpolated back bilinearly (block centres at the block's middle pixel). Both parts are divided
by their common sum, so a uniform canvas stays uniform and the light is conserved; with s = 1
this is the single-scale convolution (tests/imaging/test_two_scale_formation.py). Such a PSF
needs a margin of max(K//2, s·(Nc//2 + 2) − 1) pixels (:func:`psf_margin`).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from metalens_cli import arguments
from metalens_cli.errors import InputError
from metalens_cli.optics.propagate import fft_size
from metalens_cli.optics.two_scale import TwoScalePsf, reach

FORMATIONS = ("physical", "paper")


def canvas_margin(*psf_sizes: int) -> int:
    """Margin M (pixels) a canvas needs around the sensor for PSF windows of these sides."""
    return max(n // 2 for n in psf_sizes)


def psf_margin(*psfs) -> int:
    """Margin M (pixels) a canvas needs around the sensor for these PSFs, (..., N, N) tensors or
    :class:`TwoScalePsf` (``optics.two_scale.reach``: the halo's blocks reach s·(Nc//2 + 2) − 1
    pixels, one more block on each side for the interpolation and the sensor's last partial one)."""
    return max(
        reach(p.window, p.scale, p.core_pixels) if isinstance(p, TwoScalePsf) else p.shape[-1] // 2 for p in psfs
    )


def unit_sum(psf: torch.Tensor) -> torch.Tensor:
    """P̂ = P / ΣP over each N × N window (differentiable)."""
    return psf / psf.sum(dim=(-2, -1), keepdim=True).clamp_min(torch.finfo(psf.dtype).tiny)


@dataclass(frozen=True)
class PsfTransform:
    """rfft2 of a unit-sum PSF placed for ``sensor_hw`` images on a canvas of ``margin`` pixels.

    ``spectrum`` (..., C, L0, L1 // 2 + 1) complex on the FFT grid ``fft_shape`` (L0, L1).
    """

    spectrum: torch.Tensor
    sensor_hw: tuple[int, int]
    margin: int
    fft_shape: tuple[int, int]


def psf_transform(psf: torch.Tensor, sensor_hw: tuple[int, int]) -> PsfTransform:
    """Normalise ``psf`` (..., C, N0, N1) to unit sum and transform it for H × W sensor images.

    The axis pixel (N0//2, N1//2) goes to index (0, 0) of the FFT grid (wrapped), so the
    convolution does not shift the image. Precompute once per PSF and reuse.
    """
    if psf.ndim < 3:
        raise InputError("psf", f"shape {tuple(psf.shape)}", "(..., C, N, N) PSFs")
    return kernel_transform(unit_sum(psf), sensor_hw)


def kernel_transform(kernel: torch.Tensor, sensor_hw: tuple[int, int]) -> PsfTransform:
    """:func:`psf_transform` of ``kernel`` (..., C, N0, N1) as it is, not normalised (e.g. a
    zero-sum correction to a PSF)."""
    margin = canvas_margin(*kernel.shape[-2:])
    shape = tuple(fft_size(n + 2 * margin) for n in sensor_hw)
    return PsfTransform(torch.fft.rfft2(_placed(kernel, shape)), tuple(sensor_hw), margin, shape)


def _placed(psf: torch.Tensor, shape: tuple[int, int]) -> torch.Tensor:
    """``psf`` zero-padded to ``shape`` with its axis pixel (N0//2, N1//2) moved to (0, 0)."""
    n0, n1 = psf.shape[-2:]
    padded = psf.new_zeros(*psf.shape[:-2], *shape)
    padded[..., :n0, :n1] = psf
    return torch.roll(padded, shifts=(-(n0 // 2), -(n1 // 2)), dims=(-2, -1))


@dataclass(frozen=True)
class TwoScaleTransform:
    """The transforms of a unit-sum :class:`TwoScalePsf` for H × W sensor images: the core's on
    the sensor's grid, the halo's for the (⌈H/s⌉ + 2) × (⌈W/s⌉ + 2) blocks of s × s pixels about
    the sensor (one block more on each side for the interpolation; s = 1: the sensor's pixels);
    ``margin``: the canvas margin it needs (:func:`psf_margin`)."""

    core: PsfTransform
    halo: PsfTransform
    scale: int
    sensor_hw: tuple[int, int]
    margin: int


def two_scale_transform(psf: TwoScalePsf, sensor_hw: tuple[int, int]) -> TwoScaleTransform:
    """Both parts of ``psf`` divided by its sum (per channel) and transformed for H × W images."""
    total = psf.sum()[..., None, None].clamp_min(torch.finfo(psf.core.dtype).tiny)
    blocks = tuple(sensor_hw) if psf.scale == 1 else tuple(-(-n // psf.scale) + 2 for n in sensor_hw)
    return TwoScaleTransform(
        kernel_transform(psf.core / total, sensor_hw),
        kernel_transform(psf.halo / total, blocks),
        psf.scale,
        tuple(sensor_hw),
        psf_margin(psf),
    )


def transform(psf, sensor_hw: tuple[int, int]) -> PsfTransform | TwoScaleTransform:
    """The transform a capture of H × W sensor images reuses: :func:`psf_transform` of a (..., C, N, N)
    tensor, :func:`two_scale_transform` of a :class:`TwoScalePsf`, a transform as it is (checked)."""
    if isinstance(psf, TwoScalePsf):
        return two_scale_transform(psf, sensor_hw)
    if isinstance(psf, (PsfTransform, TwoScaleTransform)):
        if psf.sensor_hw != tuple(sensor_hw):
            raise InputError(
                "psf",
                f"transform made for {psf.sensor_hw} images, sensor is {tuple(sensor_hw)}",
                "psf_transform(psf, sensor size)",
            )
        return psf
    return psf_transform(psf, sensor_hw)


def _sensor_hw(canvas: torch.Tensor, margin: int) -> tuple[int, int]:
    h, w = (n - 2 * margin for n in canvas.shape[-2:])
    if h < 1 or w < 1:
        raise InputError(
            "canvas", f"{tuple(canvas.shape[-2:])} pixels with margin {margin}", "a canvas larger than twice its margin"
        )
    return h, w


def _canvas_spectrum(canvas: torch.Tensor, margin: int, psf: PsfTransform) -> torch.Tensor:
    """rfft2 of ``canvas`` trimmed to the margin ``psf`` needs, on its FFT grid."""
    if margin < psf.margin:
        raise InputError(
            "canvas margin",
            f"{margin} pixels, the PSF window needs {psf.margin}",
            "a canvas extending past the sensor by N//2 of the PSF window on every side",
        )
    trim = margin - psf.margin
    h, w = psf.sensor_hw
    if trim:
        canvas = canvas[..., trim : trim + h + 2 * psf.margin, trim : trim + w + 2 * psf.margin]
    return torch.fft.rfft2(canvas, s=psf.fft_shape)


def _kept(product: torch.Tensor, psf: PsfTransform) -> torch.Tensor:
    """Inverse transform of ``product`` restricted to the sensor crop (rows first: only the kept rows)."""
    h, w = psf.sensor_hw
    rows = torch.fft.ifft(product, dim=-2)[..., psf.margin : psf.margin + h, :]
    return torch.fft.irfft(rows, n=psf.fft_shape[1], dim=-1)[..., psf.margin : psf.margin + w]


def convolve(canvas: torch.Tensor, psf, margin: int) -> torch.Tensor:
    """The sensor crop of ``canvas`` (..., C, H + 2M, W + 2M) convolved with the unit-sum ``psf``
    (..., C, N, N), a :class:`TwoScalePsf` or their transform; C broadcasts (a 1-channel mask with
    3 PSFs gives 3)."""
    return _blur(canvas, margin, transform(psf, _sensor_hw(canvas, margin)))


def _blur(canvas: torch.Tensor, margin: int, psf: PsfTransform | TwoScaleTransform) -> torch.Tensor:
    """:func:`convolve` with a transform made for this canvas's sensor."""
    if isinstance(psf, PsfTransform):
        return _kept(_canvas_spectrum(canvas, margin, psf) * psf.spectrum, psf)
    if margin < psf.margin:
        raise InputError(
            "canvas margin",
            f"{margin} pixels, the two-scale PSF needs {psf.margin}",
            "a canvas extending past the sensor by imaging.formation.psf_margin(psf) on every side",
        )
    core = _kept(_canvas_spectrum(canvas, margin, psf.core) * psf.core.spectrum, psf.core)
    if psf.scale == 1:
        return core + _kept(_canvas_spectrum(canvas, margin, psf.halo) * psf.halo.spectrum, psf.halo)
    s, extent = psf.scale, psf.halo.margin
    (h, w), (bh, bw) = psf.sensor_hw, psf.halo.sensor_hw
    top = margin - s * (extent + 1)  # block −1 − extent starts here; the sensor starts at block 0
    region = canvas[..., top : top + s * (bh + 2 * extent), top : top + s * (bw + 2 * extent)]
    lead, c = region.shape[:-3], region.shape[-3]
    blocks = torch.nn.functional.avg_pool2d(region.reshape(-1, c, *region.shape[-2:]), s)
    halo = _kept(
        _canvas_spectrum(blocks.reshape(*lead, c, *blocks.shape[-2:]), extent, psf.halo) * psf.halo.spectrum, psf.halo
    )
    c = halo.shape[-3]
    fine = torch.nn.functional.interpolate(
        halo.reshape(-1, c, bh, bw), scale_factor=s, mode="bilinear", align_corners=False
    )  # pixel i of block b at (i + 1/2)/s − 1/2 blocks: the block's centre is its middle pixel
    return core + fine[..., s : s + h, s : s + w].reshape(*halo.shape[:-2], h, w)


def coverage_alpha(blurred_coverage: torch.Tensor, alpha_gain: float | None = None) -> torch.Tensor:
    """α from m ∗ P̂_near, clamped to 0..1 (round-off); with ``alpha_gain`` g the gain-and-clamp
    variant min(g·α, 1) of Shi et al."""
    if alpha_gain is not None:
        arguments.positive(alpha_gain, "alpha_gain", unit="gain")
        blurred_coverage = alpha_gain * blurred_coverage
    return blurred_coverage.clamp(0.0, 1.0)


@dataclass
class Capture:
    """What :func:`form_image` returns, each (..., 3, H, W) on the sensor, linear.

    Attributes:
        obstructed: the capture with the obstruction.
        unobstructed: the capture without it, P̂_far ∗ I_clean.
        obstruction_light: the obstruction term as it enters the capture (P̂_near ∗ (m ⊙ I_obs) in
            the physical form, α ⊙ (P̂_near ∗ I_obs) in the paper's).
        alpha: α = m ∗ P̂_near in 0..1, the fraction of the far light the cover blocks.
    """

    obstructed: torch.Tensor
    unobstructed: torch.Tensor
    obstruction_light: torch.Tensor
    alpha: torch.Tensor


def form_image(
    clean: torch.Tensor,
    obstruction: torch.Tensor,
    mask: torch.Tensor,
    psf_near,
    psf_far,
    margin: int,
    *,
    formation: str = "physical",
    alpha_gain: float | None = None,
) -> Capture:
    """The capture of a scene behind a near obstruction; see the module docstring for both forms.

    Pure torch: batched, differentiable, any device.

    Args:
        clean: the far scene's linear radiance I_clean on a canvas with margin M.
        obstruction: the obstruction's linear radiance I_obs on the same canvas (0 where nothing is).
        mask: its coverage m in 0..1, one or three channels.
        psf_near: R, G, B PSFs at the obstruction's depth, the axis at pixel (N//2, N//2) (any
            normalisation: each is divided by its sum), or a :class:`PsfTransform` (precomputed,
            reused).
        psf_far: likewise at the scene's depth.
        margin: M, pixels of canvas on every side of the sensor's H × W (≥ N//2 of each PSF).
        formation: "physical" or "paper".
        alpha_gain: g for the gain-and-clamp α = min(g·α, 1) of Shi et al.; None: α as is.

    Returns:
        The :class:`Capture` on the sensor's H × W.

    Shape:
        - Input: ``clean``, ``obstruction`` :math:`(..., 3, H + 2M, W + 2M)`, ``mask``
          :math:`(..., 1, H + 2M, W + 2M)` or :math:`(..., 3, H + 2M, W + 2M)`, PSFs :math:`(..., 3, N, N)`
        - Output: each :math:`(..., 3, H, W)`
    """
    check_capture_inputs(clean, obstruction, mask, margin, formation, alpha_gain)
    kinds = (torch.Tensor, PsfTransform, TwoScalePsf, TwoScaleTransform)
    for name, psf in (("psf_near", psf_near), ("psf_far", psf_far)):
        if isinstance(arguments.instance(psf, name, kinds, PSF_FORM), torch.Tensor):
            arguments.array(psf, name, ndim=tuple(range(3, 9)), form=PSF_FORM)
    emitted, mask = _obstruction_canvases(obstruction, mask, formation)
    sensor = _sensor_hw(clean, margin)
    near, far = transform(psf_near, sensor), transform(psf_far, sensor)
    if isinstance(near, TwoScaleTransform) or isinstance(far, TwoScaleTransform):
        planes = (_blur(emitted, margin, near), _blur(mask, margin, near), _blur(clean, margin, far))
        return _composite(*planes, formation, alpha_gain)
    channels = obstruction.shape[-3]
    # one batched transform of [I_obs or m ⊙ I_obs, m]; the mask's spectrum meets each channel's PSF
    f = _canvas_spectrum(torch.cat([emitted, mask], dim=-3), margin, near)
    planes = _kept(
        torch.cat([f[..., :channels, :, :] * near.spectrum, f[..., channels:, :, :] * near.spectrum], dim=-3), near
    )
    near_light, blurred_mask = planes.split(channels, dim=-3)
    unobstructed = _kept(_canvas_spectrum(clean, margin, far) * far.spectrum, far)
    return _composite(near_light, blurred_mask, unobstructed, formation, alpha_gain)


PSF_FORM = "PSFs (..., C, N, N) as a tensor or a TwoScalePsf, or their transform"
CANVAS_FORM = "a (..., C, H + 2M, W + 2M) tensor"


def check_formation(formation: str) -> None:
    """One of :data:`FORMATIONS`."""
    if formation not in FORMATIONS:
        raise InputError("formation", f"unknown form {formation!r}", " or ".join(FORMATIONS))


def check_capture_inputs(clean, obstruction, mask, margin: int, formation: str, alpha_gain) -> None:
    """The canvases (finite tensors), margin, form and α gain of a capture (:func:`form_image`,
    ``field_formation.form_image_field``), each error naming its parameter."""
    for name, canvas in (("clean", clean), ("obstruction", obstruction), ("mask", mask)):
        arguments.instance(canvas, name, torch.Tensor, CANVAS_FORM)
        arguments.array(canvas, name, ndim=tuple(range(3, 9)), form=CANVAS_FORM)
    arguments.count(margin, "margin", lo=0)
    check_formation(formation)
    if alpha_gain is not None:
        arguments.positive(alpha_gain, "alpha_gain", unit="gain")


def _obstruction_canvases(
    obstruction: torch.Tensor, mask: torch.Tensor, formation: str
) -> tuple[torch.Tensor, torch.Tensor]:
    """The obstruction light that the near PSF blurs (m ⊙ I_obs, or I_obs in the paper's form) and m."""
    check_formation(formation)
    mask = mask.to(obstruction.dtype)
    return (obstruction * mask if formation == "physical" else obstruction), mask


def _composite(
    near_light: torch.Tensor,
    blurred_mask: torch.Tensor,
    unobstructed: torch.Tensor,
    formation: str,
    alpha_gain: float | None,
) -> Capture:
    """The capture from the blurred obstruction light, m ∗ P̂_near and P̂_far ∗ I_clean."""
    alpha = coverage_alpha(blurred_mask, alpha_gain)
    obstruction_light = near_light if formation == "physical" else alpha * near_light
    return Capture(obstruction_light + (1 - alpha) * unobstructed, unobstructed, obstruction_light, alpha)


def canvas_coverage(mask: torch.Tensor, psf_near: torch.Tensor) -> torch.Tensor:
    """m ∗ P̂_near over the whole canvas (..., C, H + 2M, W + 2M), clamped to 0..1: the fraction
    of each far point's cone the cover blocks, wherever on the canvas. Beyond the canvas the
    mask is taken to continue as its edge pixels (as the canvas's scene is extended)."""
    kernel = unit_sum(psf_near)
    h, w = mask.shape[-2:]
    n0, n1 = (n // 2 for n in kernel.shape[-2:])
    padded = torch.nn.functional.pad(mask.to(kernel.dtype), (n1, n1, n0, n0), mode="replicate")
    shape = (fft_size(h + 2 * n0), fft_size(w + 2 * n1))
    spectrum = torch.fft.rfft2(padded, s=shape) * torch.fft.rfft2(_placed(kernel, shape))
    return torch.fft.irfft2(spectrum, s=shape)[..., n0 : n0 + h, n1 : n1 + w].clamp(0.0, 1.0)


def zero_order_light(
    clean: torch.Tensor,
    obstruction: torch.Tensor,
    mask: torch.Tensor,
    psf_near: torch.Tensor,
    zero_near,
    zero_far,
    margin: int,
    *,
    formation: str = "physical",
) -> tuple[torch.Tensor, torch.Tensor]:
    """The unconverted light of the lens on the sensor (``optics.zero_order``), (obstructed,
    unobstructed), each (..., 3, H, W), per unit of the focused light (scale by ζ_c):
    Z_near ∗ (m ⊙ I_obs) + Z_far ∗ ((1 − α̃) ⊙ I_clean) and Z_far ∗ I_clean.

    The cover blocks a far point's zero-order light in the same cone as its focused light (α̃ =
    m ∗ P̂_near at the point, :func:`canvas_coverage`), but that light lands over a disc around it,
    hence the product before the blur. ``zero_near``, ``zero_far``: unit-sum (1, N, N) PSFs or
    their :class:`PsfTransform`; ``psf_near`` the focused near PSFs (3, N, N); canvases as
    :func:`form_image`, with a margin that holds the zero-order discs."""
    emitted, mask = _obstruction_canvases(obstruction, mask, formation)
    passed = (1 - canvas_coverage(mask, psf_near)) * clean
    obstructed = convolve(emitted, zero_near, margin) + convolve(passed, zero_far, margin)
    return obstructed, convolve(clean, zero_far, margin)


def add_noise(
    image: torch.Tensor,
    photons: float | torch.Tensor | None = None,
    *,
    read_noise: float = 0.0,
    generator: torch.Generator | int | None = None,
) -> torch.Tensor:
    """Poisson-Gaussian sensor noise, differentiable (Gaussian approximation of shot noise).

    A pixel of value x (1 = full scale) collects x·``photons`` electrons: its noise has
    variance x/photons (shot, x clamped at 0) + ``read_noise``² (read noise, in full-scale
    units).

    Args:
        image: linear image(s), 1 = full scale.
        photons: full-well electrons; None or 0 means no shot noise; a tensor gives one count per
            channel (shape (3, 1, 1): a filter passes each channel its own share of the light,
            differentiably).
        read_noise: read-noise σ as a fraction of full scale, ≥ 0; may be a tensor too (one σ per
            channel, (3, 1, 1)).
        generator: a seed or a ``torch.Generator`` on the image's device; the same seed gives the
            same noise.

    Returns:
        The noisy image (not clipped).

    Shape:
        - Input: :math:`(..., C, H, W)`
        - Output: :math:`(..., C, H, W)`
    """
    arguments.instance(image, "image", torch.Tensor, "an image tensor (..., C, H, W)")
    arguments.array(image, "image", form="an image tensor")
    for name, value, form in (
        ("photons", photons, "a positive full-well count (None or 0: no shot noise)"),
        ("read_noise", read_noise, "a non-negative standard deviation"),
    ):
        if torch.is_tensor(value):
            arguments.array(value, name, form=form)
        elif value is not None or name == "read_noise":
            arguments.number(value, name, lo=0.0, form=form)
    if isinstance(generator, int):
        generator = torch.Generator(device=image.device).manual_seed(generator)
    variance = torch.zeros_like(image)
    if torch.is_tensor(photons) or photons:
        if bool((torch.as_tensor(photons) <= 0).any()):
            raise InputError("photons", f"{photons!r}", "a positive full-well count")
        variance = image.clamp_min(0) / photons
    if bool((torch.as_tensor(read_noise) < 0).any()):
        raise InputError("read_noise", f"{read_noise!r}", "a non-negative standard deviation")
    variance = variance + read_noise**2
    noise = torch.randn(image.shape, generator=generator, dtype=image.dtype, device=image.device)
    return image + torch.sqrt(variance) * noise
