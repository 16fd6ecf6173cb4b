"""`metalens symmetry`: wavelength ↔ depth under the depth-wavelength model."""

from __future__ import annotations

import click

from metalens_cli.analysis import symmetry as model
from metalens_cli.cli import render
from metalens_cli.cli.options import (
    Length,
    LengthList,
    MetalensCommand,
    Wavelength,
    WavelengthList,
    announce,
    flatten,
    json_option,
    load_preset_option,
    max_memory_option,
    pick,
    plot_option,
    preset_option,
    quiet_option,
)
from metalens_cli.cli.progress import progress_bar
from metalens_cli.io.units import LENGTH_FORM, format_length

NOTES = {
    "infinite": "asymptote: λ = λd focuses from infinity",
    "virtual": "no real depth: λ < λd (virtual source)",
    "real": "",
}


@click.command(cls=MetalensCommand)
@preset_option
@click.option("--f", "f_m", type=Length(), help="Focal length (lens-to-design-plane distance), e.g. 4mm.")
@click.option("--lambda-d", "lambda_d_m", type=Wavelength(), help="Design wavelength, e.g. 450nm.")
@click.option(
    "--wavelength",
    "wavelengths",
    type=WavelengthList(),
    multiple=True,
    help="Wavelengths: 530nm, 500nm,600nm or 430:645:5nm (repeatable). Default 400:700:10nm.",
)
@click.option(
    "--depth",
    "depths",
    type=LengthList(allow_inf=True),
    multiple=True,
    help="Depths z: the wavelength λd(1 + f/z) focused from there (repeatable; inf allowed).",
)
@click.option(
    "--delta-z",
    "delta_z_m",
    type=Length(),
    help="Depth step Δz (> 0, toward the lens) for Δλ = λd·f·(1/z − 1/(z − Δz)).",
)
@click.option("--at-depth", "at_depth_m", type=Length(allow_inf=True), help="Depth z at which --delta-z is taken.")
@click.option("--z-near", "z_near_m", type=Length(), help="Near depth drawn on the plot.")
@click.option(
    "--validate",
    is_flag=True,
    help="Check the model against the on-axis Rayleigh-Sommerfeld intensity of the hyperbolic lens (needs --aperture).",
)
@click.option("--aperture", "aperture_m", type=Length(), help="Lens diameter D for --validate, e.g. 2.516mm.")
@quiet_option()
@max_memory_option
@json_option
@plot_option
def symmetry(
    preset_path,
    f_m,
    lambda_d_m,
    wavelengths,
    depths,
    delta_z_m,
    at_depth_m,
    z_near_m,
    validate,
    aperture_m,
    quiet,
    max_memory,
    as_json,
    plot_path,
):
    """Depth z = λd·f/(λ − λd) at which each wavelength focuses on the design plane.

    Also the inverse λ = λd(1 + f/z) for --depth, and Δλ for a depth step (--delta-z with
    --at-depth). Values from --f/--lambda-d, or from --preset (lens.focal_length,
    lens.design_wavelength).

    --validate computes, for the hyperbolic lens (λd, f, D), the on-axis intensity on the
    design plane over (λ, z) and reports the depth of maximum intensity beside the model's
    (at NA 0.3 they differ by a few percent: the model is paraxial).
    """
    preset = load_preset_option(preset_path)
    f_m = pick(f_m, preset, lambda p: p.lens.focal_length_m, "--f", LENGTH_FORM)
    lambda_d_m = pick(lambda_d_m, preset, lambda p: p.lens.design_wavelength_m, "--lambda-d", LENGTH_FORM)
    if (delta_z_m is None) != (at_depth_m is None):
        raise click.UsageError("--delta-z and --at-depth go together (e.g. --delta-z 5mm --at-depth 45mm)")
    table = model.symmetry_table(
        f_m,
        lambda_d_m,
        flatten(wavelengths) or model.DEFAULT_WAVELENGTHS_M,
        flatten(depths),
        delta_z_m,
        at_depth_m,
    )
    validation = None
    if validate:
        aperture_m = pick(aperture_m, preset, lambda p: p.lens.aperture_m, "--aperture", LENGTH_FORM)
        validation = _validate(table, aperture_m, quiet, max_memory)
    if plot_path:
        _plot(plot_path, table, validation, aperture_m, z_near_m)
    if as_json:
        render.emit_json(_report(table, validation, aperture_m, plot_path))
        return
    con = render.console()
    _render_table(con, table)
    if validation is not None:
        _render_validation(con, validation)
    if plot_path:
        render.console(stderr=True).print(f"wrote {plot_path}")


