"""The filter learned with the lens (``[filter] learn = true``).

- :class:`LearnedFilter`: the centres and FWHMs of N pass bands and one 10-90 % edge width, in
  nm (float64 parameters), with the transmission of ``optics.spectra.bandpass_transmission``,
  differentiable in them. The peak transmission stays as given: the channel PSFs are normalised
  and training captures carry no noise, so it would cancel from the loss.
- Band quadrature (``optimize.spectral_sampling = "bands"``, :class:`BandSampler`): per band,
  ``wavelengths_per_channel`` wavelengths stratified over the band and its edges (FWHM plus
  ``EDGE_REACH`` edge widths each side); channel c's weight of node j is
  ∫ S^c(λ)·hat_j(λ) dλ / ∫ S^c(λ) dλ, hat_j the linear interpolant of node j (flat beyond the end
  nodes), summed on a ``FINE_STEP_M`` grid. Moving a band edge moves weight between the nodes
  beside it, so the channel PSFs are differentiable in the filter (exactly so for PSFs linear in
  λ between nodes), which importance samples drawn from S^c are not.
- Constraints: after every step :meth:`LearnedFilter.project` puts the filter back within what a
  filter maker can build (FWHM in [min_width, max_width], edge ≥ min_edge_width, gaps ≥ min_gap,
  bands inside the sensor range); the split-spectrum conditions of ``analysis.bands`` (oblique
  rays included) enter the loss as :func:`split_penalty`, Σ max(0, m_req − margin)² in nm², zero
  once each condition holds with the margin m_req; a start that fails them is first moved to one
  that meets them (:func:`make_feasible`). :func:`check_filter` is the final word.
- :func:`snap_to_catalogue`: the nearest purchasable filter (``io.filter_catalogue``) that meets
  the conditions.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import torch

from metalens_cli.analysis.bands import BandsReport, bands_from_centers, check_bands
from metalens_cli.design.rundir import run_preset_toml
from metalens_cli.errors import InputError, ResultFailed
from metalens_cli.io.filter_catalogue import CatalogueFilter, read_catalogue
from metalens_cli.io.preset_spectra import channel_throughput, preset_sensitivity
from metalens_cli.io.presets import catalogue_candidates, preset_incidence_factor
from metalens_cli.optics.spectra import bandpass_transmission, wavelength_grid
from metalens_cli.optics.split_spectrum import Band, label_bands, oblique_bands, split_conditions

NM = 1e-9
FINE_STEP_M = 0.1e-9  # the weights' integration grid: a 2 nm edge's logistic scale (0.46 nm) over 4.6 samples
EDGE_REACH = 1.6  # a band's transmission falls below 1e-3 of its peak 1.6 edge widths past its half-power point
SUPPORT_MARGIN_M = 20e-9  # rays of the initial windows: the bands' reach ± this


class LearnedFilter(torch.nn.Module):
    """N pass bands being learned: ``centres_nm``, ``widths_nm`` (FWHM) and one ``edge_nm``."""

    def __init__(self, config):
        super().__init__()
        self.centres_nm = torch.nn.Parameter(torch.tensor(config.centers_m, dtype=torch.float64) / NM)
        self.widths_nm = torch.nn.Parameter(torch.tensor(config.widths_m, dtype=torch.float64) / NM)
        self.edge_nm = torch.nn.Parameter(torch.tensor(config.edge_width_m / NM, dtype=torch.float64))
        self.peak = float(config.peak_transmission)

    def transmission(self, wavelengths_m) -> torch.Tensor:
        """T(λ) (L,) at ``wavelengths_m`` (m), float64, differentiable in the parameters."""
        return bandpass_transmission(
            torch.as_tensor(np.asarray(wavelengths_m, dtype=float)),
            self.centres_nm * NM,
            self.widths_nm * NM,
            edge_width_m=self.edge_nm * NM,
            peak=self.peak,
        )

    def bands(self) -> tuple[Band, ...]:
        """The pass bands [c − w/2, c + w/2] (m) with tensor edges (differentiable)."""
        lo = (self.centres_nm - self.widths_nm / 2) * NM
        hi = (self.centres_nm + self.widths_nm / 2) * NM
        return label_bands([(lo[i], hi[i]) for i in range(lo.shape[0])])

    def values(self) -> tuple[list[float], list[float], float]:
        """(centres, widths, edge width) in metres, as floats."""
        return (
            [float(c) * NM for c in self.centres_nm.detach()],
            [float(w) * NM for w in self.widths_nm.detach()],
            float(self.edge_nm.detach()) * NM,
        )

    def to_config(self, base):
        """``base`` (a ``FilterConfig``) with this filter's bands and edge."""
        centres, widths, edge = self.values()
        return dataclasses.replace(base, centers_m=tuple(centres), widths_m=tuple(widths), edge_width_m=edge)

    @torch.no_grad()
    def project(self, config, sensor_range_m: tuple[float, float]) -> None:
        """Back within the limits of ``config`` (a ``FilterConfig``): FWHM in [min_width,
        max_width] (narrowed, each in proportion to its width above min_width, where the bands and
        gaps would not fit in the sensor range; preset loading refuses limits where even the
        narrowest do not), edge ≥ min_edge_width and ≤ 1/0.81 of the narrowest band (the smooth
        model's own limit), then the centres moved as little as a forward and a backward sweep
        need for gaps ≥ min_gap between bands and every band inside the sensor range."""
        w = self.widths_nm.clamp_(config.min_width_m / NM, config.max_width_m / NM)
        c, gap, narrowest = self.centres_nm, config.min_gap_m / NM, config.min_width_m / NM
        excess = float(w.sum()) + (w.shape[0] - 1) * gap - (sensor_range_m[1] - sensor_range_m[0]) / NM
        if excess > 0:  # wider bands than the range holds: each gives up its share of the width above min_width
            w.sub_(excess * (w - narrowest) / float((w - narrowest).sum()))
        self.edge_nm.clamp_(config.min_edge_width_m / NM, float(w.min()) / 0.81)
        floor = sensor_range_m[0] / NM
        for i in range(c.shape[0]):
            c[i] = torch.clamp(c[i], min=floor + w[i] / 2)
            floor = c[i] + w[i] / 2 + gap
        ceiling = sensor_range_m[1] / NM
        for i in reversed(range(c.shape[0])):
            c[i] = torch.clamp(c[i], max=ceiling - w[i] / 2)
            ceiling = c[i] - w[i] / 2 - gap


