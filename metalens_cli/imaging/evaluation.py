"""The raw-capture evaluation of designs (Suppl. Note 11 protocol), with statistics.

Every design sees the same units: (image, seed) pairs, where a seed draws the depths, the
obstructions and the noise. Per unit and design: the unobstructed and obstructed captures, raw
and (for designs given a reconstruction network) reconstructed, scored against the clean image
(``pipeline.score``: photometric match, then PSNR/SSIM/LPIPS). Reported
per (design, obstruction, condition): the mean over units with a 95 % bootstrap confidence
interval; Δ = obstructed − unobstructed per unit (for LPIPS unobstructed − obstructed, as the
paper defines it: negative is a degradation for every metric); and paired differences between
designs on the same units (raw against raw, recon against recon) and between each design's
recon and raw captures.
"""

from __future__ import annotations

import csv
import io
import os
from collections.abc import Callable
from dataclasses import dataclass, field

from metalens_cli.analysis.statistics import mean_ci, paired_difference_ci
from metalens_cli.imaging.field_formation import DEFAULT_TOLERANCE
from metalens_cli.imaging.images import load_images
from metalens_cli.imaging.metrics import DEFAULT_MATCH
from metalens_cli.imaging.pipeline import (
    CaptureSetup,
    ChannelPsfs,
    capture_psfs,
    draw_depths,
    score,
    simulate_captures,
)
from metalens_cli.io.atomic import atomic_write

CONDITIONS = ("unobstructed", "obstructed")
MIN_UNITS = 20  # fewer units per cell: a warning (bootstrap CIs of a handful of units are wide and unreliable)


@dataclass
class EvaluationSettings:
    """What every unit shares: sensor, depth intervals (m), wavelengths (m), image source,
    obstruction parameters, formation and scoring options."""

    pixels: int
    pixel_pitch_m: float
    z_near_interval_m: tuple[float, float]
    z_far_interval_m: tuple[float, float]
    wavelengths_m: list[float]
    images: str = "photos"
    limit: int | None = None
    obstruction_params: object = None
    formation: str = "physical"
    match: str = DEFAULT_MATCH
    alpha_gain: float | None = None
    photons: float | None = None
    read_noise: float = 0.0
    photons_before_filter: bool = False  # photons count the light before each design's filter (its throughput passes)
    psf_window: int | None = None
    device: object = "cpu"
    field_model: str = "on-axis"  # "auto": PSFs over the field where the sensor outgrows the isoplanatic patch
    field_tolerance: float = DEFAULT_TOLERANCE  # the space-variant formation's (imaging.field_formation)

    @classmethod
    def from_setup(cls, setup: CaptureSetup, **options) -> EvaluationSettings:
        """The sensor, depth intervals, wavelengths, obstruction parameters and device of
        ``setup``, with the other fields from ``options``."""
        return cls(
            setup.pixels,
            setup.pixel_pitch_m,
            setup.z_near_interval_m,
            setup.z_far_interval_m,
            setup.wavelengths_m,
            obstruction_params=setup.obstruction_params,
            device=setup.device,
            **options,
        )


@dataclass
class Evaluation:
    """Results: ``rows`` (design, capture, obstruction, condition, metric means, ``<metric>_ci``, n),
    ``deltas``, ``comparisons`` (paired design differences), ``units`` (every score), ``psfs``
    (per design and seed: depths, windows, kept light), ``images`` (names), ``panels`` (first
    image and seed, for figures), ``warnings`` and, for captured pairs, ``alignments``."""

    rows: list[dict] = field(default_factory=list)
    deltas: list[dict] = field(default_factory=list)
    comparisons: list[dict] = field(default_factory=list)
    units: list[dict] = field(default_factory=list)
    psfs: list[dict] = field(default_factory=list)
    images: list[str] = field(default_factory=list)
    panels: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    alignments: list[dict] = field(default_factory=list)


def design_photons(design, settings: EvaluationSettings):
    """The full-well electrons of a design's captures: ``settings.photons``, or with
    ``photons_before_filter`` that many times each channel's filter throughput (3,)
    (``io.preset_spectra.channel_throughput``: designs with other filters at the same light)."""
    if not settings.photons or not settings.photons_before_filter:
        return settings.photons
    from metalens_cli.io.preset_spectra import channel_throughput

    return settings.photons * channel_throughput(design.preset)


def metric_names(lpips_model) -> tuple[str, ...]:
    return ("psnr_db", "ssim", "lpips") if lpips_model is not None else ("psnr_db", "ssim")


def delta(metric: str, unobstructed: float, obstructed: float) -> float:
    """Δ of one unit: obstructed − unobstructed, or unobstructed − obstructed for LPIPS (lower is better)."""
    return unobstructed - obstructed if metric == "lpips" else obstructed - unobstructed


