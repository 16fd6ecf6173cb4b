"""Split-spectrum conditions for a multi-band filter, a focal length f and a near depth.

A lens that focuses pass-band light from far away focuses the same light from the near
depth z_near at wavelengths scaled by s = 1 + f/z_near (depth-wavelength symmetry). The
filter removes that sharp near-depth light when every shifted pass band lands in a stop
band or outside the sensor. For bands c = 1..N in ascending order (B, G, R for three), the
paper's inequalities (Suppl. Note 1) are

    min Λpass^c · s > min Λstop^c   (= max Λpass^c, the first stopped wavelength above c)
    max Λpass^c · s < min Λpass^{c+1}          for c < N

and together they say the shifted band c lies between pass band c and pass band c + 1.
The general condition they stand for, checked as well: each band, shifted by every s in
the z_near range, overlaps no pass band inside the sensor's wavelength range.

With a z_near range [z_lo, z_hi] each condition is checked at its worst depth: the
lower-bound conditions at z_hi (smallest s), the upper-bound ones at z_lo (largest s).

An interference filter's bands move blue for oblique rays: λ(θ) = λ0·√(1 − sin²θ/n_eff²).
Over a cone of rays up to θ_max a band [lo, hi] passes, for some ray, [k·lo, hi] with
k = √(1 − sin²θ_max/n_eff²) (:func:`incidence_factor`); the conditions are checked on those
widened bands (k = 1: normal incidence, the paper's check). A filter on the sensor sees rays up
to atan((a + h)/f), from the aperture's rim to the opposite sensor corner (:func:`steepest_incidence`).
All values in metres. Pure Python: answers instantly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from metalens_cli.analysis.symmetry import shift_factor
from metalens_cli.constants import SENSOR_RANGE_M
from metalens_cli.errors import InputError
from metalens_cli.io.tables import TRANSMISSION_TABLE, as_fractions, read_table_csv

THREE_BAND_LABELS = ("B", "G", "R")


@dataclass(frozen=True)
class Band:
    """One pass band [lo_m, hi_m] with a label (B, G, R for a three-band filter)."""

    label: str
    lo_m: float
    hi_m: float


@dataclass(frozen=True)
class Condition:
    """``lhs relation rhs``; ``margin_m`` > 0 when it holds (rhs − lhs for '<', lhs − rhs for '>')."""

    name: str
    lhs_m: float
    relation: str
    rhs_m: float
    depth_m: float
    margin_m: float
    ok: bool


@dataclass(frozen=True)
class BandsReport:
    """All conditions, and the closed-form windows of z_near (at this f) and f (at this z_near)."""

    bands: tuple[Band, ...]
    f_m: float
    z_near_m: tuple[float, float]
    sensor_range_m: tuple[float, float]
    s: tuple[float, float]
    conditions: tuple[Condition, ...]
    z_near_window_m: tuple[float, float] | None
    f_window_m: tuple[float, float] | None
    ignored_bands: tuple[Band, ...] = ()
    incidence_factor: float = 1.0

    @property
    def ok(self) -> bool:
        return all(c.ok for c in self.conditions)


def _round(value_m: float) -> float:
    """Round to 12 significant digits: 457nm − 11nm gives 4.46e-07, not 4.4600000000000003e-07."""
    return float(f"{value_m:.12g}")


def label_bands(intervals: list[tuple[float, float]]) -> tuple[Band, ...]:
    """Sort intervals and label them B, G, R (three bands) or band1..bandN."""
    ordered = sorted(intervals)
    labels = THREE_BAND_LABELS if len(ordered) == 3 else tuple(f"band{i + 1}" for i in range(len(ordered)))
    return tuple(Band(label, lo, hi) for label, (lo, hi) in zip(labels, ordered))


def bands_from_centers(centers_m: list[float], widths_m: list[float], field: str = "--band") -> tuple[Band, ...]:
    """Pass bands [c − w/2, c + w/2] (w = FWHM); they must not overlap."""
    if len(centers_m) != len(widths_m):
        raise InputError(field, "needs one width per centre", "CENTER:WIDTH pairs")
    if not centers_m:
        raise InputError(field, "no band given", "at least one CENTER:WIDTH, e.g. 530nm:20nm")
    intervals = []
    for c, w in zip(centers_m, widths_m):
        if w >= 2 * c:
            raise InputError(field, f"width {w:.4g} m is wider than twice its centre", "a width below the centre")
        intervals.append((_round(c - w / 2), _round(c + w / 2)))
    bands = label_bands(intervals)
    for a, b in zip(bands, bands[1:]):
        if b.lo_m <= a.hi_m:
            raise InputError(field, f"bands {a.label} and {b.label} overlap", "disjoint pass bands")
    return bands


def read_filter_csv(path: str | Path) -> tuple[list[float], list[float]]:
    """Wavelengths (m) and transmission (0-1) from ``wavelength_nm, transmission`` rows
    (header optional; transmission in 0-1 or percent)."""
    rows, _ = read_table_csv(path, TRANSMISSION_TABLE, "--filter-csv")
    return [row[0] * 1e-9 for row in rows], as_fractions([row[1] for row in rows], "--filter-csv", path)


def bands_from_transmission(
    wavelengths_m: list[float], transmission: list[float], threshold: float = 0.5
) -> tuple[Band, ...]:
    """Pass bands where the transmission exceeds ``threshold``, edges interpolated linearly."""

    def crossing(i: int) -> float:
        (w0, w1), (t0, t1) = wavelengths_m[i : i + 2], transmission[i : i + 2]
        return w0 + (threshold - t0) * (w1 - w0) / (t1 - t0)

    intervals, start = [], None
    if transmission[0] > threshold:
        start = wavelengths_m[0]
    for i in range(len(transmission) - 1):
        above_now, above_next = transmission[i] > threshold, transmission[i + 1] > threshold
        if not above_now and above_next:
            start = crossing(i)
        elif above_now and not above_next:
            intervals.append((start, crossing(i)))
            start = None
    if start is not None:
        intervals.append((start, wavelengths_m[-1]))
    if not intervals:
        raise InputError("--threshold", f"no pass band above {threshold:g}", "a threshold below the filter's peak")
    return label_bands(intervals)


def filter_bands(config) -> tuple[Band, ...]:
    """The pass bands of a preset's ``[filter]`` (:class:`~metalens_cli.io.presets.FilterConfig`):
    where its CSV transmission exceeds its threshold, else its centres and widths."""
    if config.csv is not None:
        return bands_from_transmission(*read_filter_csv(config.csv), threshold=config.threshold)
    return bands_from_centers(list(config.centers_m), list(config.widths_m), field="filter.centers")


def _condition(name: str, lhs: float, relation: str, rhs: float, depth: float) -> Condition:
    margin = lhs - rhs if relation == ">" else rhs - lhs
    return Condition(name, lhs, relation, rhs, depth, margin, margin > 0)


def _paper_conditions(bands: tuple[Band, ...], f_m: float, z_lo: float, z_hi: float) -> list[Condition]:
    """The paper's named inequalities, each at its worst depth of the z_near range."""
    s_min, s_max = shift_factor(f_m, z_hi), shift_factor(f_m, z_lo)
    out = []
    for i, band in enumerate(bands):
        out.append(_condition(f"{band.label}.min_into_stop", band.lo_m * s_min, ">", band.hi_m, z_hi))
        if i + 1 < len(bands):
            nxt = bands[i + 1]
            out.append(_condition(f"{band.label}.max_below_{nxt.label}", band.hi_m * s_max, "<", nxt.lo_m, z_lo))
    return out


