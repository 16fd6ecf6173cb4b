"""`metalens tolerance`: how good the fabrication must be for a design (sensitivity, Monte Carlo,
budgets, photographs)."""

from __future__ import annotations

import math

import click

from metalens_cli.cli import render
from metalens_cli.cli.options import (
    Angle,
    Length,
    LightLevels,
    MetalensCommand,
    OutputFile,
    SeedList,
    announce,
    device_option,
    geometry_options,
    json_option,
    load_preset_option,
    max_memory_option,
    plot_option,
    quiet_option,
    torch_device,
)
from metalens_cli.errors import InputError
from metalens_cli.io import units


class SignedLength(click.ParamType):
    """A length that may be negative or zero: ``10nm``, ``-5nm``, ``0nm`` → metres."""

    name = "length"

    def convert(self, value, param, ctx):
        """The signed length in metres (``io.units.parse_signed_length``); a bad value fails with
        the accepted form."""
        if not isinstance(value, str):
            return value
        try:
            return units.parse_signed_length(value, param.opts[0])
        except InputError as exc:
            self.fail(f"{exc.message} (expected {exc.expected})", param, ctx)


class Fraction(click.ParamType):
    """A fraction in [0, 1): ``0.001`` or ``0.1%``."""

    name = "fraction"

    def convert(self, value, param, ctx):
        """The fraction as a float; a bad value fails with the accepted form."""
        if not isinstance(value, str):
            return value
        text = value.strip()
        try:
            number = float(text[:-1]) / 100 if text.endswith("%") else float(text)
        except ValueError:
            self.fail(f"{value!r} is not a fraction (expected e.g. 0.001 or 0.1%)", param, ctx)
        if not (math.isfinite(number) and 0 <= number < 1):
            self.fail(f"{value!r} is out of range (expected a fraction in [0, 1), e.g. 0.1%)", param, ctx)
        return number