def evaluate(
    designs,
    kinds: list[str],
    seeds: list[int],
    settings: EvaluationSettings,
    *,
    lpips_model=None,
    on_progress: Callable[[int, int], None] | None = None,
    reconstructors: list | None = None,
) -> Evaluation:
    """Score every design on the same (image, seed) units for every obstruction kind.

    ``reconstructors``: one per design, a callable mapping a linear (3, H, W) capture to its
    reconstruction (``imaging.restore.Reconstructor``) or None; designs with one are scored on
    their ``recon`` captures as well as their ``raw`` ones.
    """
    out = Evaluation()
    recon = list(reconstructors) if reconstructors is not None else [None] * len(designs)
    psfs: dict[tuple[int, int], ChannelPsfs] = {}
    for d, design in enumerate(designs):
        at_depths: dict[tuple[float, float], ChannelPsfs] = {}  # seeds drawing the same depths share them
        for seed in seeds:
            z_near, z_far = draw_depths(settings.z_near_interval_m, settings.z_far_interval_m, seed)
            p = at_depths.get((z_near, z_far)) or capture_psfs(
                design,
                z_near,
                z_far,
                settings.wavelengths_m,
                settings.pixel_pitch_m,
                settings.pixels,
                field_model=settings.field_model,
                field_tolerance=settings.field_tolerance,
                device=settings.device,
                window=settings.psf_window,
            )
            psfs[d, seed] = at_depths[z_near, z_far] = p
            out.psfs.append(
                {
                    "design": design.spec,
                    "seed": seed,
                    "z_near_m": z_near,
                    "z_far_m": z_far,
                    **p.report(),
                    "seconds": p.seconds,
                }
            )
            out.warnings += [f"{design.spec}, seed {seed}: {w}" for w in p.warnings()]
    photons = [design_photons(design, settings) for design in designs]
    margin = max(p.margin for p in psfs.values())  # one canvas for all: every design sees the same scene
    images = load_images(settings.images, (settings.pixels, settings.pixels), settings.limit, margin)
    out.images = [image.name for image in images]
    metrics = metric_names(lpips_model)
    scores: dict[tuple, dict] = {}
    total, done = len(designs) * len(kinds) * len(seeds), 0
    out.panels = {design.spec: [] for design in designs}
    obstructions: dict = {}  # generated once, shared by the designs (same seed, depths and canvas)
    units: dict[tuple, list] = {}  # (kind, seed, design) → its units, listed in that order at the end
    for d, design in enumerate(designs):  # one design's capture transforms held at a time
        for kind in kinds:
            for seed in seeds:
                captures = simulate_captures(
                    images,
                    kind,
                    psfs[d, seed],
                    design.focal_length_m,
                    settings.pixel_pitch_m,
                    seed,
                    params=settings.obstruction_params,
                    formation=settings.formation,
                    alpha_gain=settings.alpha_gain,
                    photons=photons[d],
                    read_noise=settings.read_noise,
                    obstructions=obstructions,
                )
                for index, c in enumerate(captures):
                    estimates = {"raw": (c.unobstructed, c.obstructed)}
                    if recon[d] is not None:
                        clear_key = ("recon", d, "unobstructed", seed, index)
                        estimates["recon"] = (
                            None if clear_key in scores else recon[d](c.unobstructed),
                            recon[d](c.obstructed),
                        )
                    for capture, (clear, obstructed) in estimates.items():
                        key = (capture, d, "unobstructed", seed, index)  # the same for every obstruction kind
                        if key not in scores:
                            scores[key] = score(clear, c.clean, lpips_model, settings.match)
                        scores[capture, d, kind, seed, index] = score(obstructed, c.clean, lpips_model, settings.match)
                        units.setdefault((kind, seed, d), []).append(
                            {
                                "design": design.spec,
                                "capture": capture,
                                "obstruction": kind,
                                "seed": seed,
                                "image": c.name,
                                "unobstructed": scores[key],
                                "obstructed": scores[capture, d, kind, seed, index],
                            }
                        )
                        if seed == seeds[0] and index == 0:
                            panels = out.panels[design.spec]
                            if capture == "raw" and not panels:
                                panels += [("clean", c.clean), ("unobstructed", c.unobstructed)]
                            panels.append((f"{'recon, ' if capture == 'recon' else ''}obstructed: {kind}", obstructed))
                done += 1
                if on_progress is not None:
                    on_progress(done, total)
        for seed in seeds:
            psfs[d, seed].transforms.clear()
    out.units = [unit for kind in kinds for seed in seeds for d in range(len(designs)) for unit in units[kind, seed, d]]
    summarise(out, [design.spec for design in designs], recon, kinds, seeds, len(images), metrics, scores)
    warn_few_units(
        out,
        len(images) * len(seeds),
        f"{len(images)} image(s) × {len(seeds)} seed(s)",
        "add seeds (--seed 0:4) or images",
    )
    return out


def warn_few_units(out: Evaluation, units: int, what: str, advice: str) -> None:
    """A warning in ``out`` when a cell has fewer than ``MIN_UNITS`` units."""
    if units < MIN_UNITS:
        out.warnings.append(
            f"{units} units per cell ({what}), fewer than {MIN_UNITS}: the confidence intervals are wide "
            f"and unreliable; {advice}"
        )