def _clear_of_pass_bands(
    band: Band, bands: tuple[Band, ...], f_m: float, z_lo: float, z_hi: float, sensor: tuple[float, float]
) -> Condition:
    """General condition: the band swept over s in [s(z_hi), s(z_lo)] overlaps no pass band in the sensor range."""
    name = f"{band.label}.clear_of_pass_bands"
    lo = band.lo_m * shift_factor(f_m, z_hi)
    hi = band.hi_m * shift_factor(f_m, z_lo)
    if lo >= sensor[1]:
        return _condition(name, lo, ">", sensor[1], z_hi)  # shifted beyond the sensor's response
    best: Condition | None = None
    for other in bands:
        p_lo, p_hi = max(other.lo_m, sensor[0]), min(other.hi_m, sensor[1])
        if p_hi <= p_lo:
            continue
        # Whichever side of the pass band the shifted band is nearer to decides the relation.
        candidate = (
            _condition(name, hi, "<", p_lo, z_lo) if p_lo - hi >= lo - p_hi else _condition(name, lo, ">", p_hi, z_hi)
        )
        if best is None or candidate.margin_m < best.margin_m:
            best = candidate
    return best if best is not None else _condition(name, lo, ">", sensor[0], z_hi)


def split_conditions(
    bands: tuple[Band, ...], f_m: float, z_lo: float, z_hi: float, sensor_range_m: tuple[float, float]
) -> list[Condition]:
    """The paper's inequalities and the general condition of every band, at their worst depths.

    Band edges may be 0-d torch tensors (a filter being learned, ``design.filter_learning``):
    the margins are then differentiable in them; the arithmetic is the same.
    """
    conditions = _paper_conditions(bands, f_m, z_lo, z_hi)
    return conditions + [_clear_of_pass_bands(b, bands, f_m, z_lo, z_hi, sensor_range_m) for b in bands]


