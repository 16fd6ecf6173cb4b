"""Fabrication tolerance of a design: sensitivity, Monte Carlo and budgets (``metalens tolerance``).

Per error source (``optics.fabrication``) and for all of them together, the fabricated lens's
light at each wavelength splits into coherent C (focused like the design), scattered V (a flat
veil) and unconverted U (the zero order, passed by the analyzer with ``leak``), all fractions of
the light entering the lens. From the design's monochromatic PSFs P (``optics.psf``, the
fraction of the pupil's power on each pixel) the fabricated lens's PSF is, in expectation,

    C(λ)·P + V(λ)·veil_per_pixel(λ) + leak·U(λ)·(a²/(π R_zo²)),

the last two flat over the window (the zero-order disc of radius R_zo = a·(1 + d/z) covers
it). The nominal lens has C = η, V = 0, U = 1 − η, η the preset's nanofin efficiency (1 without
one). Each pass band is sampled at ``band_samples`` wavelengths across its FWHM and its PSF is
their mean. Metrics per band:

- ``core_far``, ``core_near``: light in the central 5 × 5 pixels at the far and near depth,
  a fraction of the light entering the lens (L_sharp's core);
- ``strehl``: the far PSF at the design's peak pixel over the design's peak (a Strehl ratio with the design as
  reference, 1 without errors);
- ``mtf50_lpmm``: MTF50 of the far PSF over its window (``analysis.mtf``).

The expected PSF is exact in expectation for independent per-fin errors, and a lens of N fins
equals it to O(1/√N) in its coherent part; the Monte Carlo (:func:`monte_carlo`) draws 2-D
realisations of the positional and rotational errors (``fabricated_map``) and computes their
PSFs with the 2-D propagator: the slow path, for lenses whose 2-D map fits.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from metalens_cli.analysis.mtf import mtf50, psf_mtf, radial_grid
from metalens_cli.analysis.psf_metrics import central_energy
from metalens_cli.analysis.statistics import mean_ci
from metalens_cli.constants import DEFAULT_ZERO_ORDER_LEAK
from metalens_cli.errors import InputError
from metalens_cli.optics import fabrication as fab

PAPER_BANDS = ((457e-9, 22e-9), (530e-9, 20e-9), (628e-9, 28e-9))  # the paper's tri-band filter (centre, FWHM)
METRICS = ("core_far", "core_near", "peak", "mtf50_lpmm")  # per band, of the expected PSFs
RELATIVE = ("strehl", "core_far", "core_near", "mtf50_lpmm")  # their ratios to the design's (strehl: the peaks')
BUDGET_METRICS = {"strehl": "strehl", "mtf50": "mtf50_lpmm", "core-far": "core_far"}
BUDGET_FORM = 'a metric and the loss it may have, e.g. "strehl -10%", "mtf50 -10%" or "core-far -5%"'
SEARCH_RANGES = {  # where the largest magnitude within a budget is looked for (SI units, rad)
    "rotation_sigma_rad": (0.0, math.radians(45)),
    "theta_levels": (2, 256),
    "missing": (0.0, 0.5),
    "stitch_sigma_m": (0.0, 2e-6),
    "width_bias_m": (-80e-9, 80e-9),
    "width_sigma_m": (0.0, 25e-9),
    "length_bias_m": (-60e-9, 60e-9),
    "length_sigma_m": (0.0, 20e-9),
}
SEARCH_STEPS = 14  # bisections: 2^-14 of the range


@dataclass(frozen=True)
class ToleranceSettings:
    """Where the metrics are taken: the pass bands (centre, FWHM in m), wavelengths per band,
    the far and near depths (m; inf: a plane wave), the sensor pixel pitch (m), the analyzer's
    zero-order leak and the torch device."""

    bands: tuple[tuple[float, float], ...] = PAPER_BANDS
    band_samples: int = 3
    z_far_m: float = math.inf
    z_near_m: float = 45e-3
    pixel_pitch_m: float = 1.85e-6
    zero_order_leak: float = DEFAULT_ZERO_ORDER_LEAK
    device: object = "cpu"

    def wavelengths(self) -> np.ndarray:
        """(B, S) wavelengths (m): each band's FWHM sampled at its S midpoints of equal parts."""
        parts = (np.arange(self.band_samples) + 0.5) / self.band_samples - 0.5
        return np.array([[c + w * t for t in parts] for c, w in self.bands])


