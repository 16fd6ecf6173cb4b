"""On-axis focal intensity of a hyperbolic metalens over (wavelength, source depth).

Validates the depth-wavelength model numerically (the paper's Fig. 2b). An on-axis point
needs no field: the first Rayleigh-Sommerfeld integral on the axis of a rotationally
symmetric aperture field U0(r) at distance d is one radial integral,

    E(0, d) = ∫_0^a U0(r) · e^{ikR} · (d / R²) · (1/R − ik) · r dr,    R = √(r² + d²),

evaluated here in u = r² (r dr = du/2), where the defocus chirps become nearly linear, with
composite Simpson quadrature. U0 = (point source at depth z) × (lens transmission):
source amplitude z/√(r² + z²) and phase k·r²/(√(r² + z²) + z) (no cancellation; z = inf is a
plane wave), lens phase −(2π/λd)(√(r² + f²) − f). Units: metres; intensities relative.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from metalens_cli.analysis.symmetry import depth_for_wavelength

SAMPLES_PER_PERIOD = 12  # Simpson on ≥ 12 samples per phase period: relative error ≲ 1e-6


def _simpson_weights(n: int, h: float) -> np.ndarray:
    if n % 2 == 0:
        raise ValueError("Simpson's rule needs an odd number of samples")
    w = np.full(n, 2.0)
    w[1::2] = 4.0
    w[0] = w[-1] = 1.0
    return w * h / 3.0


def required_samples(
    wavelengths_m,
    depths_m,
    lambda_d_m: float,
    f_m: float,
    aperture_m: float,
    distance_m: float | None = None,
    per_period: int = SAMPLES_PER_PERIOD,
) -> int:
    """Odd number of u = r² samples giving ``per_period`` samples per period of the integrand's phase.

    dφ/du = k/(2√(u + z²)) + k/(2√(u + d²)) − kd/(2√(u + f²)) is monotone between its
    values at u = 0 and u = a², so its largest magnitude is at one of the two ends.
    """
    d = f_m if distance_m is None else distance_m
    a2 = (aperture_m / 2) ** 2
    kd = 2 * math.pi / lambda_d_m
    rate = 0.0
    for u in (0.0, a2):
        for wavelength in np.asarray(wavelengths_m, dtype=float):
            k = 2 * math.pi / wavelength
            for z in np.asarray(depths_m, dtype=float)[[0, -1]]:
                source = 0.0 if math.isinf(z) else k / (2 * math.sqrt(u + z * z))
                rate = max(rate, abs(source + k / (2 * math.sqrt(u + d * d)) - kd / (2 * math.sqrt(u + f_m * f_m))))
    n = math.ceil(rate * a2 / (2 * math.pi) * per_period) + 1
    return max(n + (n + 1) % 2, 65)


def on_axis_intensity(
    wavelengths_m: np.ndarray,
    depths_m: np.ndarray,
    lambda_d_m: float,
    f_m: float,
    aperture_m: float,
    *,
    distance_m: float | None = None,
    samples: int | None = None,
    chunk: int = 1 << 22,
) -> np.ndarray:
    """|E(0, d)|² for every (wavelength, depth), shape (W, Z); d defaults to f.

    Unit plane-wave amplitude at the lens; float64 throughout (torch, for its fast
    multi-threaded sin/cos). ``samples`` (odd) defaults to :func:`required_samples` for
    the extreme depths given (pass them sorted). ``chunk`` bounds the samples held at once.
    """
    import torch

    if samples is None:
        samples = required_samples(wavelengths_m, depths_m, lambda_d_m, f_m, aperture_m, distance_m)
    wavelengths = torch.as_tensor(np.asarray(wavelengths_m, dtype=np.float64))
    depths = torch.as_tensor(np.asarray(depths_m, dtype=np.float64))
    d = f_m if distance_m is None else distance_m
    a2 = (aperture_m / 2) ** 2
    u = torch.linspace(0.0, a2, samples, dtype=torch.float64)
    weights = torch.as_tensor(_simpson_weights(samples, a2 / (samples - 1)) * 0.5)  # r dr = du / 2
    r_prop = torch.sqrt(u + d * d)
    lens_phase = -(2 * math.pi / lambda_d_m) * (torch.sqrt(u + f_m * f_m) - f_m)
    finite = torch.isfinite(depths)[:, None]
    zf = torch.where(finite, depths[:, None], torch.ones_like(depths[:, None]))
    rz = torch.sqrt(u + zf * zf)
    source_chirp = torch.where(finite, u / (rz + zf), torch.zeros_like(rz))  # × k below
    weighted_amp = torch.where(finite, zf / rz, torch.ones_like(rz)) * weights  # (Z, S)
    out = torch.empty(wavelengths.numel(), depths.numel(), dtype=torch.float64)
    rows_per_chunk = max(1, chunk // (samples * max(depths.numel(), 1)))
    for start in range(0, wavelengths.numel(), rows_per_chunk):
        k = (2 * math.pi / wavelengths[start : start + rows_per_chunk])[:, None, None]
        phase = k * (source_chirp + r_prop) + lens_phase  # (W, Z, S)
        kernel_re = d / r_prop**3  # (d / R²)(1/R − ik) = kernel_re + i·kernel_im
        kernel_im = -k * d / r_prop**2
        cos, sin = torch.cos(phase), torch.sin(phase)
        re = ((cos * kernel_re - sin * kernel_im) * weighted_amp).sum(-1)
        im = ((sin * kernel_re + cos * kernel_im) * weighted_amp).sum(-1)
        out[start : start + rows_per_chunk] = re**2 + im**2
    return out.numpy()


@dataclass(frozen=True)
class ValidationRow:
    """Model depth λd·f/(λ − λd) beside the depth of maximum on-axis intensity at d = f."""

    wavelength_m: float
    model_depth_m: float | None
    best_depth_m: float | None
    rel_deviation: float | None


@dataclass(frozen=True)
class FocalValidation:
    """What :func:`validate_symmetry` found: a :class:`ValidationRow` per wavelength, the on-axis
    intensity ``intensity`` |E(0, f)|² (W, Z) for a unit plane wave over ``wavelengths_m`` (W,) and
    the log-spaced ``depths_m`` (Z,) (m), the quadrature's odd number of ``samples`` in u = r², its
    ``convergence`` (the largest relative change of a best depth when the samples are doubled) and
    the wall-clock ``seconds`` taken."""

    rows: tuple[ValidationRow, ...]
    wavelengths_m: np.ndarray
    depths_m: np.ndarray
    intensity: np.ndarray  # (W, Z), on-axis intensity on the depth grid
    samples: int
    convergence: float  # max relative change of the best depths when the quadrature is doubled
    seconds: float

    @property
    def max_abs_rel_deviation(self) -> float | None:
        """The largest |best − model| / model depth deviation over the wavelengths that have both
        depths; None when none has."""
        values = [abs(r.rel_deviation) for r in self.rows if r.rel_deviation is not None]
        return max(values) if values else None


def validation_report(v: FocalValidation, aperture_m: float) -> dict:
    """JSON-able: the lens diameter, the method, the model and best depth per wavelength, the
    largest deviation, the depth range, the quadrature and its convergence, the seconds."""
    return {
        "aperture_m": aperture_m,
        "method": "on-axis Rayleigh-Sommerfeld integral, Simpson in r², Brent refinement in log z",
        "rows": [asdict(r) for r in v.rows],
        "max_abs_rel_deviation": v.max_abs_rel_deviation,
        "depth_range_m": [float(v.depths_m[0]), float(v.depths_m[-1])],
        "quadrature_samples": v.samples,
        "convergence_rel": v.convergence,
        "seconds": v.seconds,
    }


def _best_depth(wavelength, lambda_d, f, aperture, lo, hi, samples, fine_points: int = 81) -> float:
    """Maximise on-axis intensity over z in [lo, hi]: a fine log grid (the focal peak is a few
    percent wide and has side lobes), then bounded Brent in log z around the best sample."""
    from scipy.optimize import minimize_scalar

    fine = np.geomspace(lo, hi, fine_points)
    values = on_axis_intensity(np.array([wavelength]), fine, lambda_d, f, aperture, samples=samples)[0]
    j = int(np.clip(np.argmax(values), 1, fine_points - 2))

    def negative(log_z):
        return -on_axis_intensity(
            np.array([wavelength]), np.array([math.exp(log_z)]), lambda_d, f, aperture, samples=samples
        )[0, 0]

    bounds = (math.log(fine[j - 1]), math.log(fine[j + 1]))
    result = minimize_scalar(negative, bounds=bounds, method="bounded", options={"xatol": 1e-8})
    return math.exp(result.x)


PHASE_RATE = 1e8  # (wavelength, depth, sample) terms of the on-axis integral per second, 2 cores


def estimate_validation(
    wavelengths_m,
    lambda_d_m: float,
    f_m: float,
    aperture_m: float,
    depth_range_m: tuple[float, float] | None = None,
    depth_points: int = 161,
) -> tuple[int, float]:
    """(peak bytes, seconds) of :func:`validate_symmetry` with these arguments, from its sample
    count: about a dozen float64 (depth × sample) arrays at once (the per-depth factors and a
    chunk of the integrand), and every term of the map and of the refinements (~106 depths per
    wavelength at S and 2S samples) at ``PHASE_RATE``."""
    wavelengths = np.asarray(wavelengths_m, dtype=np.float64)
    if depth_range_m is None:
        real = [
            m for m in (depth_for_wavelength(float(w), lambda_d_m, f_m).depth_m for w in wavelengths) if m is not None
        ]
        depth_range_m = (max(1e-3, 0.5 * min(real, default=1e-3)), 1e3)
    depths = np.geomspace(depth_range_m[0], depth_range_m[1], depth_points)
    samples = required_samples(wavelengths, depths, lambda_d_m, f_m, aperture_m)
    terms = wavelengths.size * samples * (depth_points + 106 * 3)
    return 12 * depth_points * samples * 8, terms / PHASE_RATE


def validate_symmetry(
    wavelengths_m,
    lambda_d_m: float,
    f_m: float,
    aperture_m: float,
    depth_range_m: tuple[float, float] | None = None,
    depth_points: int = 161,
    progress=None,
) -> FocalValidation:
    """On-axis intensity map over a log depth grid and, per wavelength, the refined best depth.

    The depth range defaults to [max(1 mm, half the smallest model depth), 1 km]. A
    wavelength whose maximum lies on the edge of the range (λ ≤ λd: no real focus, or a
    focus beyond it) gets ``best_depth_m = None``. ``progress(i, total)`` is
    called after each wavelength. Accuracy: the best depths are recomputed with twice the
    quadrature samples and the largest relative change is returned as ``convergence``.
    """
    import time

    start = time.perf_counter()
    wavelengths = np.asarray(wavelengths_m, dtype=np.float64)
    models = [depth_for_wavelength(float(w), lambda_d_m, f_m).depth_m for w in wavelengths]
    if depth_range_m is None:
        real = [m for m in models if m is not None]
        depth_range_m = (max(1e-3, 0.5 * min(real, default=1e-3)), 1e3)
    depths = np.geomspace(depth_range_m[0], depth_range_m[1], depth_points)
    samples = required_samples(wavelengths, depths, lambda_d_m, f_m, aperture_m)
    intensity = on_axis_intensity(wavelengths, depths, lambda_d_m, f_m, aperture_m, samples=samples)
    rows, changes = [], []
    for i, wavelength in enumerate(wavelengths):
        j = int(np.argmax(intensity[i]))
        model = models[i]
        if 0 < j < depths.size - 1:
            lo, hi = depths[j - 1], depths[j + 1]
            best = _best_depth(wavelength, lambda_d_m, f_m, aperture_m, lo, hi, samples)
            check = _best_depth(wavelength, lambda_d_m, f_m, aperture_m, lo, hi, 2 * samples - 1)
            changes.append(abs(check - best) / best)
        else:
            best = None
        deviation = (best - model) / model if best is not None and model is not None else None
        rows.append(ValidationRow(float(wavelength), model, best, deviation))
        if progress is not None:
            progress(i + 1, wavelengths.size)
    return FocalValidation(
        rows=tuple(rows),
        wavelengths_m=wavelengths,
        depths_m=depths,
        intensity=intensity,
        samples=samples,
        convergence=max(changes) if changes else 0.0,
        seconds=time.perf_counter() - start,
    )
