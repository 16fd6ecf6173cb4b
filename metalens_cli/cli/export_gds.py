"""`metalens export-gds`: a design's nanofin layout as GDSII or OASIS for e-beam lithography."""

from __future__ import annotations

import click

from metalens_cli.cli import render
from metalens_cli.cli.options import (
    Length,
    MetalensCommand,
    OutputFile,
    announce,
    design_options,
    json_option,
    load_preset_option,
    max_memory_option,
    pick,
    quiet_option,
)
from metalens_cli.cli.progress import progress_bar
from metalens_cli.io import units


class LayerSpec(click.ParamType):
    """``LAYER/DATATYPE`` (``1/0``) or ``LAYER`` (datatype 0) → (layer, datatype)."""

    name = "layer"

    def convert(self, value, param, ctx):
        """The (layer, datatype) pair of ints for ``LAYER/DATATYPE`` or ``LAYER`` (datatype 0); a
        bad value fails with the accepted form."""
        if isinstance(value, tuple):
            return value
        parts = str(value).split("/")
        if len(parts) > 2 or not all(part.strip().isdigit() for part in parts):
            self.fail(f"{value!r} is not LAYER/DATATYPE (expected e.g. 1/0)", param, ctx)
        return int(parts[0]), int(parts[1]) if len(parts) == 2 else 0


class AnglesSpec(click.ParamType):
    """``exact`` → None, or a number of quantised levels K."""

    name = "exact|K"

    def convert(self, value, param, ctx):
        """None for ``exact`` (any case), else the int number K of quantised θ levels; a bad value
        fails with the accepted form."""
        text = str(value).strip().lower()
        if value is None or text == "exact":
            return None
        if not text.isdigit():
            self.fail(
                f"{value!r} is neither exact nor a whole number of levels (expected exact or K, e.g. 128)", param, ctx
            )
        return int(text)


@click.command("export-gds", cls=MetalensCommand)
@design_options
@click.option("--width", "width_m", type=Length(), help="Nanofin width (the side at angle θ) [preset's].")
@click.option("--length", "length_m", type=Length(), help="Nanofin length [preset's].")
@click.option("--layer", type=LayerSpec(), default="1/0", show_default=True, help="GDS layer/datatype.")
@click.option(
    "--dbu", "dbu_m", type=Length(), default="1nm", show_default=True, help="Database unit: vertices are rounded to it."
)
@click.option("-o", "--output", type=OutputFile(), required=True, help="Output file, .gds or .oas.")
@click.option("--format", "fmt", type=click.Choice(("gds", "oas")), help="Output format [from the extension].")
@click.option(
    "--angles",
    type=AnglesSpec(),
    default="exact",
    show_default=True,
    help="exact: one polygon per fin at its own θ; K: θ quantised to K referenced cells (phase error ≤ π/K).",
)
@click.option(
    "--verify",
    is_flag=True,
    help="Read the file back with KLayout and check count and a random sample of fins; exit 1 on mismatch.",
)
@quiet_option()
@max_memory_option
@json_option
@click.pass_context
def export_gds(
    ctx,
    spec,
    preset_path,
    f_m,
    aperture_m,
    pitch_m,
    width_m,
    length_m,
    layer,
    dbu_m,
    output,
    fmt,
    angles,
    verify,
    quiet,
    max_memory,
    as_json,
):
    """Write the nanofin layout of a design for e-beam lithography.

    The lens centre is the layout origin and a site; sites at multiples of the pitch within D/2
    each carry a width × length rectangle, its width side at θ counter-clockwise from +x
    (phase 2θ), vertices rounded to the database unit. One top cell named after the design holds
    the fins and a text element recording the tool version, design and geometry.
    """
    from metalens_cli.io.designs import resolve_design
    from metalens_cli.io.layout import FinGeometry, estimate_layout, export_layout, format_of
    from metalens_cli.io.layout_verify import require_klayout
    from metalens_cli.io.resources import Estimate

    preset = load_preset_option(preset_path)
    design = resolve_design(spec, preset, f_m=f_m, aperture_m=aperture_m, pitch_m=pitch_m)
    in_force = design.preset
    geometry = FinGeometry(
        pitch_m=design.lens.pitch_m,
        width_m=pick(width_m, in_force, lambda p: p.nanofin.width_m, "--width", units.LENGTH_FORM),
        length_m=pick(length_m, in_force, lambda p: p.nanofin.length_m, "--length", units.LENGTH_FORM),
        dbu_m=dbu_m,
        layer=layer[0],
        datatype=layer[1],
    )
    fmt = format_of(output, fmt)
    fins, disk, memory, seconds = estimate_layout(design.lens.aperture_m, geometry.pitch_m, fmt, angles)
    announce(Estimate(f"export-gds of {fins:,} nanofins", memory, "--aperture", seconds, disk), max_memory, output)
    if verify:
        require_klayout()
    with progress_bar("export-gds", quiet) as update:
        report = export_layout(design, geometry, output, fmt=fmt, angles=angles, progress=update)
    checked = None
    if verify:
        from metalens_cli.io.layout_verify import verify_layout

        checked = verify_layout(output, design, geometry, angles)
    efficiency, warnings = None, []
    if in_force is not None:
        from metalens_cli.cli.progress import efficiency_used

        efficiency = efficiency_used(in_force, quiet)
        fin = in_force.nanofin
        if (geometry.width_m, geometry.length_m, geometry.pitch_m) != (fin.width_m, fin.length_m, fin.pitch_m):
            warnings.append(
                f"the layout's fin ({geometry.width_m * 1e9:g} × {geometry.length_m * 1e9:g} nm at "
                f"{geometry.pitch_m * 1e9:g} nm) is not the preset's ({fin.width_m * 1e9:g} × {fin.length_m * 1e9:g} "
                f"nm at {fin.pitch_m * 1e9:g} nm), whose η the optics used"
            )
    render.say(warnings)
    if as_json:
        render.emit_json(
            {
                **report.to_dict(),
                "efficiency": efficiency,
                "warnings": warnings,
                **({"verify": checked.to_dict()} if checked else {}),
            }
        )
    else:
        _render(report, checked)
    ctx.exit(1 if checked is not None and not checked.ok else 0)


def _render(report, checked) -> None:
    con = render.console()
    phase = (
        "exact rotations"
        if report.max_phase_error_rad == 0
        else f"max phase error {report.max_phase_error_rad:.4f} rad"
    )
    con.print(
        f"wrote {report.file}: {report.atoms:,} nanofins, {report.bytes / 1e6:.1f} MB {report.format.upper()}, "
        f"top cell {report.top_cell}, {phase}, {report.seconds:.1f} s"
    )
    if checked is None:
        return
    w = checked.worst
    status = "[green]verified[/]" if checked.ok else "[red]MISMATCH[/]"
    con.print(
        f"{status}: {checked.found_atoms:,} fins read (expected {checked.expected_atoms:,}); {checked.samples} sampled "
        f"sites, worst centre {w.get('centre_m', 0) * 1e9:.2f} nm, width {w.get('width_m', 0) * 1e9:.2f} nm, length "
        f"{w.get('length_m', 0) * 1e9:.2f} nm, rotation {w.get('rotation_rad', 0):.4f} rad, phase vs design "
        f"{w.get('phase_vs_design_rad', 0):.4f} rad"
    )
    for failure in checked.failures:
        con.print(f"  {failure}")
