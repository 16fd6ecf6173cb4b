"""Choosing the nanofin: η over a grid of fin widths and lengths, per pass band, and the fin to
fabricate (Suppl. Note 7 of the paper).

Per geometry (width w along x, length l along y) and pass band (centre c, FWHM b): η is
averaged over ``samples_per_band`` wavelengths evenly across [c − b/2, c + b/2]; the score of a
fin is the mean of its band efficiencies. The recommended fin has the best score among those
whose neighbourhood (every grid fin within ± ``tolerance_m`` in both w and l: the fabrication
tolerance) keeps at least ``keep`` of that score; the neighbourhood is cut at the grid's edges.
The map is computed with a cheap truncation, all fins of a row of the grid in one batch
(:func:`metalens_cli.optics.fin_modes.fin_responses_symmetric`); :func:`refine` recomputes the
chosen fin and its neighbourhood with a converged one (coarse to fine); :func:`sweep_fins` does
all of it, the map and the refinement cached on disk (:mod:`metalens_cli.io.cache`; an entry
that is not η in 0..1 of the grid's shape, or not a refinement's JSON, is set aside and redone);
:func:`recommended_nanofin` makes the result a preset's ``[nanofin]``, so that the optics and
the layout use the fin that was chosen; :func:`sweep_cell` fills in the cell and bands a sweep
was not given.
"""

from __future__ import annotations

import contextlib
import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from metalens_cli.analysis.bands import filter_bands
from metalens_cli.constants import PAPER_BANDS_M, PAPER_FIN_HEIGHT_M, PAPER_PITCH_M
from metalens_cli.errors import InputError
from metalens_cli.io import cache
from metalens_cli.io.presets import NanofinConfig
from metalens_cli.optics.fin import Fin
from metalens_cli.optics.fin_modes import fin_responses_symmetric
from metalens_cli.optics.nanofin import FIRST_HARMONICS, SOLVER, converge

BAND_SAMPLES = 8  # 3 bands × 8: the 24 wavelengths of issue 17's benchmark
NEAR = 1 + 1e-9  # a grid fin at ± the tolerance, to rounding, is a neighbour


@dataclass
class FinMap:
    """``eta`` (L, W, B): band-mean η per fin length (rows), width (columns) and band; ``score``
    (L, W) its mean over the bands; the grid in metres; ``wavelengths_m`` (B, samples per band)."""

    widths_m: np.ndarray
    lengths_m: np.ndarray
    bands_m: list[tuple[float, float]]
    wavelengths_m: np.ndarray
    eta: np.ndarray
    harmonics: int
    seconds: float

    @property
    def score(self) -> np.ndarray:
        """(L, W) mean of ``eta`` over the bands."""
        return self.eta.mean(axis=-1)


@dataclass(frozen=True)
class SweepCell:
    """The cell a sweep's fins stand in and the bands they are scored over: lattice ``period_m``,
    fin ``height_m``, ``material`` and ``substrate`` (as ``--material`` takes them), ``bands_m``
    (centre, FWHM), lengths in metres."""

    period_m: float
    height_m: float
    material: str
    substrate: str
    bands_m: list[tuple[float, float]]


def sweep_cell(
    preset=None,
    *,
    period_m: float | None = None,
    height_m: float | None = None,
    material: str | None = None,
    substrate: str | None = None,
    bands_m=(),
) -> SweepCell:
    """Each value given, else the ``preset``'s ``[nanofin]`` and filter bands, else the paper's
    (395 nm, 700 nm, sinx on fused-silica, its three bands)."""
    fin = preset.nanofin if preset is not None else None
    preset_bands = (
        []
        if preset is None or preset.filter is None
        else [((b.lo_m + b.hi_m) / 2, b.hi_m - b.lo_m) for b in filter_bands(preset.filter)]
    )
    return SweepCell(
        period_m=period_m if period_m is not None else (fin.pitch_m if fin else PAPER_PITCH_M),
        height_m=height_m if height_m is not None else (fin.height_m if fin else PAPER_FIN_HEIGHT_M),
        material=material or (fin.material if fin else "sinx"),
        substrate=substrate or (fin.substrate if fin else "fused-silica"),
        bands_m=list(bands_m) or preset_bands or list(PAPER_BANDS_M),
    )


def band_wavelengths(bands_m: list[tuple[float, float]], samples: int = BAND_SAMPLES) -> np.ndarray:
    """(B, samples) wavelengths evenly across each band's FWHM (one sample: the centre)."""
    if samples == 1:
        return np.array([[c] for c, _ in bands_m])
    return np.array([np.linspace(c - b / 2, c + b / 2, samples) for c, b in bands_m])