def filter_columns(n_bands: int) -> tuple[str, ...]:
    """loss.csv columns of a learned filter: centres, widths (nm), edge (nm), the split penalty."""
    return (
        *(f"filter_center_{i}_nm" for i in range(n_bands)),
        *(f"filter_width_{i}_nm" for i in range(n_bands)),
        "filter_edge_nm",
        "split",
        "light",
    )


def filter_row(band_filter: LearnedFilter) -> dict:
    """One step's loss.csv values of a learned filter: each band's centre and width and the edge
    width, in nm (the :func:`filter_columns` other than ``split`` and ``light``)."""
    centres, widths, edge = band_filter.values()
    return {
        **{f"filter_center_{i}_nm": c / NM for i, c in enumerate(centres)},
        **{f"filter_width_{i}_nm": w / NM for i, w in enumerate(widths)},
        "filter_edge_nm": edge / NM,
    }


# ------------------------------------------------------------------------------ quadrature


def band_nodes(centres_m, widths_m, edge_m: float, per_band: int, rng: np.random.Generator | None) -> np.ndarray:
    """Increasing wavelengths (m): per band, ``per_band`` nodes stratified over [c − r, c + r],
    r = w/2 + EDGE_REACH·edge (one per stratum, uniformly placed with ``rng``, else at its middle)."""
    nodes = []
    for c, w in zip(centres_m, widths_m):
        reach = w / 2 + EDGE_REACH * edge_m
        u = np.full(per_band, 0.5) if rng is None else rng.random(per_band)
        nodes.append(c - reach + (np.arange(per_band) + u) * (2 * reach / per_band))
    return np.unique(np.concatenate(nodes))