@dataclass(frozen=True)
class Budget:
    """A loss a design may take: ``metric`` (one of ``RELATIVE``) may fall by at most ``loss``
    (a fraction, 0.1 for −10 %) in every band."""

    metric: str
    loss: float
    text: str

    def holds(self, relative: dict) -> bool:
        """True when every band's ``relative`` value (fabricated over nominal) keeps the budget."""
        return all(v >= 1 - self.loss - 1e-12 for v in relative[self.metric])


def parse_budget(text: str) -> Budget:
    """``"strehl -10%"`` → Budget("strehl", 0.1); the metric one of strehl, mtf50, core-far."""
    parts = str(text).split()
    if len(parts) != 2 or parts[0] not in BUDGET_METRICS or not parts[1].startswith("-") or not parts[1].endswith("%"):
        raise InputError("--budget", repr(text), BUDGET_FORM)
    try:
        loss = float(parts[1][1:-1]) / 100
    except ValueError:
        raise InputError("--budget", repr(text), BUDGET_FORM) from None
    if not 0 < loss < 1:
        raise InputError("--budget", repr(text), f"a loss between 0 and 100 %: {BUDGET_FORM}")
    return Budget(BUDGET_METRICS[parts[0]], loss, text)


@dataclass
class Light:
    """Per wavelength (..., fractions of the light entering the lens): ``coherent`` C,
    ``scattered`` V and ``unconverted`` U (module docstring); ``fin``: the RCWA report."""

    coherent: np.ndarray
    scattered: np.ndarray
    unconverted: np.ndarray
    fin: dict = field(default_factory=dict)


def design_efficiency(design, wavelengths_m: np.ndarray) -> np.ndarray:
    """η at ``wavelengths_m``: the preset's nanofin efficiency, the design's ``efficiency``, else 1."""
    from metalens_cli.imaging.camera import design_factors

    flat = np.asarray(wavelengths_m, dtype=float).ravel()
    return design_factors(design, flat)[2].reshape(np.shape(wavelengths_m))


def fabricated_light(design, errors: fab.FabricationErrors, wavelengths_m: np.ndarray, *, phase: bool = True) -> Light:
    """C, V and U of ``design`` fabricated with ``errors`` at ``wavelengths_m`` (any shape).

    Dimensional errors scale the preset's η by the RCWA ratio κ(λ) of the fabricated fins' coherent
    light to the design fin's (``io.fin_variations``), their scattered light likewise, and change
    the unconverted light by the RCWA change of the co-polarised power; missing fins then convert
    nothing; ``phase``: the positional and rotational factor
    (``fabrication.phase_factor``) moves coherent light into the veil."""
    eta = design_efficiency(design, wavelengths_m)
    coherent, scattered, unconverted, fin = eta.copy(), np.zeros_like(eta), 1 - eta, {}
    if errors.dimensional():
        if design.preset is None:
            raise InputError(
                "--preset", f"{design.spec} has no nanofin for width and length errors", "a preset with [nanofin]"
            )
        from metalens_cli.io.fin_variations import fabricated_fin_light

        flat = np.asarray(wavelengths_m, dtype=float).ravel()
        light = fabricated_fin_light(design.preset.nanofin, flat, errors)
        per = eta / light.design_conversion.reshape(eta.shape)
        coherent = light.coherent.reshape(eta.shape) * per
        scattered = light.scattered.reshape(eta.shape) * per
        unconverted = np.clip(1 - eta + (light.unconverted - light.design_unconverted).reshape(eta.shape), 0.0, None)
        fin = {"rcwa_solves": light.solves, "seconds": light.seconds, "kappa": light.kappa.tolist()}
    p = errors.missing
    converted = coherent + scattered
    coherent, scattered, unconverted = (
        (1 - p) ** 2 * coherent,
        (1 - p) * scattered + p * (1 - p) * coherent,
        (unconverted + p * converted),
    )
    if phase:
        kappa = fab.phase_factor(design.lens, errors)
        coherent, scattered = kappa * coherent, scattered + (1 - kappa) * coherent
    return Light(coherent, scattered, unconverted, fin)