def fin_map(
    period_m: float,
    height_m: float,
    widths_m,
    lengths_m,
    bands_m,
    fin_index: Callable,
    substrate_index: Callable,
    harmonics: int,
    *,
    on_progress: Callable[[int, int], None] | None = None,
    samples_per_band: int = BAND_SAMPLES,
    device=None,
) -> FinMap:
    """η of every (length, width) fin of the grid that fits in its cell (others NaN), averaged per
    band; ``fin_index``/``substrate_index`` map wavelengths (m) to complex indices; ``device``
    a torch device (None: cpu)."""
    widths, lengths = np.asarray(widths_m, float), np.asarray(lengths_m, float)
    waves = band_wavelengths(bands_m, samples_per_band)
    flat = waves.ravel()
    n_fin, n_sub = fin_index(flat), substrate_index(flat)
    eta = np.full((lengths.size, widths.size, len(bands_m)), np.nan)
    seconds = 0.0
    for i, length in enumerate(lengths):
        columns = [j for j, width in enumerate(widths) if width <= period_m and length <= period_m]
        if columns:
            fins = [Fin(period_m, height_m, widths[j], length) for j in columns]
            responses = fin_responses_symmetric(fins, n_fin, n_sub, flat, harmonics, device)
            eta[i, columns] = [r.conversion.reshape(waves.shape).mean(axis=1) for r in responses]
            seconds += sum(float(r.seconds.sum()) for r in responses)
        if on_progress is not None:
            on_progress((i + 1) * widths.size, lengths.size * widths.size)
    if np.isnan(eta).all():
        raise InputError("width", "no fin of the grid fits in its cell", "widths and lengths up to the period")
    return FinMap(widths, lengths, list(bands_m), waves, eta, harmonics, seconds)