@click.command("tolerance", cls=MetalensCommand)
@click.argument("spec", metavar="DESIGN")
@geometry_options
@click.option("--rotation-sigma", type=Angle(), help="σ of each fin's rotation error, e.g. 2deg (independent per fin).")
@click.option("--theta-levels", type=click.IntRange(2, 4096), help="θ rounded to N levels per π by data preparation.")
@click.option("--missing", type=Fraction(), help="Fraction of fins missing, e.g. 0.1% (each converts nothing).")
@click.option(
    "--stitch-field", "stitch_field_m", type=Length(), default="100um", show_default=True, help="Write-field side."
)
@click.option(
    "--stitch-sigma", "stitch_sigma_m", type=Length(), help="σ per axis of each write field's placement, e.g. 20nm."
)
@click.option(
    "--width-bias", "width_bias_m", type=SignedLength(), help="Every fin's width off by this, e.g. 10nm or -5nm."
)
@click.option("--width-sigma", "width_sigma_m", type=Length(), help="σ of each fin's width about its biased value.")
@click.option("--length-bias", "length_bias_m", type=SignedLength(), help="Every fin's length off by this.")
@click.option("--length-sigma", "length_sigma_m", type=Length(), help="σ of each fin's length.")
@click.option(
    "--budget",
    help='A loss the design may take, "strehl -10%", "mtf50 -10%" or "core-far -5%": the largest error of each '
    "source that keeps it, and the Monte Carlo yield.",
)
@click.option("--draws", type=click.IntRange(0, 10000), help="Monte Carlo draws of 2-D maps [0].")
@click.option(
    "--seed",
    "seeds",
    type=SeedList(),
    default="0",
    show_default=True,
    help="Seeds: the first draws the Monte Carlo maps; each is a noise and obstruction draw of every photograph.",
)
@click.option("--photos", type=click.IntRange(0, 1000), help="Obstructed photographs scored [0].")
@click.option(
    "--light",
    "light_levels",
    type=LightLevels(),
    default="2000",
    show_default=True,
    help="The photographs' camera: electrons at full scale before each design's filter (none: noise-free).",
)
@click.option(
    "--obstruction", default="dirt", show_default=True, help="Obstructions of the photographs, e.g. dirt,fence."
)
@click.option("--band-samples", type=click.IntRange(1, 15), default=3, show_default=True, help="Wavelengths per band.")
@click.option(
    "--z-near", "z_near_m", type=Length(), help="Near (obstruction) depth [the preset's mid z_near, else 45mm]."
)
@click.option("--pixel-pitch", "pixel_pitch_m", type=Length(), help="Sensor pixel pitch [the preset's, else 1.85um].")
@click.option("--z-far", "z_far_m", type=Length(allow_inf=True), default="inf", show_default=True, help="Far depth.")
@device_option
@quiet_option()
@max_memory_option
@json_option
@plot_option
@click.option("--csv", "csv_path", type=OutputFile((".csv",)), help="Also write the sensitivity table as CSV.")
def tolerance(
    spec,
    preset_path,
    f_m,
    aperture_m,
    pitch_m,
    rotation_sigma,
    theta_levels,
    missing,
    stitch_field_m,
    stitch_sigma_m,
    width_bias_m,
    width_sigma_m,
    length_bias_m,
    length_sigma_m,
    budget,
    draws,
    seeds,
    photos,
    light_levels,
    obstruction,
    band_samples,
    z_near_m,
    pixel_pitch_m,
    z_far_m,
    device,
    quiet,
    max_memory,
    as_json,
    plot_path,
    csv_path,
):
    """How each fabrication error degrades DESIGN, and how large each may be.

    Per error source and combined: the far and near 5 × 5 core energy per pass band, the Strehl
    ratio (far peak over the design's) and MTF50, as expected over the fins (exact in
    expectation for errors independent per fin; a lens of N fins equals it to O(1/√N)).
    Rotation, θ levels and stitching are phase errors (rotation: exp(−(2σ)²) of the focused light;
    N levels: sinc²(π/N); stitching: the pupil mean of exp(−σ²|∇φ|²/2), squared); width and
    length bias and spread change each fin's η and unconverted light (RCWA of the preset's fin,
    cached); a missing fin converts nothing. Light the errors scatter is a flat veil; the
    zero order passes the analyzer with its leak (1 %).

    --budget: the largest error of each source alone that keeps the loss (both signs for a bias;
    for θ levels the fewest levels). --draws N: N drawn 2-D maps of the positional and rotational
    errors through the 2-D propagator (slow; for lenses whose 2-D map fits), their mean with 95 %
    CIs and, with --budget, the yield. --photos N: N photographs imaged through the design and
    through each fabricated lens under --light, paired PSNR and SSIM changes with 95 % CIs.
    """
    from metalens_cli.imaging import tolerance as tol
    from metalens_cli.io.designs import resolve_design
    from metalens_cli.optics import fabrication as fab

    preset = load_preset_option(preset_path)
    design = resolve_design(spec, preset, f_m=f_m, aperture_m=aperture_m, pitch_m=pitch_m)
    table = design.preset.tolerance if design.preset is not None else None
    given = {
        "rotation_sigma_rad": rotation_sigma,
        "theta_levels": theta_levels,
        "missing": missing,
        "stitch_field_m": stitch_field_m,
        "stitch_sigma_m": stitch_sigma_m,
        "width_bias_m": width_bias_m,
        "width_sigma_m": width_sigma_m,
        "length_bias_m": length_bias_m,
        "length_sigma_m": length_sigma_m,
    }
    errors = tol.errors_from(given, table)
    budget = budget if budget is not None else (table.budget if table is not None else None)
    draws = draws if draws is not None else (table.draws or 0 if table is not None else 0)
    photos = photos if photos is not None else (table.photos or 0 if table is not None else 0)
    if not errors.sources():
        raise InputError(
            "--rotation-sigma",
            "no error source given",
            "at least one of "
            + ", ".join(o for o in fab.OPTIONS.values() if o != "--stitch-field")
            + " (or the preset's [tolerance])",
        )
    parsed_budget = tol.parse_budget(budget) if budget is not None else None
    if errors.dimensional() and design.preset is None:
        raise InputError(
            "--preset", f"{design.spec} has no nanofin for width and length errors", "a preset with [nanofin]"
        )
    in_force = design.preset
    settings = tol.ToleranceSettings(
        bands=tol.preset_bands(in_force),
        band_samples=band_samples,
        z_far_m=z_far_m,
        z_near_m=z_near_m or tol.preset_near(in_force),
        pixel_pitch_m=pixel_pitch_m or (in_force.sensor.pixel_pitch_m if in_force is not None else 1.85e-6),
        device=torch_device(device),
    )
    evaluation = None
    if photos:
        from metalens_cli.imaging.obstructions import parse_obstructions

        kinds = parse_obstructions(obstruction)
        evaluation = tol.photo_settings(design, photos, light_levels, settings)
    announce(tol.estimate(design, errors, settings, draws, photos), max_memory, device=settings.device)
    from metalens_cli.cli.progress import progress_bar

    with progress_bar("tolerance", quiet) as update:
        steps = [0]

        def step(text):
            steps[0] += 1
            update(steps[0], steps[0] + 1)

        result = tol.analyse(design, errors, settings, budget=parsed_budget, on_progress=step)
        if draws:
            result.monte_carlo = tol.monte_carlo(
                design, errors, settings, draws, seeds[0], budget=parsed_budget, on_draw=update
            )
        if photos:
            cases = [(label, case) for label, case in tol.cases_of(errors)]
            result.photos, report = tol.photo_scores(design, cases, evaluation, kinds, seeds, on_progress=update)
            result.warnings += report["warnings"]
    report = tol.report(result)
    from metalens_cli.io.atomic import atomic_files

    with atomic_files(csv_path, plot_path) as (csv_file, plot_file):
        if csv_file is not None:
            csv_file.write_text(tol.csv_text(result), encoding="utf-8")
        if plot_file is not None:
            from metalens_cli.plotting.tolerance import plot_tolerance

            plot_tolerance(plot_file, result)
    render.say(result.warnings)
    if as_json:
        render.emit_json(
            {**report, **({"csv": csv_path} if csv_path else {}), **({"plot": plot_path} if plot_path else {})}
        )
        return
    _render(result)


