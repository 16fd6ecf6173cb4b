"""The oracle Wiener restoration: the best linear back end given a design's far channel PSFs
and its camera's noise, a bound on what linear deconvolution recovers from its captures.

Per channel c, on a linear capture y (3, H, W), mirrored by ``margin`` pixels on every side so
that the FFT's wrap-around meets a continuation of the image rather than its opposite edge:

    x̂ = F⁻¹[ H_c* · Y / (|H_c|² + μ_c · (ν / ν_N)²) ]

H_c the transfer function of the unit-sum far PSF (axis at its centre pixel: no shift), ν the
radial spatial frequency (cycles per pixel) and ν_N = 1/2: the noise-to-signal ratio of white
noise over a scene whose power falls as 1/ν² (natural images). ν = 0 is not regularised, so the
mean is kept and a grey wall stays grey. μ_c is chosen per design, channel and camera from
``MU_GRID`` by the least mean squared error (linear values) on held-out scenes that the table
never scores; μ = 0 (the inverse filter) is in the grid, so a delta PSF without noise restores
exactly. The obstruction is unknown to the filter.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from metalens_cli.imaging.formation import psf_transform

MU_GRID = (0.0, *np.logspace(-8, 4, 25).tolist())


def _mirrored(image: torch.Tensor, margin: int) -> torch.Tensor:
    """``image`` (..., H, W) extended by ``margin`` pixels of its mirror image on every side
    (repeatedly, for a margin beyond the image's size)."""
    array = image.detach().cpu().numpy()
    pad = [(0, 0)] * (array.ndim - 2) + [(margin, margin)] * 2
    return torch.as_tensor(np.pad(array, pad, mode="symmetric"), dtype=image.dtype, device=image.device)


def _frequency_weight(fft_shape: tuple[int, int], dtype, device) -> torch.Tensor:
    """(ν/ν_N)² on the rfft2 grid of ``fft_shape``."""
    fy = torch.fft.fftfreq(fft_shape[0], dtype=dtype, device=device)[:, None]
    fx = torch.fft.rfftfreq(fft_shape[1], dtype=dtype, device=device)[None, :]
    return (fy**2 + fx**2) / 0.25


@dataclass
class WienerFilter:
    """The filters of one design's far PSFs for ``sensor_hw`` captures: ``transfer`` H (3, L0,
    L1//2 + 1), ``weight`` (ν/ν_N)², the mirror ``margin`` and FFT grid, and ``mu`` (3,)."""

    transfer: torch.Tensor
    weight: torch.Tensor
    margin: int
    fft_shape: tuple[int, int]
    sensor_hw: tuple[int, int]
    mu: np.ndarray
    _power: torch.Tensor | None = field(default=None, repr=False)  # |H|², made once

    @classmethod
    def of(cls, psf_far: torch.Tensor, sensor_hw: tuple[int, int], mu=(0.0, 0.0, 0.0)) -> WienerFilter:
        """The filter of the far channel PSFs ``psf_far`` (3, N, N) (any normalisation)."""
        t = psf_transform(psf_far.to(torch.float64), tuple(sensor_hw))
        return cls(
            t.spectrum,
            _frequency_weight(t.fft_shape, torch.float64, t.spectrum.device),
            t.margin,
            t.fft_shape,
            tuple(sensor_hw),
            np.asarray(mu, dtype=float),
        )

    def spectrum(self, capture: torch.Tensor) -> torch.Tensor:
        """rfft2 of the mirrored capture (3, H, W) on the filter's grid."""
        return torch.fft.rfft2(_mirrored(capture.to(torch.float64), self.margin), s=self.fft_shape)

    def gain(self, mu) -> torch.Tensor:
        """The filter H*/(|H|² + μ(ν/ν_N)²) (3, L0, L1//2 + 1) for ``mu`` (3,)."""
        mu = torch.as_tensor(np.asarray(mu, dtype=float), dtype=torch.float64, device=self.transfer.device)
        h = self.transfer
        if self._power is None:
            self._power = h.real**2 + h.imag**2
        denominator = self._power + mu.reshape(3, 1, 1) * self.weight
        return h.conj() / denominator.clamp_min(torch.finfo(torch.float64).tiny)

    def restore_spectrum(self, spectrum: torch.Tensor, mu) -> torch.Tensor:
        """The restored sensor crop (3, H, W) from a capture's :meth:`spectrum`, with ``mu`` (3,)."""
        full = torch.fft.irfft2(spectrum * self.gain(mu), s=self.fft_shape)
        m, (rows, cols) = self.margin, self.sensor_hw
        return full[..., m : m + rows, m : m + cols]

    def __call__(self, capture) -> np.ndarray:
        """The restoration (3, H, W) float32 of a linear capture (numpy or torch)."""
        x = torch.as_tensor(np.asarray(capture), dtype=torch.float64, device=self.transfer.device)
        return self.restore_spectrum(self.spectrum(x), self.mu).cpu().numpy().astype(np.float32)


def choose_mu(wiener: WienerFilter, captures, cleans, grid=MU_GRID) -> tuple[np.ndarray, np.ndarray]:
    """μ (3,) from ``grid`` with the least mean squared error per channel of the restored
    ``captures`` against ``cleans`` (lists of linear (3, H, W) held-out images) over the sensor,
    and that error (3, len(grid)). (Over the whole mirrored FFT grid instead, by Parseval without
    an inverse transform per μ, the zero-padded edge of the grid rings and μ comes out 10²-10⁴
    times too large: 18.6 against 41.4 dB noise-free on the split lens's photographs.)"""
    errors = np.zeros((3, len(grid)))
    for capture, clean in zip(captures, cleans):
        x = torch.as_tensor(np.asarray(capture), dtype=torch.float64, device=wiener.transfer.device)
        truth = torch.as_tensor(np.asarray(clean), dtype=torch.float64, device=x.device)
        spectrum = wiener.spectrum(x)
        for k, mu in enumerate(grid):
            restored = wiener.restore_spectrum(spectrum, [mu] * 3)
            errors[:, k] += ((restored - truth) ** 2).mean(dim=(-2, -1)).cpu().numpy()
    errors /= max(len(captures), 1)
    return np.asarray(grid)[errors.argmin(axis=1)], errors
