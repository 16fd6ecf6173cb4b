"""The reconstruction network (Suppl. Note 5): a LocalNet-style U-Net with CBAM attention that
predicts a residual, added to the capture after a learned spectral filter (:class:`SpectralFilter`:
a radial frequency response per channel whose DC gain is fixed at one, the identity at the start).

A uniform capture is returned unchanged, whatever the weights (the grey-wall invariant the optics
keep): the U-Net sees the filtered capture as contrast, S(x − m)/m with m the capture's
mean per channel, its main path has no biases (zero in, zero out), and the residual is scaled
back by m (the filter acts on x − m: a uniform capture's DC never meets the FFT). Planes:

- signal (:func:`signal_planes`, carried through the U-Net): the contrast (3 planes) and the
  gradient magnitude of its Rec. 709 luminance (forward differences, edge replicated;
  g²/√(g² + ε), exactly 0 where flat);
- context (:func:`context_planes`, modulating the first level's features, 1 + a 1 × 1 convolution of it, so it cannot
  create signal where there is none): an over-exposure mask, 0 below ``OVEREXPOSED`` of full scale
  rising linearly to 1 at 1, and positional encodings sin(2^k·π·u), cos(2^k·π·u), k <
  ``frequencies``, of the pixel position u (x and y) from the optical axis in units of
  ``position_scale`` pixels (half the sensor's side), so that the network can learn aberrations
  that vary over the field (Vaswani et al. 2017; Mildenhall et al. 2020). Positions come in as a
  (B, 2, H, W) plane pair, so a tile or a crop knows where on the sensor it lies
  (:func:`pixel_positions`), and m may be given, so tiles use the whole capture's.

Bias-free convolutional networks (Mohan et al. 2020, "Robust and interpretable blind image
denoising via bias-free convolutional neural networks") keep this invariant without losing
accuracy in denoising. The U-Net has ``depth`` stride-2 downsamplings; level k carries
``width``·2^k channels; every level is a residual block: two 3 × 3 convolutions (leaky ReLU
between) whose output passes CBAM (channel attention from average- and max-pooled features through
a shared MLP, then spatial attention from a 7 × 7 convolution of the channel mean and max; Woo et
al. 2018) before the shortcut is added, so attention gates the residual and activations keep
their scale through the levels (He initialisation). Upsampling is a 1 × 1 convolution followed by
bilinear interpolation, then concatenation with the skip. The output convolution starts at zero,
so an untrained network is the identity. Any H, W (a stride-2 level has ⌈H/2⌉ rows; upsampling
returns to the skip's size exactly) and any floating dtype.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
from torch import nn
from torch.nn import functional as F

from metalens_cli.imaging.images import LUMA_709

OVEREXPOSED = 0.95  # fraction of full scale where the over-exposure mask starts
GRADIENT_EPS = 1e-6  # ε of the gradient plane g²/√(g² + ε), in squared contrast units
MEAN_FLOOR = 1e-3  # the smallest capture mean the contrast is taken relative to (linear units)
# spectral gains are stored ÷ this, so that optimiser steps of the order of the learning rate move them visibly
GAIN_SCALE = 30.0


@dataclass(frozen=True)
class NetworkShape:
    """Width (channels at full resolution), depth (downsamplings), positional frequencies per axis,
    CBAM reduction of the channel MLP, the pixel scale of positions (half the trained sensor side)
    and the knots of the learned spectral filter (0: none)."""

    width: int = 16
    depth: int = 3
    frequencies: int = 4
    reduction: int = 4
    position_scale: float = 64.0
    spectral_bins: int = 32

    def __post_init__(self):
        """ValueError for sizes no network has (a foreign or damaged model file's)."""
        counts = {
            "width": (self.width, 1),
            "depth": (self.depth, 0),
            "frequencies": (self.frequencies, 0),
            "reduction": (self.reduction, 1),
            "spectral_bins": (self.spectral_bins, 0),
        }
        for name, (value, least) in counts.items():
            if isinstance(value, bool) or not isinstance(value, int) or value < least:
                raise ValueError(f"{name} {value!r} is not an integer ≥ {least}")
        if self.spectral_bins == 1:
            raise ValueError("spectral_bins 1 leaves the filter only its fixed DC knot: 0 (no filter) or ≥ 2")

    def to_dict(self) -> dict:
        """The fields as a plain dict (as model files and reports store them)."""
        return asdict(self)

    @property
    def signal_channels(self) -> int:
        """Channels of the signal planes: the 3 contrast channels and the luminance-gradient
        magnitude (4)."""
        return 3 + 1

    @property
    def context_channels(self) -> int:
        """Channels of the context planes: the over-exposure mask and sin, cos of x and y at each of
        the ``frequencies`` (1 + 4F)."""
        return 1 + 4 * self.frequencies


def pixel_positions(
    height: int,
    width: int,
    *,
    top: int = 0,
    left: int = 0,
    full: tuple[int, int] | None = None,
    scale: float = 1.0,
    dtype=torch.float32,
    device="cpu",
) -> torch.Tensor:
    """(2, height, width) positions (x, y) in units of ``scale`` pixels from the centre of the
    ``full`` (H, W) image (default: this one) for a window whose top-left pixel is (top, left)."""
    full_h, full_w = full or (height, width)
    y = (torch.arange(top, top + height, dtype=dtype, device=device) - (full_h - 1) / 2) / scale
    x = (torch.arange(left, left + width, dtype=dtype, device=device) - (full_w - 1) / 2) / scale
    return torch.stack([x.expand(height, width), y[:, None].expand(height, width)])


def capture_mean(x: torch.Tensor) -> torch.Tensor:
    """(B, 3, 1, 1) mean of each channel of (B, 3, H, W) captures: what the contrast is relative to."""
    return x.mean(dim=(-2, -1), keepdim=True)


def signal_planes(contrast: torch.Tensor) -> torch.Tensor:
    """(B, 4, H, W): the contrast (B, 3, H, W) and its luminance-gradient magnitude, zero where it is."""
    luma = sum(w * contrast[:, c : c + 1] for c, w in enumerate(LUMA_709))
    gx = F.pad(luma[..., :, 1:] - luma[..., :, :-1], (0, 1, 0, 0))
    gy = F.pad(luma[..., 1:, :] - luma[..., :-1, :], (0, 0, 0, 1))
    g2 = gx * gx + gy * gy
    return torch.cat([contrast, g2 / torch.sqrt(g2 + GRADIENT_EPS)], dim=1)


def context_planes(x: torch.Tensor, positions: torch.Tensor, frequencies: int) -> torch.Tensor:
    """(B, 1 + 4F, H, W): over-exposure mask of the capture x and positional encodings."""
    overexposed = ((x.amax(dim=1, keepdim=True) - OVEREXPOSED) / (1 - OVEREXPOSED)).clamp(0, 1)
    scales = (2.0 ** torch.arange(frequencies, dtype=x.dtype, device=x.device) * math.pi).view(1, 1, -1, 1, 1)
    angles = (positions.to(x.dtype).unsqueeze(2) * scales).flatten(1, 2)
    return torch.cat([overexposed, torch.sin(angles), torch.cos(angles)], dim=1)


class SpectralFilter(nn.Module):
    """A learned, radially symmetric frequency response per channel, 1 + g_c(ρ), with g_c linear
    between ``bins`` knots over ρ = 0 … 1/√2 cycles per pixel (the corner of the spectrum), the
    knot at ρ = 0 fixed at 0 (a uniform image passes unchanged: no tint), the others learned from
    0: the identity. Applied by FFT after extending the edge pixels ``pad`` pixels outwards (no
    wrap-around across the image); defined in cycles per pixel, so the same at any image size. It
    restores the contrast a shift-invariant lens blur takes from each spatial frequency, which the
    U-Net's local convolutions reach only slowly when the blur is wide. :meth:`change` is the
    filtered image minus the image, g_c(ρ) alone through the FFT: exactly zero while the gains
    are, so an untrained network returns its input bit for bit."""

    def __init__(self, channels: int, bins: int, pad: int = 32):
        super().__init__()
        self.gain = nn.Parameter(torch.zeros(channels, bins - 1))  # knots 1 … bins − 1
        self.pad = pad

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(B, C, H, W) → the filtered image, same shape: x + :meth:`change` (x)."""
        return x + self.change(x)

    def change(self, x: torch.Tensor) -> torch.Tensor:
        """S(x) − x."""
        h, w = x.shape[-2:]
        p = self.pad
        padded = F.pad(x, (p, p, p, p), mode="replicate")
        ph, pw = padded.shape[-2:]
        iy = torch.arange(ph, device=x.device)
        fy = torch.where(iy < (ph + 1) // 2, iy, iy - ph).to(x.dtype) / ph  # torch.fft.fftfreq, traceable for any size
        fx = torch.arange(pw // 2 + 1, device=x.device).to(x.dtype) / pw  # torch.fft.rfftfreq
        knots = self.gain.shape[-1]
        rho = torch.sqrt(fy[:, None] ** 2 + fx[None, :] ** 2) * (math.sqrt(2) * knots)
        lo = rho.floor().clamp(max=knots - 1).long()
        frac = rho - lo
        g = GAIN_SCALE * F.pad(self.gain.to(x.dtype), (1, 0))  # DC knot: 0
        response = g[:, lo] * (1 - frac) + g[:, lo + 1] * frac
        out = torch.fft.irfft2(torch.fft.rfft2(padded) * response, s=(ph, pw))
        return out[..., p : p + h, p : p + w]


class Cbam(nn.Module):
    """Convolutional block attention (Woo et al. 2018): channel, then spatial."""

    def __init__(self, channels: int, reduction: int, kernel: int = 7):
        super().__init__()
        hidden = max(channels // reduction, 4)
        self.mlp = nn.Sequential(nn.Conv2d(channels, hidden, 1), nn.ReLU(inplace=True), nn.Conv2d(hidden, channels, 1))
        self.spatial = nn.Conv2d(2, 1, kernel, padding=kernel // 2)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(B, C, H, W) → the same shape, reweighted by channel, then by spatial attention."""
        # adaptive pooling: 10× faster than amax over (H, W) of a channels-last tensor on the CPU
        x = x * torch.sigmoid(self.mlp(F.adaptive_avg_pool2d(x, 1)) + self.mlp(F.adaptive_max_pool2d(x, 1)))
        pooled = torch.cat([x.mean(dim=1, keepdim=True), x.amax(dim=1, keepdim=True)], dim=1)
        return x * torch.sigmoid(self.spatial(pooled))


class _Level(nn.Module):
    """Residual block with CBAM (Woo et al. 2018, Fig. 3): relu(CBAM(conv(relu(conv x))) + shortcut x)."""

    def __init__(self, c_in: int, c_out: int, reduction: int):
        super().__init__()
        self.conv1 = nn.Conv2d(c_in, c_out, 3, padding=1, bias=False)
        self.conv2 = nn.Conv2d(c_out, c_out, 3, padding=1, bias=False)
        self.attention = Cbam(c_out, reduction)
        self.shortcut = nn.Identity() if c_in == c_out else nn.Conv2d(c_in, c_out, 1, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = self.attention(self.conv2(F.leaky_relu_(self.conv1(x), 0.2)))
        h += self.shortcut(x)  # in place: the products' gradients need their inputs, not their output
        return F.leaky_relu_(h, 0.2)


class ReconstructionNet(nn.Module):
    """S(x) + m·U-Net(planes of S(x − m)/m): (B, 3, H, W) linear capture → (B, 3, H, W) linear
    estimate, S the learned spectral filter (identity when ``spectral_bins`` is 0), m the capture's
    mean per channel. Convolutions on the U-Net's main path have no biases (CBAM's gates do)."""

    def __init__(self, shape: NetworkShape = NetworkShape()):
        super().__init__()
        self.shape = shape
        w, r = shape.width, shape.reduction
        self.spectral = SpectralFilter(3, shape.spectral_bins) if shape.spectral_bins else None
        channels = [w * 2**k for k in range(shape.depth + 1)]
        self.encoder = nn.ModuleList(
            [_Level(shape.signal_channels, w, r)]
            + [_Level(channels[k], channels[k + 1], r) for k in range(shape.depth)]
        )
        self.context = nn.Conv2d(shape.context_channels, w, 1)  # the modulation 1 + context(planes)
        self.down = nn.ModuleList([nn.Conv2d(c, c, 3, stride=2, padding=1, bias=False) for c in channels[:-1]])
        self.up = nn.ModuleList([nn.Conv2d(channels[k + 1], channels[k], 1, bias=False) for k in range(shape.depth)])
        self.decoder = nn.ModuleList([_Level(2 * channels[k], channels[k], r) for k in range(shape.depth)])
        self.head = nn.Conv2d(w, 3, 3, padding=1, bias=False)
        for module in self.modules():
            if isinstance(module, nn.Conv2d):
                nn.init.kaiming_normal_(module.weight, nonlinearity="relu")
                if module.bias is not None:
                    nn.init.zeros_(module.bias)
        for module in (self.head, self.context):
            nn.init.zeros_(module.weight)
        nn.init.zeros_(self.context.bias)

    def forward(
        self, x: torch.Tensor, positions: torch.Tensor | None = None, mean: torch.Tensor | None = None
    ) -> torch.Tensor:
        """``positions`` (B or 1, 2, H, W) from :func:`pixel_positions`; None: this image's own,
        centred, in units of ``shape.position_scale`` pixels. ``mean`` (B or 1, 3, 1, 1): the mean
        the contrast is relative to (a tile's: the whole capture's); None: :func:`capture_mean` of x."""
        h, w = x.shape[-2:]
        if positions is None:
            positions = pixel_positions(h, w, scale=self.shape.position_scale, dtype=x.dtype, device=x.device)[None]
        mean = (capture_mean(x) if mean is None else mean.to(x.dtype)).expand(x.shape[0], -1, -1, -1)
        # the filter acts on the deviation from the mean: a uniform capture's large DC term never
        # meets the FFT, whose rounding would leak it into the other frequencies
        deviation = x - mean
        change = self.spectral.change(deviation) if self.spectral is not None else torch.zeros_like(x)
        scale = mean.clamp_min(MEAN_FLOOR)
        context = context_planes(x, positions.expand(x.shape[0], -1, -1, -1), self.shape.frequencies)
        skips, features = [], signal_planes((deviation + change) / scale)
        for k, level in enumerate(self.encoder):
            features = level(features)
            if k == 0:
                features = features * (1 + self.context(context))
            if k < self.shape.depth:
                skips.append(features)
                features = self.down[k](features)
        for k in reversed(range(self.shape.depth)):
            # the 1 × 1 convolution before the upsampling: both are linear and bilinear weights sum to
            # one, so the order changes nothing but the cost (a quarter of the pixels, half the channels)
            features = F.interpolate(
                self.up[k](features), size=skips[k].shape[-2:], mode="bilinear", align_corners=False
            )
            features = self.decoder[k](torch.cat([features, skips[k]], dim=1))
        return x + change + scale * self.head(features)
