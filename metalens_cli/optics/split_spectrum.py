"""The split-spectrum conditions of a multi-band filter (pure Python, differentiable in torch
band edges): the physics that ``analysis.bands`` reports, preset validation bounds
(:func:`largest_margin`) and ``design.filter_learning`` trains against.

A lens focusing pass-band light from infinity focuses the same light from depth z at
wavelengths scaled by s = 1 + f/z (:func:`shift_factor`). The filter removes that near-depth
light when every shifted pass band lands in a stop band or beyond the sensor. For bands
c = 1..N in ascending order the paper's inequalities (Suppl. Note 1) are

    min Λpass^c · s > max Λpass^c
    max Λpass^c · s < min Λpass^{c+1}          for c < N

each at its worst depth of a z_near range [z_lo, z_hi]: the first at z_hi (smallest s), the
second at z_lo (largest s). The general condition they stand for, checked as well: each band,
shifted by every s of the range, overlaps no pass band inside the sensor's range.

Oblique rays up to θ move an interference filter's bands blue by k = √(1 − sin²θ/n_eff²)
(:func:`incidence_factor`); for some ray of the cone a band [lo, hi] passes [k·lo, hi]
(:func:`oblique_bands`), and the conditions are checked on those. Lengths in metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from metalens_cli.arguments import instance, positive
from metalens_cli.errors import InputError

THREE_BAND_LABELS = ("B", "G", "R")


@dataclass(frozen=True)
class Band:
    """One pass band [lo_m, hi_m] with a label (B, G, R for a three-band filter).

    Checked when built: a text label and edges 0 < lo < hi.

    Attributes:
        label: the band's name, e.g. "B", "G", "R" or "band1".
        lo_m: lower edge (m); a 0-d tensor while a filter is learned.
        hi_m: upper edge (m), above ``lo_m``; likewise.

    Examples:
        >>> band = Band("G", 520e-9, 540e-9)
        >>> band.label, round((band.hi_m - band.lo_m) * 1e9, 6)
        ('G', 20.0)
    """

    label: str
    lo_m: float
    hi_m: float

    def __post_init__(self) -> None:
        """A text label and edges 0 < lo < hi (m; 0-d tensors while a filter is learned)."""
        instance(self.label, "label", str, "a text label")
        lo, hi = positive(self.lo_m, "lo_m"), positive(self.hi_m, "hi_m")
        if not lo < hi:
            raise InputError("hi_m", f"{hi:g} m is not above lo_m {lo:g} m", "a band lo_m < hi_m")


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


def label_bands(intervals: list[tuple[float, float]]) -> tuple[Band, ...]:
    """Sort intervals and label them B, G, R (three bands) or band1..bandN."""
    ordered = sorted(intervals)
    labels = THREE_BAND_LABELS if len(ordered) == 3 else tuple(f"band{i + 1}" for i in range(len(ordered)))
    return tuple(Band(label, lo, hi) for label, (lo, hi) in zip(labels, ordered))


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


def sensed_bands(bands: tuple[Band, ...], sensor_range_m: tuple[float, float]) -> tuple[Band, ...]:
    """The bands that overlap the sensor's range: the only ones the conditions concern."""
    return tuple(b for b in bands if b.hi_m > sensor_range_m[0] and b.lo_m < sensor_range_m[1])


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


def oblique_bands(bands: tuple[Band, ...], factor: float) -> tuple[Band, ...]:
    """What each band passes for some ray of the cone: [factor·lo, hi] (``factor`` ≤ 1)."""
    return tuple(Band(b.label, b.lo_m * factor, b.hi_m) for b in bands)


def shift_factor(f_m: float, depth_m: float) -> float:
    """s = 1 + f/z: a wavelength focused from infinity is focused from depth z at λ·s."""
    return 1.0 + f_m / depth_m


def largest_margin(
    n_bands: int,
    f_m: float,
    z_near_m: tuple[float, float],
    sensor_range_m: tuple[float, float],
    min_width_m: float,
    min_gap_m: float,
    incidence: float = 1.0,
) -> float:
    """The supremum of the margin m (m) by which the paper's inequalities can all hold, on the
    oblique bands of ``incidence`` factor k, for ``n_bands`` bands of FWHM ≥ ``min_width_m``,
    gaps ≥ ``min_gap_m``, inside ``sensor_range_m`` (what ``design.filter_learning`` can reach);
    ≤ 0 when no such filter meets them; −inf when the bands do not fit in the range.

    An upper bound on every split margin (the general condition only adds to them). Each
    constraint asks a band's lower edge to be at least an increasing function of the previous
    band's upper edge, or (min_into_stop when k·s ≤ 1) at most a fixed value; so for a given m
    the narrowest bands placed as low as each allows are feasible if any filter is, and m is
    found by bisection (to 1e-6 nm)."""
    low, high = sensor_range_m
    s_min, s_max = shift_factor(f_m, z_near_m[1]), shift_factor(f_m, z_near_m[0])
    rise = incidence * s_min - 1.0  # min_into_stop: lo·rise ≥ width + m
    w, gap = min_width_m, min_gap_m
    if n_bands * w + (n_bands - 1) * gap > high - low:
        return -math.inf

    def fits(m: float) -> bool:
        lo, floor = low, (m + w) / rise if rise > 0 else -math.inf
        for _ in range(n_bands):
            lo = max(lo, floor)
            if lo + w > high or (rise <= 0 and lo * rise - w < m):
                return False
            hi = lo + w
            lo = max(hi + gap, (hi * s_max + m) / incidence)
        return True

    below, above = -10 * high * (1 + s_max / incidence), high  # at `below` only the packing binds; `above` fails
    while above - below > 1e-15:
        middle = (below + above) / 2
        below, above = (middle, above) if fits(middle) else (below, middle)
    return below