def summarise(out: Evaluation, specs: list[str], recon: list, kinds, seeds, n_images: int, metrics, scores) -> None:
    """Fill ``out.rows``, ``deltas`` and ``comparisons`` from ``scores[(capture, design index,
    condition or "unobstructed", seed, image index)]`` (metric dicts) over the units (seed,
    image); designs named ``specs``, those whose ``recon`` entry is not None also scored as recon."""
    from metalens_cli.imaging.metrics import PSNR_CEILING_DB

    exact = sum(1 for value in scores.values() if value["psnr_db"] >= PSNR_CEILING_DB)
    if exact:
        out.warnings.append(
            f"{exact} score(s) match their reference exactly; their PSNR is reported as the {PSNR_CEILING_DB:g} dB "
            "ceiling"
        )
    units = [(seed, index) for seed in seeds for index in range(n_images)]
    cells = [
        (capture, d)
        for d in range(len(specs))
        for capture in ("raw", "recon")
        if capture == "raw" or recon[d] is not None
    ]

    def values(capture, d, kind, condition, metric):
        return [
            scores[(capture, d, "unobstructed" if condition == "unobstructed" else kind, seed, index)][metric]
            for seed, index in units
        ]

    def deltas(capture, d, kind, metric):
        return [
            delta(metric, u, o)
            for u, o in zip(
                values(capture, d, kind, "unobstructed", metric), values(capture, d, kind, "obstructed", metric)
            )
        ]

    for kind in kinds:
        for capture, d in cells:
            for condition in CONDITIONS:
                row = {
                    "design": specs[d],
                    "capture": capture,
                    "obstruction": kind,
                    "condition": condition,
                    "n": len(units),
                }
                for metric in metrics:
                    stats = mean_ci(values(capture, d, kind, condition, metric), metric=metric)
                    row[metric], row[f"{metric}_ci"] = stats["mean"], stats["ci"]
                out.rows.append(row)
            entry = {"design": specs[d], "capture": capture, "obstruction": kind, "n": len(units)}
            for metric in metrics:
                stats = mean_ci(deltas(capture, d, kind, metric), metric=f"delta_{metric}")
                entry[f"delta_{metric}"], entry[f"delta_{metric}_ci"] = stats["mean"], stats["ci"]
            out.deltas.append(entry)
        # design against design on the same kind of capture, and each design's recon against its raw
        pairs = [(a, b) for i, a in enumerate(cells) for b in cells[i + 1 :] if a[0] == b[0] or a[1] == b[1]]
        for (cap_a, a), (cap_b, b) in pairs:
            first_cell, second_cell = ((cap_b, b), (cap_a, a)) if a == b else ((cap_a, a), (cap_b, b))  # recon − raw
            for condition in (*CONDITIONS, "delta"):
                for metric in metrics:
                    if condition == "delta":
                        first, second = deltas(*first_cell, kind, metric), deltas(*second_cell, kind, metric)
                    else:
                        first, second = (values(*cell, kind, condition, metric) for cell in (first_cell, second_cell))
                    stats = paired_difference_ci(first, second, metric=metric)
                    out.comparisons.append(
                        {
                            "design": specs[first_cell[1]],
                            "capture": first_cell[0],
                            "versus": specs[second_cell[1]],
                            "versus_capture": second_cell[0],
                            "obstruction": kind,
                            "condition": condition,
                            "metric": metric,
                            "difference": stats["mean"],
                            "ci": stats["ci"],
                            "n": stats["n"],
                        }
                    )


def evaluation_report(result: Evaluation, extra: dict, notes: list[str], csv_path=None, plot_path=None) -> dict:
    """The JSON report of an evaluation: rows, deltas, comparisons, units, images, the confidence
    level, ``extra`` (what was evaluated and how), ``notes``, warnings and the files written."""
    return {
        "rows": result.rows,
        "deltas": result.deltas,
        "comparisons": result.comparisons,
        "units": result.units,
        "images": result.images,
        "confidence": 0.95,
        **extra,
        "notes": notes,
        "warnings": result.warnings,
        **({"csv": str(csv_path)} if csv_path else {}),
        **({"plot": str(plot_path)} if plot_path else {}),
    }


def write_rows_csv(path: str | os.PathLike[str], rows: list[dict], metrics=("psnr_db", "ssim")) -> None:
    """The rows of an evaluation as CSV, atomically: design, capture, obstruction, condition, n,
    then per metric its mean and the bounds of its confidence interval."""
    columns = ["design", "capture", "obstruction", "condition", "n"] + [
        c for m in metrics for c in (m, f"{m}_lo", f"{m}_hi")
    ]
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow(
            {
                **{k: row[k] for k in ("design", "capture", "obstruction", "condition", "n")},
                **{
                    c: v
                    for m in metrics
                    for c, v in ((m, row[m]), (f"{m}_lo", row[f"{m}_ci"][0]), (f"{m}_hi", row[f"{m}_ci"][1]))
                },
            }
        )
    with atomic_write(path) as temporary:
        temporary.write_text(buffer.getvalue(), encoding="utf-8")