def _percent(ratio) -> str:
    return "—" if ratio is None or not math.isfinite(ratio) else f"{100 * (ratio - 1):+.2f} %"


def _render(result) -> None:
    from metalens_cli.optics.fabrication import OPTIONS

    con = render.console()
    names = [f"{c * 1e9:.0f} nm" for c, _ in result.settings["bands_m"]]
    rows = []
    for case in result.cases:
        rel = case["relative"]
        for b, band in enumerate(names):
            rows.append(
                [
                    case["source"] if b == 0 else "",
                    band,
                    _percent(rel["strehl"][b]),
                    _percent(rel["core_far"][b]),
                    _percent(rel["core_near"][b]),
                    _percent(rel["mtf50_lpmm"][b]),
                    "" if case["within_budget"] is None or b else ("yes" if case["within_budget"] else "[red]no[/]"),
                ]
            )
    con.print(
        render.table(
            f"Fabrication tolerance of {result.design['spec']}: change against the design (expected over the fins)",
            ["source", "band", "Strehl", "core far", "core near", "MTF50", "in budget"],
            rows,
        )
    )
    for entry in result.budgets:
        option = OPTIONS[entry["source"]]
        if "levels" in entry:
            text = "none within range" if entry["levels"] is None else f"at least {entry['levels']} levels"
        else:
            text = ", ".join(
                ("beyond " if limit["beyond_range"] else "") + _magnitude(entry["source"], limit["largest"])
                for limit in entry["limits"]
            )
        con.print(f"budget: {option} {text}")
    mc = result.monte_carlo
    if mc is not None:
        strehl = mc["relative"]["strehl"]
        parts = [f"{n}: {s['mean']:.4f} [{s['ci'][0]:.4f}, {s['ci'][1]:.4f}]" for n, s in zip(names, strehl)]
        con.print(f"Monte Carlo, {mc['draws']} drawn 2-D maps: Strehl " + "; ".join(parts))
        if "yield" in mc:
            y = mc["yield"]
            con.print(f"yield within {y['budget']}: {y['fraction']:.0%} [{y['ci'][0]:.0%}, {y['ci'][1]:.0%}]")
    for p in result.photos:
        if p["metric"] == "psnr_db":
            con.print(
                f"photos, {p['source']}, {p['obstruction']} {p['condition']}"
                f"{' at ' + p['light'] if 'light' in p else ''}: PSNR {p['change']:+.3f} dB "
                f"[{p['ci'][0]:+.3f}, {p['ci'][1]:+.3f}] (n = {p['n']})"
            )


def _magnitude(source: str, value: float) -> str:
    if source == "rotation_sigma_rad":
        return f"{math.degrees(value):.3g}°"
    if source == "missing":
        return f"{100 * value:.3g} %"
    return f"{value * 1e9:+.3g} nm" if "bias" in source else f"{value * 1e9:.3g} nm"