@dataclass
class NominalPsfs:
    """The design's monochromatic PSFs (B, S, N, N) at the far and near depth (fraction of the
    pupil's power per pixel, float64), their wavelengths (B, S), windows and seconds."""

    far: np.ndarray
    near: np.ndarray
    wavelengths_m: np.ndarray
    windows: tuple[int, int]
    seconds: float


def _psfs(lens, settings: ToleranceSettings, distance_m: float, windows: tuple[int, int], propagator: str = "auto"):
    """(far, near) PSF stacks (B, S, N, N) of ``lens`` at the settings' wavelengths."""
    import torch

    from metalens_cli.optics.psf import compute_psf
    from metalens_cli.optics.sampling import PsfGrid

    lams = settings.wavelengths()
    out = []
    for z, n in zip((settings.z_far_m, settings.z_near_m), windows):
        grid = PsfGrid(list(lams.ravel()), [z], n, settings.pixel_pitch_m, distance_m)
        with torch.no_grad():
            psf = compute_psf(lens, grid, propagator=propagator, dtype=torch.float64, device=settings.device).psf
        out.append(psf[0].cpu().numpy().reshape(*lams.shape, n, n))
    return out


def psf_windows(design, settings: ToleranceSettings) -> tuple[int, int]:
    """(far, near) odd windows that hold every band's light (``optics.blur.psf_window``)."""
    from metalens_cli.optics.blur import psf_window

    lams = list(settings.wavelengths().ravel())
    return tuple(
        psf_window(design.lens, lams, [z], design.focal_length_m, settings.pixel_pitch_m)
        for z in (settings.z_far_m, settings.z_near_m)
    )


def nominal_psfs(design, settings: ToleranceSettings) -> NominalPsfs:
    """The design's PSFs at the settings' wavelengths and depths, each depth in the window its
    light needs."""
    start = time.perf_counter()
    windows = psf_windows(design, settings)
    far, near = _psfs(design.lens, settings, design.focal_length_m, windows)
    return NominalPsfs(far, near, settings.wavelengths(), windows, time.perf_counter() - start)


def _flat(light: Light, lams: np.ndarray, depth_m: float, design, settings: ToleranceSettings) -> np.ndarray:
    """(B, S) light per pixel that is flat over the window: the veil and the zero order."""
    from metalens_cli.optics.zero_order import zero_order_radius_m

    d, a = design.focal_length_m, settings.pixel_pitch_m
    veil = light.scattered * fab.veil_per_pixel(design.lens.pitch_m, a, lams, d)
    radius = zero_order_radius_m(design.lens.aperture_m, d, depth_m)
    return veil + settings.zero_order_leak * light.unconverted * a**2 / (math.pi * radius**2)


def band_metrics(
    far: np.ndarray,
    near: np.ndarray,
    light: Light,
    lams: np.ndarray,
    design,
    settings: ToleranceSettings,
    peak_at: list | None = None,
) -> dict:
    """Per band: the metrics (module docstring) of the expected PSFs C·P + flat, P the (B, S, N, N)
    PSF stacks ``far`` and ``near``. ``peak``: the far PSF at ``peak_at`` (per band, a flat pixel
    index: the design's peak, so that a fabricated lens is compared where the design focuses;
    None: each PSF's own maximum, whose position ``peak_px`` gives)."""
    out = {}
    for name, stack, z in (("far", far, settings.z_far_m), ("near", near, settings.z_near_m)):
        flat = _flat(light, lams, z, design, settings)
        psf = (light.coherent[..., None, None] * stack + flat[..., None, None]).mean(axis=1)  # (B, N, N)
        out[f"core_{name}"] = central_energy(psf, 5).tolist()
        if name == "far":
            rows = psf.reshape(psf.shape[0], -1)
            at = rows.argmax(axis=1) if peak_at is None else np.asarray(peak_at)
            out["peak"] = rows[np.arange(rows.shape[0]), at].tolist()
            out["peak_px"] = at.tolist()
            grid = radial_grid(psf.shape[-1], settings.pixel_pitch_m)
            out["mtf50_lpmm"] = mtf50(grid.frequencies_lpmm, psf_mtf(psf, grid)).tolist()
    return out