def _neighbourhood(m: FinMap, i: int, j: int, tolerance_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Row and column masks of the grid fins within ± ``tolerance_m`` of fin (i, j)."""
    rows = np.abs(m.lengths_m - m.lengths_m[i]) <= tolerance_m * NEAR
    cols = np.abs(m.widths_m - m.widths_m[j]) <= tolerance_m * NEAR
    return rows, cols


def largest_neighbourhood(widths_m, lengths_m, tolerance_m: float) -> int:
    """The most grid fins that one fin's neighbourhood holds (cut at the grid's edges): the most
    :func:`refine` recomputes."""

    def most(grid) -> int:
        grid = np.sort(np.asarray(grid, float))
        reach = tolerance_m * NEAR
        return int((np.searchsorted(grid, grid + reach, "right") - np.searchsorted(grid, grid - reach, "left")).max())

    return most(widths_m) * most(lengths_m)


def refine(
    m: FinMap,
    choice: dict,
    period_m: float,
    height_m: float,
    fin_index: Callable,
    substrate_index: Callable,
    harmonics: int,
    *,
    device=None,
) -> dict:
    """The recommended fin (``choice`` from :func:`recommend`) and every grid fin of its
    neighbourhood recomputed with ``harmonics`` at the map's wavelengths: ``harmonics``,
    ``score``, ``eta_per_band``, ``worst_neighbour``, ``robust`` (the keep rule at this
    truncation), ``fins`` recomputed and ``seconds``."""
    i, j = (
        int(np.argmin(np.abs(m.lengths_m - choice["length_m"]))),
        int(np.argmin(np.abs(m.widths_m - choice["width_m"]))),
    )
    rows, cols = _neighbourhood(m, i, j, choice["tolerance_m"])
    sites = [
        (r, c)
        for r in np.nonzero(rows)[0]
        for c in np.nonzero(cols)[0]
        if m.widths_m[c] <= period_m and m.lengths_m[r] <= period_m
    ]
    flat = m.wavelengths_m.ravel()
    fins = [Fin(period_m, height_m, m.widths_m[c], m.lengths_m[r]) for r, c in sites]
    responses = fin_responses_symmetric(fins, fin_index(flat), substrate_index(flat), flat, harmonics, device)
    per_band = [r.conversion.reshape(m.wavelengths_m.shape).mean(axis=1) for r in responses]
    centre = per_band[sites.index((i, j))]
    score, worst = float(centre.mean()), float(min(p.mean() for p in per_band))
    return {
        "harmonics": harmonics,
        "score": score,
        "eta_per_band": centre.tolist(),
        "worst_neighbour": worst,
        "robust": worst >= choice["keep"] * score,
        "fins": len(fins),
        "seconds": sum(float(r.seconds.sum()) for r in responses),
    }


def recommend(m: FinMap, tolerance_m: float = 10e-9, keep: float = 0.95) -> dict:
    """The recommended fin (see the module docstring): ``width_m``, ``length_m``, ``score``,
    ``worst_neighbour`` (the lowest score within the tolerance), ``eta_per_band``, and whether a
    fin met the ``keep`` rule (``robust``; when none does, the best score is returned)."""
    score = np.where(np.isnan(m.score), -np.inf, m.score)
    best = None
    for i, j in sorted(np.ndindex(score.shape), key=lambda ij: -score[ij]):
        if not np.isfinite(score[i, j]):
            break
        rows, cols = _neighbourhood(m, i, j, tolerance_m)
        worst = float(score[np.ix_(rows, cols)].min())
        if best is None:
            best = (i, j, worst, False)
        if worst >= keep * score[i, j]:
            best = (i, j, worst, True)
            break
    i, j, worst, robust = best
    return {
        "width_m": float(m.widths_m[j]),
        "length_m": float(m.lengths_m[i]),
        "score": float(score[i, j]),
        "worst_neighbour": worst,
        "eta_per_band": m.eta[i, j].tolist(),
        "robust": robust,
        "tolerance_m": tolerance_m,
        "keep": keep,
    }


@dataclass
class Sweep:
    """A sweep's map, the recommended fin (:func:`recommend`'s dict with ``converged``, from
    :func:`refine` and the convergence table), whether the map and the refinement came from the
    cache, and warnings for the user."""

    map: FinMap
    choice: dict
    cached: bool
    converged_cached: bool
    warnings: list[str] = field(default_factory=list)


def sweep_fins(
    period_m: float,
    height_m: float,
    widths_m,
    lengths_m,
    bands_m,
    fin_index: Callable,
    substrate_index: Callable,
    harmonics: int,
    *,
    samples_per_band: int = BAND_SAMPLES,
    tolerance_m: float = 10e-9,
    keep: float = 0.95,
    max_harmonics: int = 35,
    device=None,
    progress: Callable = lambda stage: contextlib.nullcontext(None),
) -> Sweep:
    """The map at ``harmonics`` (:func:`fin_map`), the recommended fin (:func:`recommend`), its
    converged N (:func:`~metalens_cli.optics.nanofin.converge` at the map's wavelengths, up to
    ``max_harmonics``) and its neighbourhood at that N (:func:`refine`), each read from the disk
    cache when it holds them. ``progress(stage)`` gives a context manager yielding an
    ``update(done, total)`` callback or None."""
    widths, lengths = np.asarray(widths_m, float), np.asarray(lengths_m, float)
    waves = band_wavelengths(bands_m, samples_per_band)
    flat = waves.ravel()
    key = cache.input_key(
        {
            "period_m": period_m,
            "height_m": height_m,
            "widths_m": widths,
            "lengths_m": lengths,
            "wavelengths_m": flat,
            "fin_index": fin_index(flat),
            "substrate_index": substrate_index(flat),
            "harmonics": harmonics,
            "solver": SOLVER,
        }
    )

    def compute_map() -> dict[str, np.ndarray]:
        with progress("nanofin sweep") as update:
            m = fin_map(
                period_m,
                height_m,
                widths,
                lengths,
                bands_m,
                fin_index,
                substrate_index,
                harmonics,
                on_progress=update,
                samples_per_band=samples_per_band,
                device=device,
            )
        return {"eta": m.eta, "seconds": np.array(m.seconds)}

    fits = (lengths[:, None] <= period_m) & (widths[None, :] <= period_m)
    stored = cache.cached("nanofin-sweep", key, compute_map, lambda arrays: _map_problem(arrays, fits, len(bands_m)))
    m = FinMap(widths, lengths, list(bands_m), waves, stored.arrays["eta"], harmonics, float(stored.arrays["seconds"]))
    choice = recommend(m, tolerance_m, keep)
    fine_key = cache.input_key(
        {
            "map": key,
            "fin_m": [choice["width_m"], choice["length_m"]],
            "tolerance_m": tolerance_m,
            "keep": keep,
            "max_harmonics": max_harmonics,
        }
    )

    def compute_refinement() -> dict[str, np.ndarray]:
        fin = Fin(period_m, height_m, choice["width_m"], choice["length_m"])
        with progress("converging the chosen fin") as update:
            chosen, table, _ = converge(
                fin,
                fin_index(flat),
                substrate_index(flat),
                flat,
                start=FIRST_HARMONICS,
                stop=max_harmonics,
                tolerance=1e-3,
                device=device,
                on_progress=update,
            )
        converged = {
            "harmonics": chosen or table[-1]["harmonics"],
            "convergence": table,
            "converged": chosen is not None,
        }
        converged.update(
            refine(m, choice, period_m, height_m, fin_index, substrate_index, converged["harmonics"], device=device)
        )
        return {"report": np.array(json.dumps(converged))}

    stored_fine = cache.cached(
        "nanofin-refine",
        fine_key,
        compute_refinement,
        lambda arrays: _refinement_problem(arrays, len(bands_m), max_harmonics),
    )
    choice["converged"] = json.loads(str(stored_fine.arrays["report"]))
    return Sweep(m, choice, stored.hit, stored_fine.hit, _warnings(m, choice))


def _map_problem(stored: dict[str, np.ndarray], fits: np.ndarray, bands: int) -> str | None:
    """Why a cached map is not one :func:`fin_map` gives (None: it may be): ``eta`` (L, W, B) in
    0..1 for the fins that ``fits`` (L, W) in their cell, NaN for the others; seconds ≥ 0."""
    reason = cache.check_array(stored, "eta", (*fits.shape, bands), 0, 1, where=fits[..., None]) or cache.check_array(
        stored, "seconds", (), 0
    )
    if reason is None and not np.isnan(stored["eta"][~fits]).all():
        return "eta: a value for a fin that does not fit in its cell"
    return reason


def _refinement_problem(stored: dict[str, np.ndarray], bands: int, max_harmonics: int) -> str | None:
    """Why a cached refinement is not the JSON that :func:`sweep_fins` writes (None: it may be):
    η and scores in 0..1 (one η per band), at least three N (converge compares each with the two
    before) up to ``max_harmonics`` ending at the N chosen, flags true or false, times ≥ 0."""
    try:
        fine = json.loads(str(stored["report"]))
        table = fine["convergence"]
        fractions = [
            fine["score"],
            fine["worst_neighbour"],
            *fine["eta_per_band"],
            *(row["conversion"] for row in table),
        ]
        orders = [fine["harmonics"], *(row["harmonics"] for row in table)]
        amounts = [fine["seconds"], *(row["seconds"] for row in table), *(row["max_change"] for row in table[1:])]
        flags, chosen = [fine["converged"], fine["robust"]], fine["harmonics"] == table[-1]["harmonics"]
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        return f"report: not a refinement ({type(exc).__name__}: {exc})"
    if not (all(_number(v, 0, 1) for v in fractions) and len(fine["eta_per_band"]) == bands):
        return f"report: η or scores outside 0..1, or not {bands} band(s)"
    if not (len(table) >= 3 and chosen and all(_whole(n, 1, max_harmonics) for n in orders)):
        return f"report: not a convergence table of at least 3 N up to {max_harmonics} ending at the N chosen"
    if not (
        _whole(fine["fins"], 1, math.inf)
        and all(_number(v, 0, math.inf) for v in amounts)
        and all(isinstance(f, bool) for f in flags)
    ):
        return "report: a count, time or change negative or not a number, or a flag not true/false"
    return None


def _number(value, low: float, high: float) -> bool:
    """Whether a JSON value is a finite number within [low, high] (true and false are not)."""
    return (
        isinstance(value, (int, float))
        and not isinstance(value, bool)
        and low <= value <= high
        and abs(value) != math.inf
    )


def _whole(value, low: float, high: float) -> bool:
    """Whether a JSON value is an integer within [low, high]."""
    return isinstance(value, int) and _number(value, low, high)


def _warnings(m: FinMap, choice: dict) -> list[str]:
    """What the user should know about a sweep's answer: no convergence, a fin on the grid's
    edge, a neighbourhood that keeps less at converged N than on the map."""
    fine, warnings = choice["converged"], []
    table = fine["convergence"]
    if not fine["converged"]:
        warnings.append(
            f"the chosen fin's η moved up to {table[-1]['max_change']:.2g} from N = {table[-2]['harmonics']} to "
            f"{table[-1]['harmonics']}; raise --max-harmonics"
        )
    if choice["width_m"] in (m.widths_m[0], m.widths_m[-1]) or choice["length_m"] in (m.lengths_m[0], m.lengths_m[-1]):
        warnings.append(
            f"the recommended fin ({choice['width_m'] * 1e9:g} × {choice['length_m'] * 1e9:g} nm) lies on the grid's "
            "edge: a better one may lie beyond it; widen --width/--length"
        )
    if not fine["robust"] and choice["robust"]:
        warnings.append(
            f"converged at N = {fine['harmonics']}, a neighbour of the chosen fin keeps less than {choice['keep']:g} "
            "of its η"
        )
    return warnings


def recommended_nanofin(period_m: float, height_m: float, material: str, substrate: str, choice: dict) -> NanofinConfig:
    """The recommended fin (``choice`` of :func:`sweep_fins`) as a preset's ``[nanofin]``: η by
    RCWA at the harmonics its refinement converged at; a material CSV by its absolute path."""
    from pathlib import Path

    from metalens_cli.io.materials import material_file

    def spec(text: str) -> str:
        return str(Path(text).resolve()) if material_file(text) else text

    return NanofinConfig(
        pitch_m=period_m,
        height_m=height_m,
        width_m=choice["width_m"],
        length_m=choice["length_m"],
        material=spec(material),
        substrate=spec(substrate),
        efficiency="rcwa",
        harmonics=int(choice["converged"]["harmonics"]),
    )
