"""Depth-wavelength symmetry of a diffractive lens (Suppl. Note 1 of the paper).

A lens designed to focus a plane wave of wavelength λd at distance f focuses, on the same
plane, a point source of wavelength λ placed at depth (paraxial model)

    z(λ) = λd · f / (λ − λd),         λ(z) = λd · (1 + f / z),

and a depth step Δz maps to a wavelength step Δλ = λ1 − λ2 with z2 = z1 − Δz:

    Δλ = λd · f · (1/z1 − 1/(z1 − Δz)).

λ → λd gives z → ∞ (the asymptote); λ < λd gives z < 0, a virtual source with no real
depth. All values in metres. Pure Python so that the command answers instantly.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from metalens_cli import arguments
from metalens_cli.errors import InputError

DEFAULT_WAVELENGTHS_M = tuple(float(f"{(400 + 10 * i) * 1e-9:.12g}") for i in range(31))  # 400-700 nm


@dataclass(frozen=True)
class DepthRow:
    """The depth at which ``wavelength_m`` focuses on the design plane.

    ``kind`` is ``"real"`` (finite depth), ``"infinite"`` (λ = λd: a plane wave) or
    ``"virtual"`` (λ < λd: z < 0, no real depth); ``depth_m`` is None unless ``"real"``.
    """

    wavelength_m: float
    depth_m: float | None
    kind: str


def _check_lens(lambda_d_m: float, f_m: float) -> None:
    arguments.positive(lambda_d_m, "lambda_d_m")
    arguments.positive(f_m, "f_m")


def depth_for_wavelength(wavelength_m: float, lambda_d_m: float, f_m: float) -> DepthRow:
    """z = λd·f/(λ − λd) for one wavelength, classified as real, infinite or virtual.

    Args:
        wavelength_m: the source wavelength λ (m), positive.
        lambda_d_m: the design wavelength λd (m), positive.
        f_m: the design focal length f (m), positive.

    Returns:
        A :class:`DepthRow`: ``kind`` ``"real"`` with ``depth_m`` z (m) for λ > λd, ``"infinite"``
        for λ = λd (within 1e-12 relative: a plane wave) and ``"virtual"`` for λ < λd (z < 0);
        ``depth_m`` None unless real.

    Examples:
        >>> row = depth_for_wavelength(550e-9, 500e-9, 4e-3)
        >>> row.kind, round(row.depth_m, 9)
        ('real', 0.04)
        >>> depth_for_wavelength(450e-9, 500e-9, 4e-3).kind
        'virtual'
    """
    _check_lens(lambda_d_m, f_m)
    arguments.positive(wavelength_m, "wavelength_m")
    difference = wavelength_m - lambda_d_m
    # Relative tolerance: a wavelength within 1e-12 of λd is λd (typed values round-trip exactly).
    if abs(difference) <= 1e-12 * lambda_d_m:
        return DepthRow(wavelength_m, None, "infinite")
    if difference < 0:
        return DepthRow(wavelength_m, None, "virtual")
    return DepthRow(wavelength_m, lambda_d_m * f_m / difference, "real")


def wavelength_for_depth(depth_m: float, lambda_d_m: float, f_m: float) -> float:
    """λ = λd·(1 + f/z): the wavelength a source at depth z focuses on the design plane.

    Args:
        depth_m: the source depth z (m), positive; ``inf`` gives λd.
        lambda_d_m: the design wavelength λd (m), positive.
        f_m: the design focal length f (m), positive.

    Returns:
        The wavelength λ (m).

    Examples:
        >>> round(wavelength_for_depth(0.04, 500e-9, 4e-3) * 1e9, 6)
        550.0
        >>> wavelength_for_depth(float("inf"), 500e-9, 4e-3)
        5e-07
    """
    _check_lens(lambda_d_m, f_m)
    arguments.positive(depth_m, "depth_m", allow_inf=True)
    return lambda_d_m * (1.0 + f_m / depth_m)


@dataclass(frozen=True)
class DeltaWavelength:
    """Δλ = λ1 − λ2 for depths z1 = ``at_depth_m`` and z2 = z1 − ``delta_z_m``."""

    at_depth_m: float
    delta_z_m: float
    delta_wavelength_m: float
    wavelength_at_depth_m: float
    wavelength_at_shifted_depth_m: float


def delta_wavelength(delta_z_m: float, at_depth_m: float, lambda_d_m: float, f_m: float) -> DeltaWavelength:
    """Δλ = λd·f·(1/z − 1/(z − Δz)); z − Δz must stay a real (positive) depth."""
    shifted = at_depth_m - delta_z_m
    if not shifted > 0:
        raise InputError(
            "--delta-z",
            f"z − Δz = {shifted:.6g} m is not a real depth",
            "a depth step smaller than --at-depth",
        )
    inverse_z = 0.0 if math.isinf(at_depth_m) else 1.0 / at_depth_m
    delta = lambda_d_m * f_m * (inverse_z - 1.0 / shifted)
    return DeltaWavelength(
        at_depth_m=at_depth_m,
        delta_z_m=delta_z_m,
        delta_wavelength_m=delta,
        wavelength_at_depth_m=wavelength_for_depth(at_depth_m, lambda_d_m, f_m),
        wavelength_at_shifted_depth_m=wavelength_for_depth(shifted, lambda_d_m, f_m),
    )


@dataclass(frozen=True)
class SymmetryTable:
    """The model for one lens (``f_m``, ``lambda_d_m``): the depth of each wavelength, the
    wavelength focused from each depth as ``(depth_m, wavelength_m)``, and Δλ for a depth step
    (None without one)."""

    f_m: float
    lambda_d_m: float
    rows: list[DepthRow]
    focused: list[tuple[float, float]]
    delta: DeltaWavelength | None

    def report(self) -> dict:
        """JSON-able: ``f_m``, ``lambda_d_m``, ``rows``, ``focused_wavelengths`` and ``delta``
        when there is one."""
        out = {
            "f_m": self.f_m,
            "lambda_d_m": self.lambda_d_m,
            "rows": [asdict(r) for r in self.rows],
            "focused_wavelengths": [{"depth_m": z, "wavelength_m": w} for z, w in self.focused],
        }
        if self.delta is not None:
            out["delta"] = asdict(self.delta)
        return out


def symmetry_table(
    f_m: float,
    lambda_d_m: float,
    wavelengths_m=DEFAULT_WAVELENGTHS_M,
    depths_m=(),
    delta_z_m: float | None = None,
    at_depth_m: float | None = None,
) -> SymmetryTable:
    """Depths of ``wavelengths_m``, wavelengths of ``depths_m`` and, given ``delta_z_m`` and
    ``at_depth_m``, the Δλ of that step."""
    rows = [depth_for_wavelength(w, lambda_d_m, f_m) for w in wavelengths_m]
    focused = [(z, wavelength_for_depth(z, lambda_d_m, f_m)) for z in depths_m]
    delta = None if delta_z_m is None else delta_wavelength(delta_z_m, at_depth_m, lambda_d_m, f_m)
    return SymmetryTable(f_m, lambda_d_m, rows, focused, delta)