def _validate(table: model.SymmetryTable, aperture_m: float, quiet: bool, max_memory):
    """The model checked against the on-axis intensity of the hyperbolic lens of diameter
    ``aperture_m`` at the table's wavelengths, after announcing what it costs."""
    from metalens_cli.analysis.focal_map import estimate_validation, validate_symmetry
    from metalens_cli.io.resources import Estimate

    wavelengths_m = [r.wavelength_m for r in table.rows]
    memory, seconds = estimate_validation(wavelengths_m, table.lambda_d_m, table.f_m, aperture_m)
    announce(
        Estimate(
            f"symmetry --validate of {len(wavelengths_m)} wavelengths for D = {aperture_m * 1e3:g} mm",
            memory,
            "--aperture",
            seconds,
        ),
        max_memory,
    )
    with progress_bar("focal-intensity map", quiet) as update:
        return validate_symmetry(wavelengths_m, table.lambda_d_m, table.f_m, aperture_m, progress=update)


def _plot(plot_path, table: model.SymmetryTable, validation, aperture_m, z_near_m) -> None:
    """The focal-intensity map with the model's curve after --validate, else the model's curve."""
    if validation is not None:
        from metalens_cli.plotting.focal_map import plot_focal_map

        plot_focal_map(plot_path, validation, table.f_m, table.lambda_d_m, aperture_m)
    else:
        from metalens_cli.plotting.symmetry import plot_symmetry

        plot_symmetry(plot_path, table.f_m, table.lambda_d_m, z_near_m=z_near_m)


def _report(table: model.SymmetryTable, validation, aperture_m, plot_path) -> dict:
    """The --json object: the table's, with the validation and the plot when made."""
    out = table.report()
    if validation is not None:
        from metalens_cli.analysis.focal_map import validation_report

        out["validation"] = validation_report(validation, aperture_m)
    if plot_path:
        out["plot"] = str(plot_path)
    return out


def _render_table(con, table: model.SymmetryTable) -> None:
    """The depth of each wavelength; the wavelength of each --depth; Δλ of a --delta-z."""
    con.print(
        render.table(
            f"Depth-wavelength symmetry: f = {format_length(table.f_m)}, λd = {format_length(table.lambda_d_m)}",
            ["λ (nm)", "depth z", "note"],
            [
                [render.nm(r.wavelength_m), format_length(r.depth_m) if r.depth_m else "—", NOTES[r.kind]]
                for r in table.rows
            ],
        )
    )
    if table.focused:
        con.print(
            render.table(
                "Wavelength focused from depth: λ = λd(1 + f/z)",
                ["depth z", "λ (nm)"],
                [[format_length(z), render.nm(w, 3)] for z, w in table.focused],
            )
        )
    delta = table.delta
    if delta is not None:
        con.print(
            f"Δλ = λd·f·(1/z − 1/(z − Δz)) = {delta.delta_wavelength_m * 1e9:.4f} nm for z = "
            f"{format_length(delta.at_depth_m)}, Δz = {format_length(delta.delta_z_m)} (λ: "
            f"{render.nm(delta.wavelength_at_depth_m, 3)} → {render.nm(delta.wavelength_at_shifted_depth_m, 3)} nm)"
        )


def _render_validation(con, v) -> None:
    """The model and the best depth per wavelength, their largest deviation, the quadrature."""
    rows = []
    for r in v.rows:
        deviation = "—" if r.rel_deviation is None else f"{100 * r.rel_deviation:+.2f} %"
        note = "" if r.model_depth_m is not None else "λ ≤ λd: no model depth"
        if r.best_depth_m is None:
            note = note or "no maximum inside the depth range"
        rows.append(
            [
                render.nm(r.wavelength_m),
                format_length(r.model_depth_m) if r.model_depth_m else "—",
                format_length(r.best_depth_m) if r.best_depth_m else "—",
                deviation,
                note,
            ]
        )
    con.print(
        render.table(
            "Validation: depth of maximum on-axis intensity at d = f (Rayleigh-Sommerfeld)",
            ["λ (nm)", "model z", "best z", "deviation", "note"],
            rows,
        )
    )
    worst = v.max_abs_rel_deviation
    con.print(
        f"max |deviation| = {'—' if worst is None else f'{100 * worst:.2f} %'}; quadrature {v.samples} samples, "
        f"doubling changes best depths by ≤ {v.convergence:.1e}; {v.seconds:.1f} s"
    )