def band_weights(nodes_m: np.ndarray, fine_m: np.ndarray, base: np.ndarray, transmission: torch.Tensor) -> torch.Tensor:
    """(3, W) channel weights of the nodes (module docstring): S^c = ``base`` (3, F) (camera × η
    on the uniform grid ``fine_m``) × ``transmission`` (F,); rows sum to 1; differentiable in T."""
    hats = np.stack([np.interp(fine_m, nodes_m, unit) for unit in np.eye(nodes_m.size)])
    raw = (torch.from_numpy(base).to(transmission.dtype) * transmission) @ torch.from_numpy(hats).to(
        transmission.dtype
    ).T
    return raw / raw.sum(dim=1, keepdim=True)


@dataclass
class BandSampler:
    """The spectral draws of a run with ``spectral_sampling = "bands"``: the sensor's response
    without the filter (``base``, camera × η on ``fine_m``) and the filter (learned or fixed)."""

    fine_m: np.ndarray
    base: np.ndarray
    band_filter: LearnedFilter
    per_band: int
    sensor_range_m: tuple[float, float]

    def draw(self, rng: np.random.Generator | None) -> tuple[np.ndarray, torch.Tensor, torch.Tensor]:
        """Wavelengths (W,), their channel weights (3, W) and the channel throughputs (3,), all
        from one evaluation of the filter and differentiable in it."""
        centres, widths, edge = self.band_filter.values()
        nodes = band_nodes(centres, widths, edge, self.per_band, rng)
        t = self.band_filter.transmission(self.fine_m)
        return nodes, band_weights(nodes, self.fine_m, self.base, t), self.throughput(t)

    def throughput(self, transmission: torch.Tensor | None = None) -> torch.Tensor:
        """(3,) R, G, B: the share of each channel's unfiltered signal the filter passes
        (``io.preset_spectra.channel_throughput`` on this grid), differentiable in the filter;
        ``transmission``: the filter on ``fine_m`` when already evaluated."""
        t = self.band_filter.transmission(self.fine_m) if transmission is None else transmission
        base = torch.from_numpy(self.base).to(t.dtype)
        return (base * t).sum(dim=1) / base.sum(dim=1)

    def light_loss(self, throughput: torch.Tensor | None = None) -> torch.Tensor:
        """L_light = −mean_c log g_c, g_c the channel throughputs (:meth:`throughput`, or as
        given): added to −mean_c log E_c (``sharp_mode = "log"``) it makes L_sharp count the
        core's share of the light before the filter instead of after it, so a band narrowed to
        half its light must double its core energy to break even."""
        return -torch.log(self.throughput() if throughput is None else throughput).mean()

    def support(self) -> list[float]:
        """The wavelengths whose rays the initial windows must hold: the bands' reach ± a margin."""
        centres, widths, edge = self.band_filter.values()
        reach = [(c - w / 2 - EDGE_REACH * edge, c + w / 2 + EDGE_REACH * edge) for c, w in zip(centres, widths)]
        lo, hi = self.sensor_range_m
        return [
            max(lo, min(r[0] for r in reach) - SUPPORT_MARGIN_M),
            min(hi, max(r[1] for r in reach) + SUPPORT_MARGIN_M),
        ]


def band_sampler(preset, band_filter: LearnedFilter | None = None) -> BandSampler:
    """The sampler of ``preset`` on a ``FINE_STEP_M`` grid: of ``band_filter`` (learned), else of
    the preset's filter, fixed."""
    lo, hi = preset.sensor.wavelength_range_m
    fine = wavelength_grid(lo, hi, FINE_STEP_M)
    base = preset_sensitivity(dataclasses.replace(preset, filter=None), fine).values
    fixed = band_filter is None
    band_filter = LearnedFilter(preset.filter).requires_grad_(False) if fixed else band_filter
    return BandSampler(fine, base, band_filter, preset.optimize.wavelengths_per_channel, (lo, hi))


