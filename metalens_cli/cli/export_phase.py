"""`metalens export-phase`: a design's phase as a surface lens-design programs read (Zemax
OpticStudio's Binary 2 in a .zmx, the JSON metalens-phase/1, or CSV)."""

from __future__ import annotations

import click

from metalens_cli.cli import render
from metalens_cli.cli.options import (
    Length,
    MetalensCommand,
    Number,
    OutputFile,
    geometry_options,
    json_option,
    load_preset_option,
)

SUFFIXES = (".zmx", ".json", ".csv", ".dat")  # io.phase_files.PHASE_SUFFIXES (not imported: it pulls in numpy)
MAX_TERMS = 64  # analysis.phase_export.MAX_TERMS


@click.command("export-phase", cls=MetalensCommand)
@click.argument("spec", metavar="DESIGN")
@geometry_options
@click.option(
    "-o",
    "--output",
    type=OutputFile(SUFFIXES),
    required=True,
    help="Output file: .zmx, .json, .csv or .dat (OpticStudio Grid Phase data), by suffix.",
)
@click.option(
    "--order",
    type=click.IntRange(1, MAX_TERMS),
    help=f"Binary 2 terms A_1..A_N on ρ², …, ρ^2N (1-{MAX_TERMS}) [the fewest within --tolerance].",
)
@click.option(
    "--tolerance",
    "tolerance_waves",
    type=Number(0, min_open=True),
    help="Largest fit residual allowed, in waves (1 wave = 2π rad) [0.01].",
)
@click.option("--norm-radius", "norm_radius_m", type=Length(), help="Binary 2 normalisation radius R_norm [D/2].")
@json_option
@click.pass_context
def export_phase(
    ctx, spec, preset_path, f_m, aperture_m, pitch_m, output, order, tolerance_waves, norm_radius_m, as_json
):
    """Write DESIGN's phase φ = 2θ as a surface lens-design programs read.

    A radial design becomes a Binary 2 phase, M·Σ A_i (r/R_norm)^2i in radians at every
    wavelength (M = 1), fitted by least squares to the unwrapped φ(r) − φ(0) at the design's
    samples in the pupil; the fit's residual is reported, and a tolerance no order up to 64
    reaches is refused. A 2-D design is written as its grid phase (.json with a .npy map beside
    it, or .csv). Formats and sign convention: docs/formats.md.
    """
    from metalens_cli.analysis import phase_export
    from metalens_cli.io.designs import resolve_design

    preset = load_preset_option(preset_path)
    design = resolve_design(spec, preset, f_m=f_m, aperture_m=aperture_m, pitch_m=pitch_m)
    report, warnings = phase_export.export_phase(
        design,
        output,
        order=order,
        tolerance_waves=phase_export.DEFAULT_TOLERANCE_WAVES if tolerance_waves is None else tolerance_waves,
        tolerance_given=tolerance_waves is not None,
        norm_radius_m=norm_radius_m,
    )
    render.say(warnings)
    if as_json:
        render.emit_json({**report.to_dict(), "design": design.describe(), "warnings": warnings})
        return
    con = render.console()
    if report.kind == "grid":
        con.print(f"wrote {', '.join(report.files)}: grid phase of {report.sites:,} sites, {report.seconds:.2f} s")
        return
    res = report.residual
    rows = [
        ["file", report.file],
        ["terms N", str(report.order)],
        ["R_norm", f"{report.norm_radius_m * 1e3:.6g} mm"],
        ["residual rms", f"{res['rms_waves']:.3g} wave ({res['rms_rad']:.3g} rad)"],
        ["residual max", f"{res['max_waves']:.3g} wave ({res['max_rad']:.3g} rad)"],
        ["A_1", f"{report.coefficients_rad[0]:.10g} rad"],
        ["samples", str(res["samples"])],
        ["time", f"{report.seconds:.2f} s"],
    ]
    con.print(render.table(f"Binary 2 phase of {design.spec}", ["key", "value"], rows))
