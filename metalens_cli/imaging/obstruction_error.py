"""The error a near obstruction adds to a capture, taken apart by cause, channel and spatial frequency.

R is the reference (the clean image on the sensor), U the unobstructed capture and O = U + S + E + Z
the obstructed one, formed as ``imaging.formation`` forms them: S = −α ⊙ (P̂_far ∗ I_clean) the
obstruction's shadow (the far light its cone fraction α blocks), E its own light (the near PSF's
image of what it emits), Z the change of the lens's zero-order light. The metric matches each
capture to R with a global gain a and bias b (``metrics.photometric_match``), so with U′ = a_U U +
b_U, O′ = a_O O + b_O and D = O′ − U′ the error the obstruction adds is, exactly,

    A = ⟨(O′ − R)²⟩ − ⟨(U′ − R)²⟩ = Σ_i ⟨t_i · (D + 2 (U′ − R))⟩,

over the parts t_i of D: a_O S (shadow), a_O E (own light), a_O Z (zero order) and the re-match
(a_O − a_U) U + b_O − b_U (what the changed gain and bias do to the whole image). ⟨·⟩ is the mean
over pixels and channels; a channel's share is the mean over its pixels, and by Parseval each part's
share splits over radial spatial-frequency bands. Everything is linear radiance (the reported PSNR
is taken on sRGB values, which no sum splits; the two orders are compared where they are used).
Pure torch, no I/O.
"""

from __future__ import annotations

import torch

from metalens_cli.imaging.formation import form_image, zero_order_light
from metalens_cli.imaging.metrics import photometric_match

PARTS = ("shadow", "own_light", "zero_order", "rematch")


def capture_parts(
    clean: torch.Tensor, rgb: torch.Tensor, mask: torch.Tensor, psfs, margin: int, *, formation: str = "physical"
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """(U, S, E, Z), each (3, H, W) on the sensor, of a clean canvas (3, H + 2M, W + 2M) behind
    an obstruction of radiance ``rgb`` and coverage ``mask`` (canvases, ``imaging.obstructions``)
    through the on-axis ``psfs`` (``imaging.channel_psfs.ChannelPsfs``, with its zero-order light when
    attached): the captures :func:`~metalens_cli.imaging.pipeline.simulate_captures` forms,
    noise-free, with O = U + S + E + Z."""
    capture = form_image(clean, rgb, mask, psfs.near, psfs.far, margin, formation=formation)
    unobstructed, zero = capture.unobstructed, torch.zeros_like(capture.unobstructed)
    if psfs.zero_order is not None:
        z = psfs.zero_order
        obstructed_zero, clear_zero = zero_order_light(
            clean, rgb, mask, psfs.near, z.near, z.far, margin, formation=formation
        )
        unobstructed, zero = unobstructed + z.scale * clear_zero, z.scale * (obstructed_zero - clear_zero)
    return unobstructed, -capture.alpha * capture.unobstructed, capture.obstruction_light, zero


def error_parts(
    reference: torch.Tensor,
    unobstructed: torch.Tensor,
    shadow: torch.Tensor,
    own_light: torch.Tensor,
    zero_order: torch.Tensor | None = None,
    *,
    match: str = "lstsq",
) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
    """The parts t_i of D = O′ − U′ (a dict over :data:`PARTS`, each (..., 3, H, W)) and the
    unobstructed capture's own error U′ − R, from R, U, S, E and Z (zero when None), each
    (..., 3, H, W) linear; ``match`` is the metric's photometric match."""
    zero = torch.zeros_like(unobstructed) if zero_order is None else zero_order
    obstructed = unobstructed + shadow + own_light + zero
    matched_u, gain_u, bias_u = photometric_match(unobstructed, reference, match)
    _, gain_o, bias_o = photometric_match(obstructed, reference, match)
    a_o, a_u, b_o, b_u = (x[..., None, None, None] for x in (gain_o, gain_u, bias_o, bias_u))
    parts = {
        "shadow": a_o * shadow,
        "own_light": a_o * own_light,
        "zero_order": a_o * zero,
        "rematch": (a_o - a_u) * unobstructed + (b_o - b_u),
    }
    return parts, matched_u - reference


def added_error(parts: dict[str, torch.Tensor], base_error: torch.Tensor) -> dict[str, torch.Tensor]:
    """Each part's share of the added error A per channel, (..., 3): ⟨t_i (D + 2 (U′ − R))⟩ over
    the channel's pixels; the shares sum to A (their mean over channels to the whole image's A)."""
    weight = sum(parts.values()) + 2 * base_error
    return {name: (t * weight).mean(dim=(-2, -1)) for name, t in parts.items()}


def radial_frequency(shape: tuple[int, int], device=None, dtype=torch.float64) -> torch.Tensor:
    """|ν| (cycles per pixel) of each bin of an H × W ``torch.fft.fft2`` grid."""
    fy = torch.fft.fftfreq(shape[0], device=device, dtype=dtype)
    fx = torch.fft.fftfreq(shape[1], device=device, dtype=dtype)
    return torch.hypot(fy[:, None], fx[None, :])


def added_error_spectrum(
    parts: dict[str, torch.Tensor], base_error: torch.Tensor, edges: list[float]
) -> dict[str, torch.Tensor]:
    """Each part's share of A per channel and radial frequency band [edges[k], edges[k+1])
    (cycles per pixel; the last band is closed), (..., 3, len(edges) − 1), by Parseval:
    Re⟨t̂_i conj(D̂ + 2 (U′ − R)^)⟩ / (H W)² summed over the band's bins. With edges from 0 to
    beyond √½ the bands sum to :func:`added_error`."""
    weight = torch.fft.fft2(sum(parts.values()) + 2 * base_error)
    h, w = base_error.shape[-2:]
    nu = radial_frequency((h, w), base_error.device)
    out = {}
    for name, t in parts.items():
        density = (torch.fft.fft2(t) * weight.conj()).real / (h * w) ** 2
        bands = []
        for k, (lo, hi) in enumerate(zip(edges[:-1], edges[1:])):
            inside = (nu >= lo) & ((nu < hi) if k < len(edges) - 2 else (nu <= hi))
            bands.append((density * inside).sum(dim=(-2, -1)))
        out[name] = torch.stack(bands, dim=-1)
    return out


__all__ = ["PARTS", "added_error", "added_error_spectrum", "capture_parts", "error_parts", "radial_frequency"]