# ------------------------------------------------------------------------------ conditions


def split_penalty(band_filter: LearnedFilter, preset, incidence: float) -> torch.Tensor:
    """Σ max(0, split_margin − margin)² over the split-spectrum conditions (nm²), the margins
    those of ``analysis.bands.split_conditions`` for the oblique bands: zero once all hold with
    the margin the preset asks for."""
    lo, hi = preset.scene.z_near_m
    conditions = split_conditions(
        oblique_bands(band_filter.bands(), incidence),
        preset.lens.focal_length_m,
        lo,
        hi,
        preset.sensor.wavelength_range_m,
    )
    need = preset.filter.split_margin_m
    total = torch.zeros((), dtype=torch.float64)
    for condition in conditions:
        total = total + torch.relu((need - torch.as_tensor(condition.margin_m, dtype=torch.float64)) / NM) ** 2
    return total


FEASIBLE_STEPS = 3000
FEASIBLE_RATE_NM = 0.05


def make_feasible(band_filter: LearnedFilter, preset, incidence: float) -> dict:
    """Move a starting filter that fails the split-spectrum conditions to one that meets them
    with the margin (the penalty alone, Adam at ``FEASIBLE_RATE_NM`` nm a step with projection,
    at most ``FEASIBLE_STEPS`` steps, a few ms each), before θ learns. Started inside, the
    penalty's gradient stays at the image terms' scale: a penalty of nm² shortfalls met during
    training would inflate Adam's second moments and freeze the bands for hundreds of steps.
    Returns what it did (the shortfall before and after, steps)."""
    before = float(split_penalty(band_filter, preset, incidence).detach())
    steps, penalty = 0, before
    if before > 0:
        optimiser = torch.optim.Adam(band_filter.parameters(), lr=FEASIBLE_RATE_NM)
        while penalty > 0 and steps < FEASIBLE_STEPS:
            optimiser.zero_grad()
            loss = split_penalty(band_filter, preset, incidence)
            loss.backward()
            optimiser.step()
            band_filter.project(preset.filter, preset.sensor.wavelength_range_m)
            steps += 1
            penalty = float(split_penalty(band_filter, preset, incidence).detach())
        band_filter.zero_grad(set_to_none=True)
    return {"penalty_before_nm2": before, "penalty_after_nm2": penalty, "steps": steps}


def check_filter(config, preset, incidence: float | None = None) -> BandsReport:
    """``bands check`` of a filter (a ``FilterConfig``) at the preset's f, z_near, sensor range
    and oblique incidence: the report the run writes and the one the CLI shows."""
    incidence = preset_incidence_factor(dataclasses.replace(preset, filter=config)) if incidence is None else incidence
    bands = bands_from_centers(list(config.centers_m), list(config.widths_m), field="filter.centers")
    return check_bands(
        bands,
        preset.lens.focal_length_m,
        preset.scene.z_near_m,
        sensor_range_m=preset.sensor.wavelength_range_m,
        incidence=incidence,
    )


def refuse_failing(report: BandsReport, what: str) -> None:
    """ResultFailed naming the conditions that fail (the learned filter is then not written)."""
    failing = [c for c in report.conditions if not c.ok]
    if failing:
        listed = ", ".join(f"{c.name} by {c.margin_m / NM:+.2f} nm at z = {c.depth_m * 1e3:g} mm" for c in failing)
        raise ResultFailed(
            f"{what} fails the split-spectrum conditions ({listed}); it was not written: raise "
            "filter.split_weight or filter.split_margin, or narrow filter.max_width, and run again"
        )


