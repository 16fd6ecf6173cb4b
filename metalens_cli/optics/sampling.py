"""Sampling plans for the propagators, derived from the geometry, and the guard that refuses
grids that would alias or wrap around (``SamplingError``; ``force=True`` proceeds anyway).

The local spatial frequency of the field leaving the lens, f(r) = |d(φ_lens + φ_source)/dr|/2π
(cycles/m), sets every sample count: the meta-atom grid resolves it only if f ≤ 1/(2p); the
propagators keep frequencies up to sin(θ_lim)/λ with sin(θ_lim) = λ·f_max + margin, and their
support is large enough that waves up to θ_lim cannot wrap (asm) or reflect (radial) into the
sensor window. ``oversample`` scales margins and sample densities (2 = the doubled-sampling check).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from metalens_cli import arguments
from metalens_cli.errors import InputError, SamplingError
from metalens_cli.optics.lens import Metalens
from metalens_cli.optics.propagate import AsmGrid, fft_size
from metalens_cli.optics.sensor import radial_sensor_radii
from metalens_cli.optics.source import source_frequency

MAX_FFT_SIZE = 32768
MAX_HANKEL_SIZE = 40000
ANGLE_MARGIN = 0.1  # sin-angle kept beyond the field's steepest ray (edge diffraction), × oversample
RADIAL_MARGIN = 2 * ANGLE_MARGIN  # the radial path's (the doubled margin, plan_radial); sin-angle
# the off-axis grid's guard beyond the light's reach a + W/2, each side, in Fresnel lengths √(λd): the edge of the kept
# band blurs the kernel's cut over about one. 40 µm lens at 10° against the direct sum: 0 → 5.2e-3, 1 → 1.8e-3,
# 2 → 7e-4, 3 → 5.3e-4 (6 → 5.2e-4)
REACH_FRESNEL = 3.0


@dataclass(frozen=True)
class PsfGrid:
    """Where a PSF computation samples: the (depth, wavelength) axes and the sensor window.

    The fields are checked and normalised on construction (``metalens_cli.arguments``; errors name
    ``wavelengths``, ``depths``, ``pixels``, ``pixel_pitch``, ``distance``), so a grid is valid
    wherever it travels; ``replace`` gives a checked copy with other values.

    Args:
        wavelengths_m: wavelengths (m), one or more, positive and finite.
        depths_m: source depths (m) from the lens, positive; ``math.inf`` is a plane wave.
        pixels: the sensor window is ``pixels`` × ``pixels``, centred on the axis pixel
            (``pixels // 2``, ``pixels // 2``).
        pixel_pitch_m: sensor pixel pitch (m).
        distance_m: lens-to-sensor distance (m); None: the lens's focal length, resolved where the
            lens is known (:meth:`distance`, :meth:`resolved`).

    Example:
        >>> grid = PsfGrid([532e-9], [math.inf], 33, 0.5e-6)
        >>> grid.replace(wavelengths_m=[450e-9, 650e-9]).wavelengths_m
        (4.5e-07, 6.5e-07)
    """

    wavelengths_m: tuple[float, ...]
    depths_m: tuple[float, ...]
    pixels: int
    pixel_pitch_m: float
    distance_m: float | None = None

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "wavelengths_m", tuple(arguments.lengths(self.wavelengths_m, "wavelengths")))
        set_(self, "depths_m", tuple(arguments.lengths(self.depths_m, "depths", allow_inf=True)))
        arguments.count(self.pixels, "pixels")
        set_(self, "pixels", int(self.pixels))
        set_(self, "pixel_pitch_m", float(arguments.positive(self.pixel_pitch_m, "pixel_pitch")))
        if self.distance_m is not None:
            set_(self, "distance_m", float(arguments.positive(self.distance_m, "distance")))

    @property
    def count(self) -> int:
        """How many PSFs the grid holds: depths × wavelengths."""
        return len(self.wavelengths_m) * len(self.depths_m)

    def replace(self, **changes) -> PsfGrid:
        """A checked copy with ``changes`` (field names as above), e.g. other wavelengths or depths."""
        return dataclasses.replace(self, **changes)

    def distance(self, lens: Metalens) -> float:
        """The lens-to-sensor distance (m): ``distance_m``, or ``lens``'s focal length when it is None."""
        d = lens.focal_length_m if self.distance_m is None else self.distance_m
        if d is None:
            raise InputError("distance", "is None and the lens has no focal length", "a lens-to-sensor distance (m)")
        return float(arguments.positive(d, "distance"))

    def resolved(self, lens: Metalens) -> PsfGrid:
        """This grid with its distance resolved for ``lens`` (:meth:`distance`)."""
        d = self.distance(lens)
        return self if self.distance_m == d else dataclasses.replace(self, distance_m=d)


def psf_grid(value, name: str = "grid") -> PsfGrid:
    """``value`` if it is a :class:`PsfGrid` (``arguments.instance``: errors name ``name``)."""
    return arguments.instance(
        value, name, PsfGrid, "a PsfGrid (ml.PsfGrid(wavelengths_m, depths_m, pixels, pixel_pitch_m))"
    )


def window_radius(n_pixels: int, pixel_pitch_m: float) -> float:
    """Distance (m) from the axis to the farthest window corner."""
    return math.hypot(n_pixels // 2 + 0.5, n_pixels // 2 + 0.5) * pixel_pitch_m


def lens_frequency(lens: Metalens) -> tuple[float, float]:
    """Largest local frequency (cycles/m) of the lens phase inside the pupil and its radius (m).

    Radial: from consecutive samples; 2-D: the larger of the x and y steps between neighbouring
    sites, phase steps wrapped to (−π, π] (a map given modulo π in θ is fine).
    """
    theta = lens.theta.detach().double().cpu().numpy()
    p = lens.pitch_m
    if lens.radial:
        r = (np.arange(theta.shape[0] - 1) + 0.5) * p
        step = np.abs(np.diff(2 * theta))[r <= lens.radius_m + p]
        k = int(np.argmax(step))
        return float(step[k] / (2 * math.pi * p)), float(r[k])
    theta = lens.theta.detach().double().cpu().numpy()
    m = theta.shape[0]
    c = (np.arange(m) - m // 2) * p
    inside = np.hypot(c[:, None], c[None, :]) <= lens.radius_m
    worst, at = 0.0, 0.0
    for axis in (0, 1):
        # Wrap 2·Δθ to (−π, π] arithmetically (np.angle(np.exp(2j·Δθ)) costs 3× more here).
        step = np.abs(np.remainder(2 * np.diff(theta, axis=axis) + math.pi, 2 * math.pi) - math.pi)
        both = inside[1:, :] & inside[:-1, :] if axis == 0 else inside[:, 1:] & inside[:, :-1]
        step = np.where(both, step, 0.0)
        if step.max() > worst:
            i, j = np.unravel_index(np.argmax(step), step.shape)
            worst, at = float(step[i, j]), float(np.hypot(c[i], c[j]))
    return worst / (2 * math.pi * p), at


def source_frequency_max(lens: Metalens, wavelengths_m, depths_m) -> float:
    """Largest local frequency (cycles/m) of the source phase over the pupil (at its rim)."""
    return max(source_frequency(lens.radius_m, min(wavelengths_m), z) for z in depths_m)


def check_lens_sampling(lens: Metalens, wavelengths_m, depths_m, force: bool) -> float:
    """Refuse when the meta-atom grid cannot resolve lens + source phase (f > 1/(2p)).

    Returns the field's maximum local frequency (cycles/m), rounded up to a step of 2^(1/16)
    so that the plans built from it do not move with small changes of θ (exact gradients).
    """
    f_lens, r_lens = lens_frequency(lens)
    f_max = f_lens + source_frequency_max(lens, wavelengths_m, depths_m)  # upper bound for lens + source
    nyquist = 1 / (2 * lens.pitch_m)
    if f_max > nyquist and not force:
        z_min = min(depths_m)
        raise SamplingError(
            "pitch",
            f"the field leaving the lens reaches {f_max * 1e-3:.4g} cycles/mm (lens phase "
            f"{f_lens * 1e-3:.4g} cycles/mm at r = {r_lens * 1e3:.4g} mm, source at z = {z_min:g} m "
            f"adds the rest) but the meta-atom pitch {lens.pitch_m:g} m resolves only "
            f"{nyquist * 1e-3:.4g} cycles/mm",
            f"a pitch ≤ {1 / (2 * f_max):.4g} m, a shallower lens phase (a smaller aperture or longer f) or a more "
            "distant source",
            forceable=True,
        )
    return 2.0 ** (math.ceil(16 * math.log2(max(f_max, 1.0))) / 16)


@dataclass(frozen=True)
class RadialPlan:
    """Hankel-path sampling: support radius R (m), frequency count, Gauss nodes on the pupil,
    sin of the band-limit angle at the longest λ (each λ keeps sin_limit(λ)/λ), and the output
    radial step (m) with its sample count."""

    radius_m: float
    n_freq: int
    n_nodes: int
    sin_limit: float
    step_m: float
    n_radii: int


def sin_limit(f_max: float, wavelengths_m, oversample: float, margin: float = ANGLE_MARGIN) -> float:
    """sin of the band-limit angle: the field's steepest ray at the longest λ plus ``margin`` ×
    ``oversample`` (sin-angle)."""
    return min(0.99, max(wavelengths_m) * f_max + margin * oversample)


def frequency_limit(f_max: float, wavelengths_m, oversample: float, margin: float = ANGLE_MARGIN) -> float:
    """Largest kept spatial frequency (cycles/m) over the wavelengths: max_λ sin_limit(λ)/λ."""
    return max(sin_limit(f_max, [lam], oversample, margin) / lam for lam in wavelengths_m)


def plan_radial(
    lens: Metalens, grid: PsfGrid, f_max: float, oversample: float = 1.0, margin: float = RADIAL_MARGIN
) -> RadialPlan:
    """Sampling for ``radial_propagate`` from the geometry (see the module docstring) over ``grid``'s
    wavelengths, window and distance (its depths do not enter).

    The angle margin ``margin`` (sin-angle, × ``oversample``) is doubled by default (``RADIAL_MARGIN``: the
    radial path is cheap; a training step takes ``[optimize] radial_margin``). R = (a + ρ_w + d·tan θ_lim)/2
    keeps waves up to θ_lim from reflecting at R into the window of radius ρ_w; n_freq = 2R·ν_max with
    ν_max = max_λ sin θ_lim(λ)/λ; Gauss nodes 3 per cycle of the forward integrand; output step 1/(8·ν_max):
    the intensity, band-limited to 2·ν_max, is sampled 4× above Nyquist for the cubic pixel integration.
    """
    wavelengths_m, distance_m, n_pixels, pixel_pitch_m = (
        grid.wavelengths_m,
        grid.distance(lens),
        grid.pixels,
        grid.pixel_pitch_m,
    )
    a, rho_w = lens.radius_m, window_radius(n_pixels, pixel_pitch_m)
    sin_lim = sin_limit(f_max, wavelengths_m, oversample, margin)
    tan_lim = sin_lim / math.sqrt(1 - sin_lim**2)
    radius = max((a + rho_w + distance_m * tan_lim) / 2, 1.05 * max(a, rho_w))
    nu_max = frequency_limit(f_max, wavelengths_m, oversample, margin)
    n_freq = math.ceil(2 * radius * nu_max * 1.05 * math.sqrt(oversample))
    n_nodes = 16 * math.ceil(3 * (f_max + nu_max) * a * oversample / 16)
    step = 1 / (8 * nu_max * oversample)
    plan = RadialPlan(radius, n_freq, n_nodes, sin_lim, step, radial_sensor_radii(step, n_pixels, pixel_pitch_m))
    if n_freq > MAX_HANKEL_SIZE:
        raise SamplingError(
            "aperture",
            f"the radial propagator would need {n_freq} Hankel samples over R = {radius:g} m (limit {MAX_HANKEL_SIZE})",
            "a smaller aperture, sensor window or distance",
        )
    return plan


def plan_asm(lens: Metalens, grid: PsfGrid, f_max: float, oversample: float = 1.0, upsample: int = 2) -> AsmGrid:
    """Padded grid for ``asm_propagate`` on the meta-atom grid (pitch p), for ``grid``'s wavelengths
    (the longest sets the side), window and distance.

    Side S ≥ 2a + W keeps the Matsushima limit (lateral travel ≤ S/2) from wrapping light from
    the pupil into the window of width W; S ≥ 2·d·tan θ_lim keeps the limit above the field's
    steepest ray plus margin. The FFT length is the next fast size.
    """
    p, a = lens.pitch_m, lens.radius_m
    m, distance_m = lens.grid_size, grid.distance(lens)
    width = 2 * (grid.pixels // 2 + 0.5) * grid.pixel_pitch_m
    sin_lim = sin_limit(f_max, grid.wavelengths_m, oversample)
    need = max(2 * a + width, 2 * distance_m * sin_lim / math.sqrt(1 - sin_lim**2), m * p)
    size = fft_size(math.ceil(need / p))
    if size > MAX_FFT_SIZE:
        raise SamplingError(
            "aperture",
            f"the angular spectrum needs a {size}² grid at pitch {p:g} m (side {need:g} m; limit {MAX_FFT_SIZE}²)",
            "the radial propagator for a radially symmetric design, or a smaller aperture, window or distance",
        )
    h = p / upsample
    half = math.ceil((width / 2) / h) + 3
    return AsmGrid(size=size, pitch_m=p, input_size=m, window_half=half, upsample=upsample)


def plan_field_asm(
    lens: Metalens,
    grid: PsfGrid,
    wavelength_m: float,
    f_max: float,
    carrier: tuple[float, float],
    centre_m: tuple[float, float],
    oversample: float = 1.0,
    upsample: int = 2,
) -> tuple[AsmGrid, int]:
    """Grid and kept band half-width K for the shifted angular spectrum of an off-axis source
    (``optics.field``): ``plan_asm``'s rules measured from the chief ray instead of the axis, at
    ``wavelength_m`` (one of ``grid``'s) with ``grid``'s window and distance.

    ``f_max``: the carrier-free field's largest local frequency (cycles/m). The kept band is the
    carrier-free field's, |u|, |v| ≤ sin θ_lim/λ, with the angle margin doubled (the default
    margin cut 1.5e-3 of edge-diffracted light off a 40 µm lens at 10°, against the direct
    Rayleigh-Sommerfeld sum; doubled, 6e-4). The side is the reach of the light that can land in
    the window and a guard, S ≥ 2a + W + 2·``REACH_FRESNEL``·√(λd): light from a pupil point
    (|x| ≤ a) into the window (W wide about the chief ray) travels at most a + W/2 sideways from the
    window's centre, and ``propagate.asm_transfer_shifted`` keeps the frequencies that travel at
    most S/2, so the band's steeper waves, which miss the window from every pupil point, are left
    out instead of padded for (the guard holds the diffraction at that cut). On the paper's lens at
    the sensor's corner this grid is 0.7-0.9× as wide as one holding every wave of the band
    (2·d·tan of its spread), and the PSFs ≤ 7e-5 apart. The band stops where that travel
    does (``carrier`` (u0, v0), cycles/m, and the window's centre ``centre_m``, m, as
    ``asm_transfer_shifted`` takes them): beyond it the transfer function is zero, so a smaller
    window's narrower band is exact, not a cut.
    """
    p, a, m = lens.pitch_m, lens.radius_m, lens.grid_size
    distance_m = grid.distance(lens)
    width = 2 * (grid.pixels // 2 + 0.5) * grid.pixel_pitch_m
    s = sin_limit(f_max, [wavelength_m], 2 * oversample)  # doubled margin, as plan_radial: edge diffraction
    need = max(2 * a + width + 2 * REACH_FRESNEL * math.sqrt(wavelength_m * distance_m), m * p)
    size = fft_size(math.ceil(need / p))
    if size > MAX_FFT_SIZE:
        raise SamplingError(
            "aperture",
            f"the off-axis angular spectrum needs a {size}² grid at pitch {p:g} m "
            f"(side {need:g} m; limit {MAX_FFT_SIZE}²)",
            "a smaller aperture or window",
        )
    half = math.ceil((width / 2) / (p / upsample)) + 3
    grid = AsmGrid(size=size, pitch_m=p, input_size=m, window_half=half, upsample=upsample)
    # the largest |u − u0| (and |v − v0|) whose travel d·u/w can land within S/2 of the window's centre c: at the other
    # frequency 0, where w is largest, travel t ↔ u = t/(λ·√(t² + d²)); |travel| only grows with the other frequency,
    # so the range holds every kept u, and 0 with it (a window beyond S/2 from the axis: u of its sign, not yet there at
    # 0, may travel there at another)
    reach = max(
        abs(t / (wavelength_m * math.hypot(t, distance_m)) - u0)
        for u0, c in zip(carrier, centre_m)
        for t in (min(c - size * p / 2, 0.0), max(c + size * p / 2, 0.0))
    )
    return grid, min(math.floor(s / wavelength_m * size * p), math.ceil(reach * size * p) + 1, (size - 1) // 2)


def plan_rs(lens: Metalens, grid: PsfGrid, rho_max_m: float, f_max: float, oversample: float = 1.0) -> tuple[int, int]:
    """Quadrature of the direct Rayleigh-Sommerfeld integral over the pupil of a radial lens:
    (Gauss-Legendre nodes in r on [0, a], trapezoid nodes in the azimuth over [0, π]), for
    ``grid``'s shortest wavelength and distance, output radii up to ``rho_max_m`` (m).

    4 nodes per cycle of the integrand in r (lens + source + kernel) and, in the azimuth,
    enough trapezoid nodes for exp(i·k·ρ·r'·cos φ/r) (≈ 0.7·k·ρ·a/d + 32).
    """
    a, lam, distance_m = lens.radius_m, min(grid.wavelengths_m), grid.distance(lens)
    kernel_freq = (a + rho_max_m) / math.hypot(a + rho_max_m, distance_m) / lam
    n_r = 16 * math.ceil(4 * (f_max + kernel_freq) * a * oversample / 16)
    beta = 2 * math.pi / lam * rho_max_m * a / distance_m
    n_phi = math.ceil((0.7 * beta + 32) * oversample)
    return n_r, n_phi
