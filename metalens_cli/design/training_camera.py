"""The camera a run trains under: the light its captures collect, their noise and the zero order.

Two ways to set it in ``[optimize]``:

- ``light`` (the verdict's camera, ``imaging.camera``): a full-scale white pixel collects ``light``
  electrons before the filter through an ideal lens, so channel c of this design collects
  light·t_c, t_c = ∫CRF_c·T·η / ∫CRF_c (the filter T and the nanofins' η both cost light, as
  ``evaluate --light`` counts them); shot noise, and ``read_electrons`` rms of read noise; and the
  unconverted light ζ_c (``zero_order_leak``) over the capture. A filter learned with θ passes
  g_c = ∫CRF_c·η·T / ∫CRF_c·η of each channel's light (its band draws, differentiable), so the
  channel collects light·s_c·g_c, s_c = ∫CRF_c·η / ∫CRF_c: a narrower band pays in noise.
- ``photons`` and ``read_noise`` (the older form): photons·g_c full-well electrons, η not counted,
  and a read noise in full-scale units; no zero order.

The zero order in a training step is its mean: the unconverted light lands as discs as wide as the
aperture (about 1360 px of 1.85 µm on the paper's lens), far wider than a step's canvas, so over
the canvas it is a veil of ζ_c times the mean light that reaches the lens, (1 − m)·I + m·O of
scene I, obstruction coverage m and obstruction light O. Exact for a uniform scene (a grey wall
gains ζ_c of itself); a veil is a bias that the metric's least-squares match removes, so under the
metric it costs only its shot noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from metalens_cli.imaging.formation import add_noise


@dataclass(frozen=True)
class TrainingCamera:
    """Per channel R, G, B: ``electrons`` (3,) a full-scale capture value stands for with the
    preset's own filter; ``per_share`` (3,) the same per unit of a filter's share g_c (band
    draws of a learned filter); read noise as ``read_electrons`` (e⁻ rms, ``light``) or
    ``read_noise`` (full-scale units, ``photons``); ``zero_order`` (3,) ζ_c or None."""

    electrons: np.ndarray | None
    per_share: np.ndarray | None
    read_electrons: float | None = None
    read_noise: float = 0.0
    zero_order: np.ndarray | None = None

    def full_scale(self, share: torch.Tensor | None) -> torch.Tensor | None:
        """(3,) electrons at full scale: of the filter's ``share`` g_c (a draw's, differentiable)
        or, for None, of the preset's filter; None without shot noise."""
        if self.electrons is None:
            return None
        if share is None:
            return torch.as_tensor(self.electrons)
        return torch.as_tensor(self.per_share, dtype=share.dtype) * share


def training_camera(preset) -> TrainingCamera | None:
    """The camera of ``preset``'s ``[optimize]`` keys (module docstring), None when noise-free."""
    from metalens_cli.imaging.camera import efficiency_share, preset_budget
    from metalens_cli.io.preset_spectra import channel_throughput

    o = preset.optimize
    if o.light > 0:
        budget = preset_budget(preset, o.zero_order_leak)
        zero = budget.zero_order if o.zero_order_leak > 0 else None
        return TrainingCamera(
            o.light * budget.throughput, o.light * efficiency_share(preset), o.read_electrons, 0.0, zero
        )
    if o.photons or o.read_noise:
        if not o.photons:
            return TrainingCamera(None, None, None, o.read_noise)
        return TrainingCamera(o.photons * channel_throughput(preset), np.full(3, o.photons), None, o.read_noise)
    return None


def zero_order_veil(clean: torch.Tensor, colour: torch.Tensor, mask: torch.Tensor, zeta) -> torch.Tensor:
    """The zero order's mean over a step's canvas (module docstring), (B, 3, 1, 1): ζ_c times the
    canvas mean of (1 − m)·clean + m·colour, with ``zeta`` (3,) and canvases (B, C, H, W)."""
    reaching = (1 - mask) * clean + mask * colour
    z = torch.as_tensor(zeta, dtype=clean.dtype, device=clean.device).reshape(3, 1, 1)
    return z * reaching.mean(dim=(-2, -1), keepdim=True)


def expose(capture: torch.Tensor, camera: TrainingCamera | None, share: torch.Tensor | None, seed: int) -> torch.Tensor:
    """``capture`` (B, 3, H, W) with ``camera``'s shot and read noise (``imaging.formation.add_noise``),
    of the filter's ``share`` (3,) (a draw's; None: the preset's filter), drawn from ``seed``;
    unchanged without a camera."""
    if camera is None:
        return capture
    n = camera.full_scale(share)
    if n is not None:
        n = n.to(capture.device, torch.float32).reshape(3, 1, 1)
    read = camera.read_noise if camera.read_electrons is None else camera.read_electrons / n
    return add_noise(capture, n, read_noise=read, generator=seed)
