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
    """A nanofin cell, lengths in metres: lattice ``period_m``, fin ``width_m`` (along x),
    ``length_m`` (along y) and ``height_m``."""

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
    """Per wavelength (arrays of shape (W,)): ``t_xx``, ``t_yy`` (complex, power-normalised),
    ``conversion`` η, ``co_polarized``, ``transmittance``, ``reflectance`` (power fractions);
    ``harmonics`` N (N × N Fourier orders) and ``seconds`` per wavelength."""

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
