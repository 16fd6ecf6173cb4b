"""A nanofin cell and what a solver returns for it: the ``Fin`` (its sizes checked as it is
made), the ``FinResponse`` per wavelength, and the rule for the Fourier harmonics N. Shared by
the solvers (``optics.nanofin``: the entry point and meent; ``optics.fin_modes``: this package's
RCWA). Lengths in metres."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metalens_cli.arguments import count, positive
from metalens_cli.errors import InputError

NM = 1e9


@dataclass(frozen=True)
class Fin:
    """A nanofin cell, lengths in metres.

    Checked when built: every size a positive finite length, the fin inside its cell.

    Attributes:
        period_m: lattice period (m).
        height_m: fin height (m).
        width_m: fin width along x (m), at most the period.
        length_m: fin length along y (m), at most the period.

    Examples:
        >>> Fin(period_m=395e-9, height_m=600e-9, width_m=85e-9, length_m=300e-9).width_m
        8.5e-08
        >>> Fin(period_m=395e-9, height_m=600e-9, width_m=85e-9, length_m=410e-9)
        Traceback (most recent call last):
        ...
        metalens_cli.errors.InputError: length: 410 nm is larger than the 395 nm period (expected a fin inside its cell)
    """

    period_m: float
    height_m: float
    width_m: float
    length_m: float

    def __post_init__(self) -> None:
        """InputError unless every size is a positive finite length and the fin fits in its cell."""
        for name in ("period_m", "height_m", "width_m", "length_m"):
            positive(getattr(self, name), name)
        for name in ("width_m", "length_m"):
            if getattr(self, name) > self.period_m:
                raise InputError(
                    name.removesuffix("_m"),
                    f"{getattr(self, name) * NM:g} nm is larger than the {self.period_m * NM:g} nm period",
                    "a fin inside its cell",
                )


@dataclass(frozen=True)
class FinResponse:
    """The response of a nanofin cell per wavelength, as :func:`fin_response` computes it.

    Attributes:
        wavelengths_m: (W,) wavelengths (m).
        t_xx: (W,) complex Jones coefficient along x, power-normalised.
        t_yy: (W,) complex Jones coefficient along y, power-normalised.
        conversion: (W,) polarisation-conversion efficiency η (power fraction).
        co_polarized: (W,) co-polarised power fraction.
        transmittance: (W,) transmitted power fraction.
        reflectance: (W,) reflected power fraction.
        harmonics: N (N × N Fourier orders).
        seconds: (W,) computation time per wavelength (s).
    """

    wavelengths_m: np.ndarray
    t_xx: np.ndarray
    t_yy: np.ndarray
    conversion: np.ndarray
    co_polarized: np.ndarray
    transmittance: np.ndarray
    reflectance: np.ndarray
    harmonics: int
    seconds: np.ndarray


def check_harmonics(harmonics: int) -> None:
    """N must be odd (orders −(N−1)/2 … (N−1)/2 on each axis) and at least 1."""
    if count(harmonics, "harmonics") % 2 == 0:
        raise InputError("harmonics", str(harmonics), "an odd number of Fourier harmonics per axis, e.g. 15")
