"""Fabrication errors of a geometric-phase lens: what they do to the focused light, and drawn maps.

A fabricated lens is its design plus errors. Each error changes, per meta-atom n, the converted
(cross-polarised) amplitude a_n·exp(i·2θ_n); the sensor sees

- the *coherent* part, the design's field times E[a_n·e^{iδφ_n}]: the design's PSF scaled by the
  power factor κ = |E[a·e^{iδφ}]|² / |a₀|² (for errors whose statistics are the same at every
  site; a factor that varies over the pupil, stitching's, is averaged over it below);
- the *scattered* part, E|a|² − |E a|²: light whose phase varies from fin to fin. Independent
  per fin, it leaves each pitch-p cell as a sub-wavelength source and spreads over the whole
  forward hemisphere; near the axis it lands on the sensor at :func:`veil_per_pixel`
  (p·a_px/(λ·d))² of its power per pixel: a flat veil;
- the unconverted (co-polarised) light, which the analyzer mostly removes (``optics.zero_order``).

Positional and rotational errors are phase errors δφ (this module); dimensional errors change
a_n (``io.fin_variations``, by RCWA). With N ≫ 1 independent fins the fabricated lens equals
this expectation to O(1/√N) in its coherent part (the law of large numbers), so a radial design
keeps a radial description; :func:`fabricated_map` draws a 2-D realisation for the slow exact
path (``imaging.tolerance``'s Monte Carlo).

Error models (θ in rad; the phase is φ = 2θ):

- rotation: every fin rotated by δθ ~ N(0, σ²), independently: κ = exp(−(2σ)²) (Maréchal's form,
  exact for Gaussian errors);
- θ levels N: data preparation rounds θ to multiples of π/N (φ to N levels over 2π): where θ
  sweeps many periods the error is uniform in ±π/N of phase, κ = sinc²(π/N) = (sin(π/N)/(π/N))²;
- stitching: each write field of side L (a square grid from the pupil's corner) is placed with
  an offset d ~ N(0, σ²) per axis; its fins carry the phase φ(x − d) ≈ φ(x) − d·∇φ(x), so at x
  E[e^{iδφ}] = exp(−σ²|∇φ(x)|²/2): an apodisation growing towards the rim, where ∇φ is steepest;
  κ is the square of its pupil mean (the Strehl ratio of a focusing lens; the light it removes
  stays within λd/L of the focus, left out of the veil);
- missing fins, a fraction p: a missing fin converts nothing (its light leaves co-polarised, as
  through clear glass): coherent (1 − p)²η, scattered p(1 − p)η, unconverted 1 − η + pη.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
import torch

from metalens_cli.arguments import number
from metalens_cli.errors import InputError
from metalens_cli.optics.lens import Metalens

OPTIONS = {  # field → the CLI option (and preset key) that sets it
    "rotation_sigma_rad": "--rotation-sigma",
    "theta_levels": "--theta-levels",
    "missing": "--missing",
    "stitch_field_m": "--stitch-field",
    "stitch_sigma_m": "--stitch-sigma",
    "width_bias_m": "--width-bias",
    "width_sigma_m": "--width-sigma",
    "length_bias_m": "--length-bias",
    "length_sigma_m": "--length-sigma",
}
POSITIONAL = ("rotation_sigma_rad", "theta_levels", "stitch_sigma_m")  # phase errors: the 2-D θ map
DIMENSIONAL = ("missing", "width_bias_m", "width_sigma_m", "length_bias_m", "length_sigma_m")  # the fin: RCWA
DEFAULT_STITCH_FIELD_M = 100e-6  # a common e-beam write field


@dataclass(frozen=True)
class FabricationErrors:
    """The error sources of one fabricated lens and their magnitudes (SI units, rad).

    Attributes:
        rotation_sigma_rad: σ of each fin's rotation error (rad), independent per fin.
        theta_levels: θ rounded to this many levels per π by data preparation (None: exact).
        missing: fraction of fins missing (0..1), independent per fin.
        stitch_field_m: side of the e-beam writer's square write field (m).
        stitch_sigma_m: σ per axis of each write field's placement offset (m).
        width_bias_m: every fin's width off by this much (m); lengths likewise ``length_bias_m``.
        width_sigma_m: σ of each fin's width about the biased width (m); ``length_sigma_m`` likewise.
    """

    rotation_sigma_rad: float = 0.0
    theta_levels: int | None = None
    missing: float = 0.0
    stitch_field_m: float = DEFAULT_STITCH_FIELD_M
    stitch_sigma_m: float = 0.0
    width_bias_m: float = 0.0
    width_sigma_m: float = 0.0
    length_bias_m: float = 0.0
    length_sigma_m: float = 0.0

    def __post_init__(self) -> None:
        """Each magnitude checked, naming its option: σ ≥ 0, levels ≥ 2, a fraction in [0, 1)."""
        for name in ("rotation_sigma_rad", "stitch_sigma_m", "width_sigma_m", "length_sigma_m"):
            number(getattr(self, name), OPTIONS[name], lo=0.0, form="a standard deviation ≥ 0 with its unit")
        for name in ("width_bias_m", "length_bias_m"):
            number(getattr(self, name), OPTIONS[name], form="a length with its unit, e.g. 10nm or -5nm")
        number(self.missing, "--missing", lo=0.0, hi=1.0, open_hi=True, form="a fraction in [0, 1), e.g. 0.1%")
        number(self.stitch_field_m, "--stitch-field", lo=0.0, open_lo=True, form="a positive length, e.g. 100um")
        levels = self.theta_levels
        if levels is not None and (isinstance(levels, bool) or not isinstance(levels, int) or levels < 2):
            raise InputError("--theta-levels", repr(levels), "an integer number of levels ≥ 2")

    def sources(self) -> list[str]:
        """The fields that differ from an error-free lens (their order in the dataclass)."""
        free = FabricationErrors()
        return [
            f.name
            for f in fields(self)
            if f.name != "stitch_field_m" and getattr(self, f.name) != getattr(free, f.name)
        ]

    def only(self, name: str) -> FabricationErrors:
        """These errors with every source but ``name`` removed (the write field kept)."""
        return FabricationErrors(**{name: getattr(self, name), "stitch_field_m": self.stitch_field_m})

    def dimensional(self) -> bool:
        """True when a fin size changes (its η and unconverted light need the nanofin model)."""
        return any(getattr(self, name) for name in DIMENSIONAL[1:])


def rotation_factor(sigma_rad: float) -> float:
    """κ of fin rotations δθ ~ N(0, σ²): |E e^{2iδθ}|² = exp(−(2σ)²)."""
    return math.exp(-((2 * sigma_rad) ** 2))


def quantization_factor(levels: int | None) -> float:
    """κ of θ rounded to N levels per π (phase error uniform in ±π/N): sinc²(π/N); 1 for None."""
    if levels is None:
        return 1.0
    x = math.pi / levels
    return (math.sin(x) / x) ** 2


def phase_gradient(lens: Metalens) -> tuple[np.ndarray, np.ndarray]:
    """|∇φ| (rad/m) at every site of a 2-D map (central differences on the grid) and the pupil
    mask (r ≤ D/2)."""
    phi = 2 * lens.theta.detach().double().cpu().numpy()
    gy, gx = np.gradient(phi, lens.pitch_m)
    _, r = lens.grid_phase(torch.float64)
    return np.hypot(gx, gy), r.numpy() <= lens.radius_m


def stitching_factor(lens: Metalens, sigma_m: float) -> float:
    """κ of write-field offsets d ~ N(0, σ²) per axis: the squared pupil mean of
    exp(−σ²|∇φ|²/2) (module docstring): over the meta-atom sites of a 2-D map; for a radial
    lens, over the pupil's area from its profile (∫ g(r)·r dr / ∫ r dr, trapezoids at its
    samples: the site mean to O(pitch/D))."""
    if sigma_m == 0:
        return 1.0
    if lens.radial:
        theta = lens.theta.detach().double().cpu().numpy()
        r = np.arange(theta.size) * lens.pitch_m
        inside = r <= lens.radius_m
        g = np.exp(-0.5 * (sigma_m * np.gradient(2 * theta, lens.pitch_m)) ** 2)[inside]
        w = r[inside]
        return float(np.trapezoid(g * w, r[inside]) / np.trapezoid(w, r[inside])) ** 2
    grad, inside = phase_gradient(lens)
    return float(np.mean(np.exp(-0.5 * (sigma_m * grad[inside]) ** 2))) ** 2


def phase_factor(lens: Metalens, errors: FabricationErrors) -> float:
    """κ of the positional and rotational errors together (independent: the factors multiply)."""
    return (
        rotation_factor(errors.rotation_sigma_rad)
        * quantization_factor(errors.theta_levels)
        * stitching_factor(lens, errors.stitch_sigma_m)
    )


def veil_per_pixel(site_pitch_m: float, pixel_pitch_m: float, wavelength_m: float, distance_m: float) -> float:
    """Fraction of the scattered power that lands on one sensor pixel near the axis:
    (p·a/(λ·d))² for cells of pitch p, pixels of pitch a, at distance d.

    Independent cells of side p radiate the angular spectrum p²·sinc²(p·ν) per unit power, flat
    (≈ p²) for p < λ over the propagating frequencies |ν| < 1/λ; near the axis a frequency ν lands
    at x = λ·d·ν on the sensor, so a pixel of side a collects (a/(λd))²·p² of it."""
    return (site_pitch_m * pixel_pitch_m / (wavelength_m * distance_m)) ** 2


def quantize(theta: np.ndarray, levels: int | None) -> np.ndarray:
    """θ rounded to the nearest of ``levels`` levels per π (multiples of π/N); None: unchanged.
    What data preparation writes: ``export-gds --angles N`` (``io.layout.quantise``) uses it too."""
    if levels is None:
        return theta
    step = math.pi / levels
    return np.rint(theta / step) * step


def fabricated_map(lens: Metalens, errors: FabricationErrors, rng: np.random.Generator) -> Metalens:
    """One drawn 2-D realisation of ``lens`` with the positional and rotational ``errors``.

    The design's θ on the M × M grid (a radial profile sampled at each site's radius) is placed
    by write field (a radial design: θ(|x − d|) exactly; a 2-D map: θ − d·∇θ, first order in d),
    rounded to ``theta_levels`` (data preparation acts on the design, before the writer) and given
    independent rotation errors. Dimensional errors are not drawn here (they change the fins'
    amplitude: ``imaging.tolerance`` applies them in expectation).

    Returns:
        A 2-D :class:`Metalens` with the same pitch, aperture and focal length, θ in float64.
    """
    _, r = lens.grid_phase(torch.float64)
    m = r.shape[0]
    coords = (np.arange(m) - m // 2) * lens.pitch_m
    yy, xx = np.meshgrid(coords, coords, indexing="ij")
    if lens.radial:
        theta = lens.phase_at_radius(r.to(lens.theta.device)).detach().cpu().numpy() / 2
    else:
        theta = lens.theta.detach().double().cpu().numpy().copy()
    if errors.stitch_sigma_m > 0:
        field_m = errors.stitch_field_m
        origin = -lens.radius_m
        iy = np.floor((yy - origin) / field_m).astype(np.int64)
        ix = np.floor((xx - origin) / field_m).astype(np.int64)
        fields_per_side = int(iy.max()) + 1
        offsets = rng.normal(0.0, errors.stitch_sigma_m, size=(2, fields_per_side, fields_per_side))
        dy, dx = offsets[0][iy, ix], offsets[1][iy, ix]
        if lens.radial:
            shifted = torch.from_numpy(np.hypot(xx - dx, yy - dy))
            theta = lens.phase_at_radius(shifted.to(lens.theta.device)).detach().cpu().numpy() / 2
        else:
            gy, gx = np.gradient(theta, lens.pitch_m)
            theta = theta - dx * gx - dy * gy
    theta = quantize(theta, errors.theta_levels)
    if errors.rotation_sigma_rad > 0:
        theta = theta + rng.normal(0.0, errors.rotation_sigma_rad, size=theta.shape)
    return Metalens(torch.from_numpy(theta), lens.pitch_m, lens.aperture_m, lens.focal_length_m)