def relative(metrics: dict, nominal: dict) -> dict:
    """Each metric over the nominal one, per band (Strehl: the peak ratio)."""
    ratio = {
        m: (np.asarray(metrics[m]) / np.asarray(nominal[m])).tolist() for m in ("core_far", "core_near", "mtf50_lpmm")
    }
    ratio["strehl"] = (np.asarray(metrics["peak"]) / np.asarray(nominal["peak"])).tolist()
    return ratio


@dataclass
class ToleranceResult:
    """``nominal``: the design's metrics; ``cases``: per source (and ``combined``) its errors,
    metrics and their ratios to the nominal; ``budgets``: per source the largest magnitude that
    keeps the budget; ``monte_carlo``: draws, means with CIs and yield; ``photos``: paired
    obstructed-PSNR changes; ``seconds``; ``warnings``."""

    design: dict
    settings: dict
    nominal: dict
    cases: list[dict]
    budgets: list[dict] = field(default_factory=list)
    monte_carlo: dict | None = None
    photos: list[dict] = field(default_factory=list)
    seconds: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


def cases_of(errors: fab.FabricationErrors) -> list[tuple[str, fab.FabricationErrors]]:
    """One case per source (its option's name) and, with two or more, ``combined``."""
    names = errors.sources()
    cases = [(fab.OPTIONS[name].removeprefix("--"), errors.only(name)) for name in names]
    return cases + ([("combined", errors)] if len(names) > 1 else [])


def analyse(
    design,
    errors: fab.FabricationErrors,
    settings: ToleranceSettings,
    *,
    budget: Budget | None = None,
    on_progress: Callable[[str], None] | None = None,
) -> ToleranceResult:
    """The expected metrics of ``design`` per error source and combined, and with a ``budget``
    the largest magnitude of each source that keeps it (bisection over ``SEARCH_RANGES``)."""
    start = time.perf_counter()
    say = on_progress or (lambda text: None)
    if not errors.sources():
        raise InputError("errors", "none given", "at least one error source, e.g. --rotation-sigma 2deg")
    say("nominal PSFs")
    psfs = nominal_psfs(design, settings)
    lams = psfs.wavelengths_m
    nominal_light = fabricated_light(design, fab.FabricationErrors(), lams)
    nominal = band_metrics(psfs.far, psfs.near, nominal_light, lams, design, settings)
    cases = []
    for label, case in cases_of(errors):
        say(label)
        light = fabricated_light(design, case, lams)
        metrics = band_metrics(psfs.far, psfs.near, light, lams, design, settings, nominal["peak_px"])
        cases.append(
            {
                "source": label,
                "errors": {name: getattr(case, name) for name in case.sources()},
                "kappa": (light.coherent / nominal_light.coherent).mean(axis=1).tolist(),
                "veil_on_sensor_pixel": _flat(light, lams, settings.z_far_m, design, settings).mean(axis=1).tolist(),
                "metrics": metrics,
                "relative": relative(metrics, nominal),
                "within_budget": None if budget is None else budget.holds(relative(metrics, nominal)),
                **({"fin": light.fin} if light.fin else {}),
            }
        )
    budgets = []
    if budget is not None:
        for name in errors.sources():
            say(f"budget of {fab.OPTIONS[name]}")
            budgets.append(largest_within(design, psfs, nominal, errors, name, budget, settings))
    result = ToleranceResult(
        design.describe(),
        settings_report(settings, psfs),
        nominal,
        cases,
        budgets,
        seconds={"psfs": psfs.seconds, "total": time.perf_counter() - start},
    )
    return result


def settings_report(settings: ToleranceSettings, psfs: NominalPsfs) -> dict:
    """The settings as JSON-ready values, with the PSF windows."""
    return {
        "bands_m": [list(b) for b in settings.bands],
        "wavelengths_m": psfs.wavelengths_m.tolist(),
        "z_far_m": None if math.isinf(settings.z_far_m) else settings.z_far_m,
        "z_near_m": settings.z_near_m,
        "pixel_pitch_m": settings.pixel_pitch_m,
        "zero_order_leak": settings.zero_order_leak,
        "windows_px": {"far": psfs.windows[0], "near": psfs.windows[1]},
    }