def snap_to_catalogue(config, catalogue: list[CatalogueFilter], preset) -> tuple[CatalogueFilter, float]:
    """The listed filter nearest to ``config`` (RMS over its bands of the centre and FWHM
    differences, nm) among those the preset may snap to (``io.presets.catalogue_candidates``:
    as many bands, meeting the split-spectrum conditions), and that distance. Preset loading
    refuses a catalogue without one; InputError if there is none."""
    fits = []
    for entry in catalogue_candidates(preset, catalogue):
        diffs = [a - b for a, b in zip(entry.centers_m + entry.widths_m, config.centers_m + config.widths_m)]
        fits.append((math.sqrt(sum(d * d for d in diffs) / len(entry.centers_m)) / NM, entry.name, entry))
    if not fits:
        raise InputError(
            "filter.catalogue",
            f"no listed filter with {len(config.centers_m)} bands meets the split-spectrum "
            "conditions at this f and z_near",
            "a catalogue with such a filter, or no catalogue",
        )
    distance, _, entry = min(fits, key=lambda fit: (fit[0], fit[1]))
    return entry, distance


# ------------------------------------------------------------------------------ the run's filter

FILTER_CSV_STEP_M = 0.5e-9


def learned_filter(run, preset, band_filter: LearnedFilter) -> tuple[object, dict]:
    """The end of a run that learned its filter: the filter checked against the split-spectrum
    conditions (:func:`refuse_failing`), snapped to the catalogue when one is given, then written
    into the run's preset.toml (so every later command uses it) and as ``filter.csv``
    (wavelength_nm, transmission every 0.5 nm over the sensor range, for a filter maker).
    Returns the preset with that filter and the report for run.json."""
    start = preset.filter
    config = band_filter.to_config(start)
    learned = check_filter(config, preset)
    refuse_failing(learned, "the learned filter")
    report = {
        "initial": _filter_json(start, preset),
        "learned": {**_filter_json(config, preset), "conditions": _conditions(learned, start.split_margin_m)},
        "incidence_factor": learned.incidence_factor,
    }
    if start.catalogue is not None:
        entry, distance = snap_to_catalogue(config, read_catalogue(start.catalogue), preset)
        config = dataclasses.replace(
            config,
            centers_m=entry.centers_m,
            widths_m=entry.widths_m,
            edge_width_m=entry.edge_width_m,
            peak_transmission=entry.peak_transmission,
        )
        report["catalogue"] = {
            "file": start.catalogue,
            "name": entry.name,
            "distance_nm": distance,
            **_filter_json(config, preset),
            "conditions": _conditions(check_filter(config, preset), start.split_margin_m),
        }
    result = dataclasses.replace(preset, filter=config)
    run.write_text("preset.toml", run_preset_toml(result))
    lo, hi = preset.sensor.wavelength_range_m
    grid = wavelength_grid(lo, hi, FILTER_CSV_STEP_M)
    t = bandpass_transmission(
        grid, config.centers_m, config.widths_m, edge_width_m=config.edge_width_m, peak=config.peak_transmission
    )
    run.write_text(
        "filter.csv", "wavelength_nm,transmission\n" + "".join(f"{w / NM:.1f},{v:.6f}\n" for w, v in zip(grid, t))
    )
    return result, report


def _filter_json(config, preset) -> dict:
    return {
        "centers_m": list(config.centers_m),
        "widths_m": list(config.widths_m),
        "edge_width_m": config.edge_width_m,
        "peak_transmission": config.peak_transmission,
        "throughput": dict(zip("RGB", channel_throughput(dataclasses.replace(preset, filter=config)).tolist())),
    }


def _conditions(report: BandsReport, split_margin_m: float) -> dict:
    """Whether the conditions hold, their margins (m), and whether every margin reaches the
    preset's ``split_margin`` (a penalty during training, not a guarantee)."""
    return {
        "ok": report.ok,
        "margins_m": {c.name: c.margin_m for c in report.conditions},
        "split_margin_m": split_margin_m,
        "split_margin_met": all(c.margin_m >= split_margin_m for c in report.conditions),
    }
