"""``bands check``: the split-spectrum conditions of a filter at a focal length f and a near
depth range, with the closed-form windows of z_near and f where the paper's inequalities hold.

The conditions themselves (the depth-wavelength shift s = 1 + f/z, the paper's inequalities and
the general clear-of-pass-bands condition, oblique rays) are ``optics.split_spectrum``; this
module builds bands from centres, widths or a measured transmission and reports on them. All
values in metres. Pure Python: answers instantly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from metalens_cli import arguments
from metalens_cli.constants import SENSOR_RANGE_M
from metalens_cli.errors import InputError
from metalens_cli.io.tables import TRANSMISSION_TABLE, as_fractions, read_table_csv
from metalens_cli.optics.split_spectrum import (
    Band,
    Condition,
    label_bands,
    oblique_bands,
    sensed_bands,
    shift_factor,
    split_conditions,
)


@dataclass(frozen=True)
class BandsReport:
    """All conditions, and the closed-form windows of z_near (at this f) and f (at this z_near).

    What :func:`check_bands` returns; ``ok`` is True when every condition holds.

    Attributes:
        bands: the filter's own pass bands that overlap the sensor range (not shifted for incidence).
        f_m: focal length f (m).
        z_near_m: the near depth range (lo, hi) (m).
        sensor_range_m: the sensor's wavelength range (lo, hi) (m).
        s: the depth-wavelength shift s = 1 + f/z over the range: (at z hi, at z lo), ascending.
        conditions: every condition evaluated (name, both sides (m), relation, depth (m), margin (m)
            > 0 when it holds, ok).
        z_near_window_m: the open interval of z_near (m) at this f where the paper's conditions hold
            (from 0 for a single band), or None when empty.
        f_window_m: the open interval of f (m) where they hold over the whole z_near range, or None.
        ignored_bands: bands entirely outside the sensor range (they take no part).
        incidence_factor: the blue-shift factor k the conditions and windows were computed at
            (1: normal incidence).
    """

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
        """Whether every evaluated condition holds (True when there are none)."""
        return all(c.ok for c in self.conditions)


def _round(value_m: float) -> float:
    """Round to 12 significant digits: 457nm − 11nm gives 4.46e-07, not 4.4600000000000003e-07."""
    return float(f"{value_m:.12g}")


def bands_from_centers(centers_m: list[float], widths_m: list[float], field: str | None = None) -> tuple[Band, ...]:
    """Pass bands [c − w/2, c + w/2] (w = FWHM); they must not overlap.

    Edges are rounded to 12 significant digits; the bands are sorted and labelled B, G, R (three
    bands) or band1 … bandN.

    Args:
        centers_m: band centres c (m).
        widths_m: band widths w (m, FWHM), one per centre, each below twice its centre.
        field: the option or key the bands came from, named in errors; None: the parameter's name.

    Returns:
        The bands (:class:`Band`), ascending.

    Examples:
        >>> bands = bands_from_centers([630e-9, 450e-9, 530e-9], [20e-9, 20e-9, 20e-9])
        >>> [(b.label, b.lo_m, b.hi_m) for b in bands]
        [('B', 4.4e-07, 4.6e-07), ('G', 5.2e-07, 5.4e-07), ('R', 6.2e-07, 6.4e-07)]
    """
    centers_m = arguments.lengths(centers_m, field or "centers_m")
    widths_m = arguments.lengths(widths_m, field or "widths_m")
    field = field or "widths_m"
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

    Bands entirely outside the sensor range do not take part (they are listed in
    ``ignored_bands``).

    Args:
        bands: the filter's pass bands (:func:`bands_from_centers`), at least one.
        f_m: focal length f (m).
        z_near_m: near depth range ``(lo, hi)`` (m); a single depth is ``(z, z)``.
        sensor_range_m: the sensor's wavelength range (lo, hi) (m), lo < hi.
        incidence: the factor k of :func:`incidence_factor`, in (0, 1] (1: normal incidence); the
            conditions and windows are those of :func:`oblique_bands`, the report's ``bands`` the
            filter's own.

    Returns:
        The :class:`BandsReport`.

    Examples:
        >>> bands = bands_from_centers([450e-9, 530e-9, 630e-9], [20e-9, 20e-9, 20e-9])
        >>> report = check_bands(bands, 4e-3, (0.04, 0.05))
        >>> report.ok, report.s
        (True, (1.08, 1.1))
    """
    listed = arguments.instance(bands, "bands", (tuple, list), "Bands (ml.bands_from_centers)")
    if not listed:
        raise InputError("bands", "is empty", "at least one Band")
    for band in listed:
        arguments.instance(band, "bands", Band, "Bands (ml.bands_from_centers)")
    arguments.positive(f_m, "f_m")
    z_lo, z_hi = arguments.interval(z_near_m, "z_near_m")
    sensor_range_m = arguments.interval(sensor_range_m, "sensor_range_m")
    if not sensor_range_m[0] < sensor_range_m[1]:
        raise InputError("sensor_range_m", f"{sensor_range_m!r} is empty", "(lo, hi) with lo < hi, in m")
    arguments.number(incidence, "incidence", lo=0.0, hi=1.0, open_lo=True, form="a blue-shift factor k in (0, 1]")
    active = sensed_bands(bands, sensor_range_m)
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