def largest_within(
    design, psfs: NominalPsfs, nominal: dict, errors: fab.FabricationErrors, name: str, budget: Budget, settings
) -> dict:
    """The largest magnitude of source ``name`` alone (both signs for a bias) whose expected
    metrics keep ``budget``; for θ levels, the fewest levels that do."""
    lams = psfs.wavelengths_m

    def keeps(value) -> bool:
        case = replace(fab.FabricationErrors(stitch_field_m=errors.stitch_field_m), **{name: value})
        light = fabricated_light(design, case, lams)
        metrics = band_metrics(psfs.far, psfs.near, light, lams, design, settings, nominal["peak_px"])
        return budget.holds(relative(metrics, nominal))

    lo, hi = SEARCH_RANGES[name]
    if name == "theta_levels":
        if not keeps(hi):
            return {"source": name, "levels": None, "note": f"even {hi} levels exceed the budget"}
        good, bad = hi, lo - 1
        while good - bad > 1:
            mid = (good + bad) // 2
            good, bad = (mid, bad) if keeps(mid) else (good, mid)
        return {"source": name, "levels": good}
    limits = []
    for end in (lo, hi) if lo < 0 else (hi,):  # a bias: each sign on its own
        if keeps(end):
            limits.append({"towards": end, "largest": end, "beyond_range": True})
            continue
        good, bad = 0.0 if lo < 0 else lo, end
        for _ in range(SEARCH_STEPS):
            mid = (good + bad) / 2
            good, bad = (mid, bad) if keeps(mid) else (good, mid)
        limits.append({"towards": end, "largest": good, "beyond_range": False})
    return {"source": name, "limits": limits}


def monte_carlo(
    design,
    errors: fab.FabricationErrors,
    settings: ToleranceSettings,
    draws: int,
    seed: int,
    *,
    budget: Budget | None = None,
    on_draw: Callable[[int, int], None] | None = None,
) -> dict:
    """``draws`` 2-D realisations of the positional and rotational errors (dimensional ones in
    expectation), their metrics against the error-free 2-D map, the mean and 95 % CI of each
    ratio per band, and with a ``budget`` the yield (fraction of draws within it, with its
    Wilson 95 % interval)."""
    rng = np.random.default_rng(seed)
    start = time.perf_counter()
    windows = psf_windows(design, settings)
    lams = settings.wavelengths()
    reference = fab.fabricated_map(design.lens, fab.FabricationErrors(), rng)
    far0, near0 = _psfs(reference, settings, design.focal_length_m, windows, "asm")
    nominal = band_metrics(far0, near0, fabricated_light(design, fab.FabricationErrors(), lams), lams, design, settings)
    light = fabricated_light(design, errors, lams, phase=False)  # the drawn map carries the phase errors
    ratios = []
    for k in range(draws):
        lens = fab.fabricated_map(design.lens, errors, rng)
        far, near = _psfs(lens, settings, design.focal_length_m, windows, "asm")
        ratios.append(relative(band_metrics(far, near, light, lams, design, settings, nominal["peak_px"]), nominal))
        if on_draw is not None:
            on_draw(k + 1, draws)
    summary = {
        m: [mean_ci([r[m][b] for r in ratios], seed=seed, metric=m) for b in range(len(settings.bands))]
        for m in RELATIVE
    }
    out = {
        "draws": draws,
        "seed": seed,
        "relative": summary,
        "per_draw": ratios,
        "seconds": time.perf_counter() - start,
    }
    if budget is not None:
        passed = sum(budget.holds(r) for r in ratios)
        out["yield"] = {"budget": budget.text, "fraction": passed / draws, "ci": wilson(passed, draws)}
    return out


def wilson(successes: int, n: int, z: float = 1.96) -> list[float]:
    """Wilson score interval (95 % by default) of a proportion ``successes``/``n``."""
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return [max(0.0, centre - half), min(1.0, centre + half)]


PHOTO_STEP_M = 10e-9  # η of a fabricated lens for the photographs: C(λ) every 10 nm over the sensor's range