def incidence_factor(max_incidence_rad: float, n_eff: float) -> float:
    """k = √(1 − sin²θ/n_eff²): the factor by which a filter's bands move for rays at θ (≤ 1).

    Evaluated as √(n_eff² − 1 + cos²θ)/n_eff, which keeps its relative precision where k → 0
    (θ → 90° with n_eff = 1, where k = cos θ); the difference form rounds k to 0 there."""
    if not (0 <= max_incidence_rad < math.pi / 2 and n_eff >= 1):
        raise InputError(
            "filter.max_incidence",
            f"{math.degrees(max_incidence_rad):g}° with n_eff {n_eff:g}",
            "an angle in [0, 90) degrees and n_eff >= 1",
        )
    return math.sqrt(n_eff * n_eff - 1.0 + math.cos(max_incidence_rad) ** 2) / n_eff


def steepest_incidence(aperture_m: float, sensor_half_diagonal_m: float, f_m: float) -> float:
    """The steepest ray (rad) on a filter at the sensor: atan((a + h)/f), aperture radius a."""
    return math.atan((aperture_m / 2 + sensor_half_diagonal_m) / f_m)


def preset_incidence_factor(preset) -> float:
    """k of a preset's ``[filter]``: ``max_incidence`` "auto" (:func:`steepest_incidence` for its
    lens and sensor) or an angle, with its ``n_eff``; 1 without a filter."""
    from metalens_cli.io.units import parse_angle

    band_filter = preset.filter
    if band_filter is None:
        return 1.0
    if band_filter.max_incidence == "auto":
        half_diagonal = math.sqrt(2) * preset.sensor.pixels * preset.sensor.pixel_pitch_m / 2
        angle = steepest_incidence(preset.lens.aperture_m, half_diagonal, preset.lens.focal_length_m)
    else:
        angle = parse_angle(band_filter.max_incidence, "filter.max_incidence")
    return incidence_factor(angle, band_filter.n_eff)


def oblique_bands(bands: tuple[Band, ...], factor: float) -> tuple[Band, ...]:
    """What each band passes for some ray of the cone: [factor·lo, hi] (``factor`` ≤ 1)."""
    return tuple(Band(b.label, b.lo_m * factor, b.hi_m) for b in bands)


def windows(bands: tuple[Band, ...], f_m: float, z_lo: float, z_hi: float):
    """Closed-form windows where every paper condition holds.

    The conditions bound s from below by max_c(max Λ^c / min Λ^c) and from above by
    min_c(min Λ^{c+1} / max Λ^c); with s = 1 + f/z this gives z_near ∈ (f/(s_hi − 1),
    f/(s_lo − 1)) at fixed f, and f ∈ ((s_lo − 1)·z_hi, (s_hi − 1)·z_lo) for the whole
    z_near range. Open intervals; None when empty. One band has no upper bound: z from 0.
    """
    s_lo = max(b.hi_m / b.lo_m for b in bands)
    s_hi = min((n.lo_m / b.hi_m for b, n in zip(bands, bands[1:])), default=math.inf)
    if s_hi <= s_lo:
        return None, None
    z_window = (_round(f_m / (s_hi - 1.0)) if math.isfinite(s_hi) else 0.0, _round(f_m / (s_lo - 1.0)))
    f_lo, f_hi = _round((s_lo - 1.0) * z_hi), _round((s_hi - 1.0) * z_lo)
    return z_window, ((f_lo, f_hi) if f_hi > f_lo else None)


def check_bands(
    bands: tuple[Band, ...],
    f_m: float,
    z_near_m: tuple[float, float],
    *,
    sensor_range_m: tuple[float, float] = SENSOR_RANGE_M,
    incidence: float = 1.0,
) -> BandsReport:
    """Evaluate the split-spectrum conditions for ``bands`` at focal length ``f_m``.

    ``z_near_m`` is ``(lo, hi)``; a single depth is ``(z, z)``. Bands entirely outside the
    sensor range do not take part (they are listed in ``ignored_bands``). ``incidence``: the
    factor k of :func:`incidence_factor` (1: normal incidence); the conditions and windows are
    those of :func:`oblique_bands`, the report's ``bands`` the filter's own.
    """
    z_lo, z_hi = z_near_m
    if math.isinf(z_hi):
        raise InputError("--z-near", "must be finite", "a length or LO:HI interval, e.g. 45mm or 40mm:50mm")
    active = tuple(b for b in bands if b.hi_m > sensor_range_m[0] and b.lo_m < sensor_range_m[1])
    ignored = tuple(b for b in bands if b not in active)
    if not active:
        raise InputError(
            "--sensor-range", "no pass band lies inside the sensor range", "a range that overlaps the filter"
        )
    seen = oblique_bands(active, incidence)
    conditions = split_conditions(seen, f_m, z_lo, z_hi, sensor_range_m)
    z_window, f_window = windows(seen, f_m, z_lo, z_hi)
    return BandsReport(
        bands=active,
        f_m=f_m,
        z_near_m=(z_lo, z_hi),
        sensor_range_m=sensor_range_m,
        s=(shift_factor(f_m, z_hi), shift_factor(f_m, z_lo)),
        conditions=tuple(conditions),
        z_near_window_m=z_window,
        f_window_m=f_window,
        ignored_bands=ignored,
        incidence_factor=incidence,
    )
