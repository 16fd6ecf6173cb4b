"""The raw-capture evaluation of designs (Suppl. Note 11 protocol), with statistics.

Every design sees the same units: (image, seed) pairs, where a seed draws the depths, the
obstructions and the noise. Per unit and design: the unobstructed and obstructed captures scored
against the clean image (``pipeline.score``: photometric match, then PSNR/SSIM/LPIPS). Reported
per (design, obstruction, condition): the mean over units with a 95 % bootstrap confidence
interval; Δ = obstructed − unobstructed per unit (for LPIPS unobstructed − obstructed, as the
paper defines it: negative is a degradation for every metric); and paired differences between
designs on the same units.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from metalens_cli.analysis.statistics import mean_ci, paired_difference_ci
from metalens_cli.imaging.images import load_images
from metalens_cli.imaging.pipeline import ChannelPsfs, channel_psfs, draw_depths, score, simulate_captures

CONDITIONS = ("unobstructed", "obstructed")


@dataclass
class EvaluationSettings:
    """What every unit shares: sensor, depth intervals (m), wavelengths (m), image source,
    obstruction parameters, formation and scoring options."""

    pixels: int
    pixel_pitch_m: float
    z_near_interval_m: tuple[float, float]
    z_far_interval_m: tuple[float, float]
    wavelengths_m: list[float]
    images: str = "builtin"
    limit: int | None = None
    obstruction_params: object = None
    formation: str = "physical"
    match: str = "luminance"
    alpha_gain: float | None = None
    photons: float | None = None
    read_noise: float = 0.0
    psf_window: int | None = None
    device: object = "cpu"


@dataclass
class Evaluation:
    """Results: ``rows`` (design, obstruction, condition, metric means, ``<metric>_ci``, n),
    ``deltas``, ``comparisons`` (paired design differences), ``units`` (every score), ``psfs``
    (per design and seed: depths, windows, kept light), ``images`` (names), ``panels`` (first
    image and seed, for figures) and ``warnings``."""

    rows: list[dict] = field(default_factory=list)
    deltas: list[dict] = field(default_factory=list)
    comparisons: list[dict] = field(default_factory=list)
    units: list[dict] = field(default_factory=list)
    psfs: list[dict] = field(default_factory=list)
    images: list[str] = field(default_factory=list)
    panels: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


def metric_names(lpips_model) -> tuple[str, ...]:
    return ("psnr_db", "ssim", "lpips") if lpips_model is not None else ("psnr_db", "ssim")


def delta(metric: str, unobstructed: float, obstructed: float) -> float:
    """Δ of one unit: obstructed − unobstructed, or unobstructed − obstructed for LPIPS (lower is better)."""
    return unobstructed - obstructed if metric == "lpips" else obstructed - unobstructed


def evaluate(designs, kinds: list[str], seeds: list[int], settings: EvaluationSettings, lpips_model=None,
             on_progress: Callable[[int, int], None] | None = None) -> Evaluation:
    """Score every design on the same (image, seed) units for every obstruction kind."""
    out = Evaluation()
    psfs: dict[tuple[int, int], ChannelPsfs] = {}
    for d, design in enumerate(designs):
        for seed in seeds:
            z_near, z_far = draw_depths(settings.z_near_interval_m, settings.z_far_interval_m, seed)
            p = channel_psfs(design, z_near, z_far, settings.wavelengths_m, settings.pixel_pitch_m,
                             device=settings.device, window=settings.psf_window)
            psfs[d, seed] = p
            out.psfs.append({"design": design.spec, "seed": seed, "z_near_m": z_near, "z_far_m": z_far, **p.report(),
                             "seconds": p.seconds})
            out.warnings += [f"{design.spec}, seed {seed}: {w}" for w in p.warnings()]
    margin = max(p.margin for p in psfs.values())  # one canvas for all: every design sees the same scene
    images = load_images(settings.images, (settings.pixels, settings.pixels), settings.limit, margin)
    out.images = [image.name for image in images]
    metrics = metric_names(lpips_model)
    scores: dict[tuple, dict] = {}
    total, done = len(designs) * len(kinds) * len(seeds), 0
    out.panels = {design.spec: [] for design in designs}
    for kind in kinds:
        for seed in seeds:
            obstructions: dict = {}  # generated once, shared by the designs (same seed, depths and canvas)
            for d, design in enumerate(designs):
                captures = simulate_captures(images, kind, psfs[d, seed], design.focal_length_m, settings.pixel_pitch_m, seed,
                                             settings.obstruction_params, settings.formation, settings.alpha_gain,
                                             settings.photons, settings.read_noise, obstructions)
                for index, c in enumerate(captures):
                    key = (d, "unobstructed", seed, index)  # the same for every obstruction kind
                    if key not in scores:
                        scores[key] = score(c.unobstructed, c.clean, lpips_model, settings.match)
                    scores[d, kind, seed, index] = score(c.obstructed, c.clean, lpips_model, settings.match)
                    out.units.append({"design": design.spec, "obstruction": kind, "seed": seed, "image": c.name,
                                      "unobstructed": scores[key], "obstructed": scores[d, kind, seed, index]})
                if seed == seeds[0]:
                    first, panels = captures[0], out.panels[design.spec]
                    if not panels:
                        panels += [("clean", first.clean), ("unobstructed", first.unobstructed)]
                    panels.append((f"obstructed: {kind}", first.obstructed))
                done += 1
                if on_progress is not None:
                    on_progress(done, total)
    _summarise(out, designs, kinds, seeds, len(images), metrics, scores)
    return out


def _summarise(out: Evaluation, designs, kinds, seeds, n_images: int, metrics, scores) -> None:
    units = [(seed, index) for seed in seeds for index in range(n_images)]

    def values(d, kind, condition, metric):
        return [scores[(d, "unobstructed" if condition == "unobstructed" else kind, seed, index)][metric] for seed, index in units]

    def deltas(d, kind, metric):
        return [delta(metric, u, o) for u, o in zip(values(d, kind, "unobstructed", metric), values(d, kind, "obstructed", metric))]

    for kind in kinds:
        for d, design in enumerate(designs):
            for condition in CONDITIONS:
                row = {"design": design.spec, "obstruction": kind, "condition": condition, "n": len(units)}
                for metric in metrics:
                    stats = mean_ci(values(d, kind, condition, metric), metric=metric)
                    row[metric], row[f"{metric}_ci"] = stats["mean"], stats["ci"]
                out.rows.append(row)
            entry = {"design": design.spec, "obstruction": kind, "n": len(units)}
            for metric in metrics:
                stats = mean_ci(deltas(d, kind, metric), metric=f"delta_{metric}")
                entry[f"delta_{metric}"], entry[f"delta_{metric}_ci"] = stats["mean"], stats["ci"]
            out.deltas.append(entry)
        for a in range(len(designs)):
            for b in range(a + 1, len(designs)):
                for condition in (*CONDITIONS, "delta"):
                    for metric in metrics:
                        if condition == "delta":
                            first, second = deltas(a, kind, metric), deltas(b, kind, metric)
                        else:
                            first, second = values(a, kind, condition, metric), values(b, kind, condition, metric)
                        stats = paired_difference_ci(first, second, metric=metric)
                        out.comparisons.append({"design": designs[a].spec, "versus": designs[b].spec, "obstruction": kind,
                                                "condition": condition, "metric": metric, "difference": stats["mean"],
                                                "ci": stats["ci"], "n": stats["n"]})