def fabricated_design(design, errors: fab.FabricationErrors, label: str):
    """``design`` as fabricated with ``errors``, for imaging: its preset's nanofin efficiency
    replaced by the coherent light C(λ) (sampled every ``PHOTO_STEP_M``), so the camera counts
    the focused light the errors leave; the rest goes to the zero order the analyzer passes with
    its leak (the veil's share on the sensor, reported by :func:`analyse`, is left out)."""
    from metalens_cli.optics.spectra import wavelength_grid

    if design.preset is None:
        raise InputError(
            "--photos", f"{design.spec} has no preset", "a design with a preset (a run directory or --preset)"
        )
    lo, hi = design.preset.sensor.wavelength_range_m
    table = [w for w in design.preset.nanofin.efficiency_wavelengths_m if lo < w < hi]
    grid = np.union1d(wavelength_grid(lo, hi, PHOTO_STEP_M), table)  # the table's knots: no error, the same η
    coherent = fabricated_light(design, errors, grid).coherent
    nanofin = replace(
        design.preset.nanofin,
        efficiency=tuple(coherent.tolist()),
        efficiency_wavelengths_m=tuple(grid.tolist()),
        efficiency_csv=None,
    )
    return replace(design, spec=label, preset=replace(design.preset, nanofin=nanofin))


def photo_scores(design, cases, evaluation_settings, kinds, seeds, *, on_progress=None) -> tuple[list[dict], dict]:
    """Obstructed and unobstructed PSNR of each case's fabricated design against the design, paired
    on the same (image, seed) units under ``evaluation_settings``'s camera (``imaging.evaluation``).

    Returns:
        (per case and obstruction: the paired PSNR and SSIM change with its 95 % CI, obstructed and
        unobstructed; the evaluation's report of the design's own scores, images and warnings).
    """
    from metalens_cli.imaging.evaluation import evaluate

    designs = [replace(design, spec="design")] + [fabricated_design(design, errors, label) for label, errors in cases]
    result = evaluate(designs, kinds, seeds, evaluation_settings, on_progress=on_progress)
    changes = []
    for c in result.comparisons:
        if c["design"] == "design" and c["capture"] == c["versus_capture"] == "raw" and c["condition"] != "delta":
            changes.append(
                {
                    "source": c["versus"],
                    "obstruction": c["obstruction"],
                    "condition": c["condition"],
                    "metric": c["metric"],
                    **({"light": c["light"]} if "light" in c else {}),
                    "change": -c["difference"],
                    "ci": [-c["ci"][1], -c["ci"][0]],
                    "n": c["n"],
                }
            )
    rows = [r for r in result.rows if r["design"] == "design"]
    warnings = [w for w in result.warnings if "another nanofin efficiency" not in w]
    return changes, {"design_rows": rows, "images": result.images, "warnings": warnings, "notes": result.notes}


def errors_from(given: dict, table) -> fab.FabricationErrors:
    """The errors of ``given`` (FabricationErrors field → a CLI value, None when not given), each
    missing one from a preset's ``[tolerance]`` ``table`` (or None); a bad value from the table is
    refused naming its key (``tolerance.KEY``)."""
    from dataclasses import fields as dataclass_fields

    values, from_table = {}, {}
    for name, value in given.items():
        if value is not None:
            values[name] = value
        elif table is not None and getattr(table, name) is not None:
            values[name] = from_table[name] = getattr(table, name)
    try:
        return fab.FabricationErrors(**values)
    except InputError as exc:
        keys = {
            fab.OPTIONS[n]: f.metadata["key"]
            for f in dataclass_fields(table or ())
            for n in [f.name]
            if n in from_table
        }
        if exc.field in keys:
            raise InputError(f"tolerance.{keys[exc.field]}", exc.message, exc.expected) from None
        raise


def preset_bands(preset) -> tuple[tuple[float, float], ...]:
    """The pass bands (centre, FWHM) of a preset's filter; the paper's tri-band filter for a
    design without one (a broadband lens is judged on the same bands)."""
    band_filter = None if preset is None else preset.filter
    if band_filter is None or not band_filter.centers_m:
        return PAPER_BANDS
    return tuple(zip(band_filter.centers_m, band_filter.widths_m))


def preset_near(preset) -> float:
    """The near depth (m): the middle of a preset's ``scene.z_near``, else the paper's 45 mm."""
    return 45e-3 if preset is None else float(np.mean(preset.scene.z_near_m))


