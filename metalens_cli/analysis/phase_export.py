"""A design's phase as a surface lens-design programs read: the Binary 2 fit of a radial design,
the grid phase of a 2-D one, and the export that writes them (``metalens export-phase``).

A geometric-phase lens adds φ = 2θ at every wavelength, as OpticStudio's Binary 2 surface does:
phase(ρ) = M · Σ_{i=1..N} A_i ρ^{2i}, ρ = r / R_norm, in radians whatever the wavelength. The fit
is least squares over the design's own samples in the pupil (r = k·pitch ≤ D/2) of the unwrapped
φ(r) − φ(0). It is solved in a well-conditioned basis, ρ²·P_j(t) with P_j the Legendre polynomials
of t = 2ρ²/ρ²_max − 1, and then converted to the power series the file holds. The residual is
that of the power series as a reader evaluates it (Horner's rule in float64), so a fit whose
conversion loses digits at high order says so in its residual. Lengths in SI metres, phases in
radians; one wave is 2π rad.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.polynomial import legendre as leg
from numpy.polynomial import polynomial as poly

from metalens_cli.arguments import positive
from metalens_cli.constants import __version__
from metalens_cli.errors import InputError
from metalens_cli.io import phase_files
from metalens_cli.io.phase_files import Binary2Surface

MAX_TERMS = 64  # Binary 2 terms tried at most (OpticStudio takes more; float64 runs out long before)
DEFAULT_TOLERANCE_WAVES = 0.01  # max residual of the automatic order (0.01 wave = 2π·0.01 rad)
DEFAULT_WAVELENGTH_M = 550e-9  # the .zmx system wavelength of a design without a design wavelength
WAVE_RAD = 2 * math.pi


@dataclass(frozen=True)
class Binary2Fit:
    """A Binary 2 fit of a radial phase and how well its power series reproduces it.

    Attributes:
        surface: the :class:`~metalens_cli.io.phase_files.Binary2Surface` (M = 1).
        r_m: the radii fitted (m): the design's samples in the pupil.
        phase_rad: the unwrapped phase there less its value on the axis (rad).
        fitted_rad: the power series evaluated there as a reader does (rad).
        rms_rad, max_rad: the residual's root mean square and largest magnitude (rad).
        condition: the condition number of the least-squares system (orthogonal basis, scaled
            columns).
        rounding_rad: a bound of the float64 rounding in evaluating the power series,
            N·ε·max Σ|A_i|ρ^{2i} (rad): where it nears the residual, more terms cannot help.
    """

    surface: Binary2Surface
    r_m: np.ndarray
    phase_rad: np.ndarray
    fitted_rad: np.ndarray
    rms_rad: float
    max_rad: float
    condition: float
    rounding_rad: float

    def residual(self) -> dict:
        """The residual as JSON-ready numbers: rms and max in rad and in waves, samples, condition."""
        return {
            "rms_rad": self.rms_rad,
            "max_rad": self.max_rad,
            "rms_waves": self.rms_rad / WAVE_RAD,
            "max_waves": self.max_rad / WAVE_RAD,
            "samples": int(self.r_m.size),
            "condition": self.condition,
            "rounding_rad": self.rounding_rad,
        }


def radial_phase_samples(lens) -> tuple[np.ndarray, np.ndarray, float]:
    """The design's samples in the pupil: radii r_k = k·pitch ≤ D/2 (m), the phase 2θ unwrapped
    (steps of more than π between neighbours taken as 2π wraps) less its value on the axis (rad),
    and that axis value (rad)."""
    if not lens.radial:
        raise InputError("design", "a 2-D rotation map has no radial profile", "a radial design")
    theta = lens.theta.detach().cpu().numpy().astype(np.float64)
    k = np.arange(theta.size)
    inside = k * lens.pitch_m <= lens.radius_m * (1 + 1e-12)
    phase = np.unwrap(2 * theta[inside])
    return k[inside] * lens.pitch_m, phase - phase[0] + 0.0, float(phase[0]) + 0.0  # + 0.0: no −0


def fit_binary2(r_m: np.ndarray, phase_rad: np.ndarray, order: int, norm_radius_m: float) -> Binary2Fit:
    """Least-squares Binary 2 fit of ``phase_rad`` (rad, 0 on the axis) at radii ``r_m`` (m) with
    ``order`` terms A_1..A_N on (r/R_norm)^{2i}, R_norm = ``norm_radius_m``.

    Args:
        r_m: radii (m), at least ``order`` distinct ones above 0.
        phase_rad: the phase there (rad), with phase 0 at r = 0 (the series has no constant term).
        order: N, the number of terms (≥ 1).
        norm_radius_m: R_norm (m).

    Returns:
        The :class:`Binary2Fit` (residual of the power series as written).

    Raises:
        InputError: naming ``order`` (too many terms for the samples) or ``norm_radius_m``.
    """
    positive(norm_radius_m, "norm_radius_m")
    r = np.asarray(r_m, dtype=np.float64)
    y = np.asarray(phase_rad, dtype=np.float64)
    u = (r / norm_radius_m) ** 2
    u_max = float(u.max())
    if order < 1 or np.unique(u[u > 0]).size < order:
        raise InputError("order", f"{order} terms for {np.unique(u[u > 0]).size} samples off the axis", "fewer terms")
    t = 2 * u / u_max - 1
    columns = u[:, None] * leg.legvander(t, order - 1)  # ρ²·P_j(t): polynomials in ρ² without a constant
    scale = np.linalg.norm(columns, axis=0)
    scale[scale == 0] = 1
    c, *_ = np.linalg.lstsq(columns / scale, y, rcond=None)
    condition = float(np.linalg.cond(columns / scale))
    series_t = leg.leg2poly(c / scale)  # Σ c_j P_j as a power series in t
    series_u = _compose(series_t, 2.0 / u_max)
    coefficients = tuple(float(a) for a in np.concatenate([series_u, np.zeros(order)])[:order])
    surface = Binary2Surface(float(norm_radius_m), coefficients, 1)
    fitted = surface.phase(r) + 0.0  # + 0.0: no −0 on the axis
    residual = fitted - y
    magnitude = np.zeros_like(u)
    for a in reversed(coefficients):
        magnitude = (magnitude + abs(a)) * u
    return Binary2Fit(
        surface=surface,
        r_m=r,
        phase_rad=y,
        fitted_rad=fitted,
        rms_rad=float(np.sqrt(np.mean(residual**2))),
        max_rad=float(np.max(np.abs(residual))),
        condition=condition,
        rounding_rad=float(order * np.finfo(np.float64).eps * magnitude.max()),
    )


def _compose(series_t: np.ndarray, slope: float) -> np.ndarray:
    """Coefficients in u of Σ_k s_k t^k with t = slope·u − 1 (Horner's rule on power series)."""
    result = np.zeros(1)
    for s in reversed(series_t):
        result = poly.polyadd(poly.polymul(result, [-1.0, slope]), [s])
    return result


def choose_binary2(
    r_m: np.ndarray,
    phase_rad: np.ndarray,
    *,
    norm_radius_m: float,
    tolerance_rad: float,
    order: int | None = None,
    max_order: int = MAX_TERMS,
    field: str = "tolerance",
) -> Binary2Fit:
    """The fit with ``order`` terms, or (None) the one with the fewest terms, up to ``max_order``,
    whose largest residual is within ``tolerance_rad``.

    Raises:
        InputError: naming ``field`` (``tolerance``) when no order up to ``max_order`` meets it (the best
            residual reached, and its order, in the message).
    """
    if order is not None:
        return fit_binary2(r_m, phase_rad, order, norm_radius_m)
    best = None
    available = int(np.unique(np.asarray(r_m)[np.asarray(r_m) > 0]).size)
    for n in range(1, min(max_order, available) + 1):
        fit = fit_binary2(r_m, phase_rad, n, norm_radius_m)
        if fit.max_rad <= tolerance_rad:
            return fit
        if best is None or fit.max_rad < best.max_rad:
            best = fit
    raise InputError(
        field,
        f"no Binary 2 fit of up to {max_order} terms reaches a max residual of {tolerance_rad / WAVE_RAD:g} wave; "
        f"the best, {best.surface.order} terms, leaves {best.max_rad / WAVE_RAD:.4g} wave "
        f"({best.max_rad:.4g} rad; rms {best.rms_rad / WAVE_RAD:.4g} wave)",
        "a larger tolerance in waves, or --order N to write a fit anyway",
    )


@dataclass(frozen=True)
class PhaseExport:
    """What :func:`export_phase` wrote: JSON-ready through :meth:`to_dict`."""

    file: str
    format: str
    kind: str
    seconds: float
    order: int | None = None
    norm_radius_m: float | None = None
    residual: dict | None = None
    coefficients_rad: tuple[float, ...] | None = None
    sites: int | None = None
    files: tuple[str, ...] = ()

    def to_dict(self) -> dict:
        """The report as a JSON-ready dict (the fields by name)."""
        return {
            "file": self.file,
            "files": list(self.files),
            "format": self.format,
            "kind": self.kind,
            "order": self.order,
            "norm_radius_m": self.norm_radius_m,
            "residual": self.residual,
            "coefficients_rad": None if self.coefficients_rad is None else list(self.coefficients_rad),
            "sites": self.sites,
            "seconds": self.seconds,
        }


def export_phase(
    design,
    output: str,
    *,
    order: int | None = None,
    tolerance_waves: float = DEFAULT_TOLERANCE_WAVES,
    tolerance_given: bool = False,
    norm_radius_m: float | None = None,
) -> tuple[PhaseExport, list[str]]:
    """Write ``design``'s phase to ``output`` by its suffix (.zmx, .json, .csv, .dat) and report it.

    A radial design is fitted (:func:`choose_binary2`; R_norm defaults to D/2); a 2-D design is
    written as its grid phase (.json with a .npy sidecar, or .csv; .zmx refused); .dat writes
    either as OpticStudio Grid Phase data on the meta-atom grid (a radial profile at each site). With an explicit
    ``order`` whose residual exceeds the tolerance, the file is written and a warning returned,
    unless the tolerance was given too (``tolerance_given``): then it is refused.

    Returns:
        The :class:`PhaseExport` and the warnings (lines for stderr).

    Raises:
        InputError: naming ``--output``, ``--order``, ``--tolerance`` or ``--norm-radius``.
    """
    start = time.perf_counter()
    suffix = Path(output).suffix.lower()
    lens = design.lens
    warnings: list[str] = []
    if not lens.radial or suffix == ".dat":
        return _export_grid(design, output, suffix, start, order, norm_radius_m, tolerance_given), warnings
    radius = lens.radius_m if norm_radius_m is None else norm_radius_m
    tolerance_rad = tolerance_waves * WAVE_RAD
    r, phase, axis_phase = radial_phase_samples(lens)
    fit = choose_binary2(r, phase, norm_radius_m=radius, tolerance_rad=tolerance_rad, order=order, field="--tolerance")
    if fit.max_rad > tolerance_rad:
        message = (
            f"{order} terms leave a max residual of {fit.max_rad / WAVE_RAD:.4g} wave "
            f"({fit.max_rad:.4g} rad), above the tolerance {tolerance_waves:g} wave"
        )
        if tolerance_given:
            raise InputError("--tolerance", message, "more terms (--order) or a larger tolerance")
        warnings.append(message)
    if fit.rounding_rad > 0.1 * max(fit.max_rad, 1e-300):
        warnings.append(
            f"the {fit.surface.order}-term power series loses digits in float64 (rounding up to "
            f"{fit.rounding_rad:.3g} rad): fewer terms or a larger --norm-radius keep it exact"
        )
    surface = fit.surface
    if suffix == ".zmx":
        wavelength = design.lambda_d_m or DEFAULT_WAVELENGTH_M
        phase_files.write_zmx(
            output,
            surface,
            aperture_m=lens.aperture_m,
            distance_m=design.focal_length_m,
            wavelength_m=wavelength,
            name=f"metalens export-phase {design.spec}",
        )
    elif suffix == ".json":
        header = phase_files.binary2_header(
            surface,
            design=design.describe(),
            aperture_m=lens.aperture_m,
            phase_at_axis_rad=axis_phase,
            residual=fit.residual(),
        )
        phase_files.write_phase_json(output, header)
    else:
        phase_files.write_radial_csv(output, fit.r_m, fit.phase_rad, fit.fitted_rad)
    report = PhaseExport(
        file=str(output),
        files=(str(output),),
        format=suffix[1:],
        kind="binary2",
        seconds=time.perf_counter() - start,
        order=surface.order,
        norm_radius_m=surface.norm_radius_m,
        residual=fit.residual(),
        coefficients_rad=surface.coefficients_rad,
    )
    return report, warnings


def grid_sites(lens) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x, y (m) and φ = 2θ (rad, as the design holds it) of every site of a 2-D map in the pupil,
    rows of increasing y, each of increasing x (row i is y, column j is x, axis at (M//2, M//2))."""
    phase = 2 * lens.theta.detach().cpu().numpy().astype(np.float64)
    m = phase.shape[0]
    c = (np.arange(m) - m // 2) * lens.pitch_m
    y, x = np.meshgrid(c, c, indexing="ij")
    inside = np.hypot(x, y) <= lens.radius_m * (1 + 1e-12)
    return x[inside], y[inside], phase[inside]


def _export_grid(design, output, suffix, start, order, norm_radius_m, tolerance_given) -> PhaseExport:
    lens = design.lens
    if suffix == ".zmx":
        raise InputError(
            "--output",
            "a 2-D design has no Binary 2 surface (a .zmx Grid Phase surface is not written)",
            "a .dat (OpticStudio Grid Phase data), .json (grid phase with a .npy map beside it) or .csv "
            "(x_m,y_m,phase_rad) output",
        )
    what = "a 2-D map" if not lens.radial else "a Grid Phase .dat"
    for option, value in (("--order", order), ("--norm-radius", norm_radius_m)):
        if value is not None:
            raise InputError(option, f"applies to a radial design's Binary 2 fit, not to {what}", "no " + option)
    if tolerance_given:
        raise InputError("--tolerance", f"applies to a radial design's Binary 2 fit, not to {what}", "no --tolerance")
    if suffix == ".dat":
        m = lens.grid_size
        if m > phase_files.MAX_DAT_SIDE:
            raise InputError(
                "--output",
                f"a Grid Phase .dat of this lens would hold {m} × {m} points "
                f"(about {phase_files.DAT_BYTES_PER_POINT * m * m / 1e9:.1f} GB of text)",
                f"at most {phase_files.MAX_DAT_SIDE} per side: a .json grid (with its .npy map) or, for a radial "
                "design, the Binary 2 .zmx",
            )
        import torch

        phase, r = lens.grid_phase(torch.float64)
        phase_files.write_grid_dat(
            output, phase.detach().cpu().numpy(), lens.pitch_m, r.numpy() <= lens.radius_m * (1 + 1e-12)
        )
        return PhaseExport(
            file=str(output),
            files=(str(output),),
            format="dat",
            kind="grid",
            seconds=time.perf_counter() - start,
            sites=m * m,
        )
    files = [str(output)]
    if suffix == ".json":
        phase = 2 * lens.theta.detach().cpu().numpy().astype(np.float64)
        m = phase.shape[0]
        header = {
            "format": phase_files.PHASE_FORMAT,
            "version": __version__,
            "kind": "grid",
            "design": design.describe(),
            "sign_convention": phase_files.SIGN_CONVENTION,
            "diffraction_order": 1,
            "aperture_m": lens.aperture_m,
            "pitch_m": lens.pitch_m,
            "grid_size": m,
            "axis_index": m // 2,
            "rows": "y",
            "columns": "x",
        }
        files.append(str(phase_files.write_grid_json(output, header, phase)))
        sites = m * m
    else:
        x, y, phase = grid_sites(lens)
        phase_files.write_grid_csv(output, x, y, phase)
        sites = int(phase.size)
    return PhaseExport(
        file=str(output),
        files=tuple(files),
        format=suffix[1:],
        kind="grid",
        seconds=time.perf_counter() - start,
        sites=sites,
    )