def photo_settings(design, photos: int, light_levels, settings: ToleranceSettings):
    """The evaluation of :func:`photo_scores`: ``photos`` of the held-out photographs on the
    preset's sensor crop and depth intervals, under the camera of ``light_levels``."""
    from metalens_cli.imaging.evaluation import EvaluationSettings
    from metalens_cli.imaging.pipeline import DEFAULT_WAVELENGTHS
    from metalens_cli.io.units import parse_length_list

    preset = design.preset
    if preset is None:
        raise InputError(
            "--photos", f"{design.spec} has no preset", "a design with a preset (a run directory or --preset)"
        )
    noise = [level for level in light_levels if level is not None]
    return EvaluationSettings(
        preset.sensor.pixels,
        preset.sensor.pixel_pitch_m,
        tuple(preset.scene.z_near_m),
        tuple(preset.scene.z_far_m),
        parse_length_list(DEFAULT_WAVELENGTHS, "--wavelengths"),
        limit=photos,
        obstruction_params=preset.obstruction,
        device=settings.device,
        light_levels=light_levels if noise else None,
        zero_order_leak=settings.zero_order_leak if noise else None,
    )


def estimate(design, errors: fab.FabricationErrors, settings: ToleranceSettings, draws: int, photos: int):
    """The job's cost (``io.resources.Estimate``): the design's PSFs at both depths, each Monte
    Carlo draw's 2-D PSFs (the largest part for a large lens) and the photographs' captures."""
    import torch

    from metalens_cli.io.resources import Estimate
    from metalens_cli.optics.psf import estimate_psf
    from metalens_cli.optics.sampling import PsfGrid

    lams = list(settings.wavelengths().ravel())
    windows = psf_windows(design, settings)
    grids = [
        PsfGrid(lams, [z], n, settings.pixel_pitch_m, design.focal_length_m)
        for z, n in zip((settings.z_far_m, settings.z_near_m), windows)
    ]
    costs = [estimate_psf(design.lens, g, dtype=torch.float64) for g in grids]
    memory, seconds = max(c.memory_bytes for c in costs), sum(c.seconds for c in costs)
    if draws:
        from metalens_cli.optics.lens import Metalens

        m = design.lens.grid_size
        flat = Metalens(torch.zeros(m, m, dtype=torch.float64), design.lens.pitch_m, design.lens.aperture_m)
        mc = [estimate_psf(flat, g, propagator="asm", dtype=torch.float64) for g in grids]
        memory = max(memory, max(c.memory_bytes for c in mc) + 3 * 8 * m * m)
        seconds += (draws + 1) * sum(c.seconds for c in mc)
    if errors.dimensional():
        seconds += 0.3 * len(lams) * (1 + 5 * bool(errors.width_sigma_m)) * (1 + 5 * bool(errors.length_sigma_m))
    what = f"tolerance of {design.spec} ({len(errors.sources())} source(s)"
    what += f", {draws} Monte Carlo draw(s)" if draws else ""
    what += f", {photos} photograph(s))" if photos else ")"
    if photos:
        seconds += 2.0 * photos * (len(cases_of(errors)) + 1)  # a quick-crop capture and its scores
    return Estimate(what, int(memory), "--draws" if draws else "--band-samples", seconds)


def report(result: ToleranceResult) -> dict:
    """The result as one JSON-ready dict (NaN, an MTF50 not reached in the window, as null)."""
    out = {
        "design": result.design,
        "settings": result.settings,
        "nominal": result.nominal,
        "cases": result.cases,
        "budgets": result.budgets,
        "monte_carlo": result.monte_carlo,
        "photos": result.photos,
        "seconds": result.seconds,
        "warnings": result.warnings,
    }
    from metalens_cli.io.json_files import jsonable

    return jsonable(out)


def csv_text(result: ToleranceResult) -> str:
    """One row per case and band: the errors, κ and each metric with its ratio to the design."""
    import csv
    import io

    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["source", "errors", "band_m", "kappa", *METRICS, *[f"{m}_relative" for m in RELATIVE]])
    for case in [
        {"source": "design", "errors": {}, "kappa": [1.0] * len(result.nominal["peak"]), "metrics": result.nominal}
    ] + result.cases:
        for b, (centre, _) in enumerate(result.settings["bands_m"]):
            rel = relative(case["metrics"], result.nominal)
            writer.writerow(
                [
                    case["source"],
                    ";".join(f"{k}={v:g}" for k, v in case["errors"].items()),
                    centre,
                    case["kappa"][b],
                    *[case["metrics"][m][b] for m in METRICS],
                    *[rel[m][b] for m in RELATIVE],
                ]
            )
    return buffer.getvalue()
