"""`metalens bands check`: do a multi-band filter, f and z_near satisfy the split-spectrum conditions?"""

from __future__ import annotations

import click

from metalens_cli.analysis import bands as model
from metalens_cli.cli import render
from metalens_cli.cli.options import (
    Angle,
    BandSpec,
    Interval,
    Length,
    MetalensGroup,
    Number,
    WavelengthInterval,
    json_option,
    load_preset_option,
    pick,
    plot_option,
    preset_option,
)
from metalens_cli.constants import SENSOR_RANGE_M
from metalens_cli.errors import InputError
from metalens_cli.io.units import INTERVAL_FORM, LENGTH_FORM, format_length
from metalens_cli.optics.split_spectrum import incidence_factor


def _incidence(preset, max_incidence, n_eff) -> float:
    """The bands' blue-shift factor: the options, else the preset's [filter], else normal incidence."""
    if max_incidence is None and n_eff is None and preset is not None:
        from metalens_cli.io.presets import preset_incidence_factor

        return preset_incidence_factor(preset)
    band_filter = preset.filter if preset is not None else None
    return incidence_factor(
        max_incidence if max_incidence is not None else 0.0,
        n_eff if n_eff is not None else (band_filter.n_eff if band_filter is not None else 1.8),
    )


@click.group(cls=MetalensGroup)
def bands():
    """Multi-band filter checks."""


def _filter_bands(preset, band_specs, filter_csv, threshold):
    """Pass bands from --band, --filter-csv or the preset's [filter], in that order."""
    if band_specs and filter_csv:
        raise click.UsageError("give either --band or --filter-csv, not both")
    if band_specs:
        return model.bands_from_centers([c for c, _ in band_specs], [w for _, w in band_specs], field="--band")
    if filter_csv:
        return model.bands_from_transmission(*model.read_filter_csv(filter_csv), threshold=threshold)
    if preset is not None and preset.filter is not None:
        return model.filter_bands(preset.filter)
    where = f" (preset {preset.name} has no [filter])" if preset is not None else ""
    raise InputError(
        "--band", f"no filter given{where}", "--band CENTER:WIDTH (repeatable), --filter-csv FILE or --preset FILE"
    )


def report_json(report: model.BandsReport) -> dict:
    """The JSON-ready core of ``metalens bands --json``: lengths in metres, ``s`` one number when it
    is the same over the whole depth range (else [at z hi, at z lo]), every band and condition, the
    windows as [lo, hi] or None."""
    return {
        "ok": report.ok,
        "s": report.s[0] if report.s[0] == report.s[1] else list(report.s),
        "f_m": report.f_m,
        "z_near_m": list(report.z_near_m),
        "sensor_range_m": list(report.sensor_range_m),
        "incidence_factor": report.incidence_factor,
        "bands": [{"label": b.label, "lo_m": b.lo_m, "hi_m": b.hi_m} for b in report.bands],
        "ignored_bands": [{"label": b.label, "lo_m": b.lo_m, "hi_m": b.hi_m} for b in report.ignored_bands],
        "conditions": [
            {
                "name": c.name,
                "lhs_m": c.lhs_m,
                "relation": c.relation,
                "rhs_m": c.rhs_m,
                "depth_m": c.depth_m,
                "margin_m": c.margin_m,
                "ok": c.ok,
            }
            for c in report.conditions
        ],
        "z_near_window_m": list(report.z_near_window_m) if report.z_near_window_m else None,
        "f_window_m": list(report.f_window_m) if report.f_window_m else None,
    }


def _window_text(window) -> str:
    return "none" if window is None else f"{format_length(window[0])} < · < {format_length(window[1])}"


def _render(report: model.BandsReport, efficiency: dict | None) -> None:
    con = render.console()
    z_lo, z_hi = report.z_near_m
    depth = format_length(z_lo) if z_lo == z_hi else f"{format_length(z_lo)} to {format_length(z_hi)}"
    s = f"{report.s[0]:.5f}" if report.s[0] == report.s[1] else f"{report.s[0]:.5f} to {report.s[1]:.5f}"
    con.print(
        "Pass bands: " + ", ".join(f"{b.label} {render.nm(b.lo_m, 1)}-{render.nm(b.hi_m, 1)} nm" for b in report.bands)
    )
    if report.incidence_factor < 1:
        con.print(
            f"Oblique rays move the bands blue by up to {100 * (1 - report.incidence_factor):.2f} %: "
            "the conditions use "
            + ", ".join(
                f"{b.label} {render.nm(b.lo_m * report.incidence_factor, 1)}-{render.nm(b.hi_m, 1)} nm"
                for b in report.bands
            )
        )
    if report.ignored_bands:
        con.print("Outside the sensor range (ignored): " + ", ".join(b.label for b in report.ignored_bands))
    rows = [
        [
            c.name,
            render.nm(c.lhs_m),
            c.relation,
            render.nm(c.rhs_m),
            format_length(c.depth_m),
            f"{c.margin_m * 1e9:+.2f}",
            "[green]yes[/]" if c.ok else "[red]NO[/]",
        ]
        for c in report.conditions
    ]
    title = f"Split-spectrum conditions: f = {format_length(report.f_m)}, z_near = {depth}, s = 1 + f/z = {s}"
    con.print(render.table(title, ["condition", "lhs (nm)", "", "rhs (nm)", "at z", "margin (nm)", "holds"], rows))
    con.print(f"z_near window at this f: {_window_text(report.z_near_window_m)}")
    con.print(f"f window at this z_near: {_window_text(report.f_window_m)}")
    failed = [c.name for c in report.conditions if not c.ok]
    if efficiency is not None:
        source = efficiency["source"]
        how = (
            f"RCWA, {efficiency['material']} on {efficiency['substrate']}, N = {efficiency['harmonics']}"
            if source == "rcwa"
            else "the preset's table"
            if source == "table"
            else efficiency["file"]
        )
        means = ", ".join(f"{b.label} {v:.3f}" for b, v in zip(report.bands, efficiency["band_mean"]))
        con.print(f"Nanofin conversion efficiency η, mean per pass band ({how}): {means}", markup=False)
    con.print("[green]All conditions hold.[/]" if not failed else f"[red]Failing:[/] {', '.join(failed)}")


@bands.command()
@preset_option
@click.option(
    "--band",
    "band_specs",
    type=BandSpec(),
    multiple=True,
    help="Pass band CENTER:WIDTH (width = FWHM), e.g. 457nm:22nm; repeatable.",
)
@click.option(
    "--filter-csv",
    type=click.Path(dir_okay=False),
    help="Filter transmission CSV: wavelength_nm,transmission (0-1 or %).",
)
@click.option(
    "--threshold",
    type=Number(0, 1, min_open=True, max_open=True),
    default=0.5,
    show_default=True,
    help="Transmission above which a CSV filter passes.",
)
@click.option("--f", "f_m", type=Length(), help="Focal length, e.g. 4mm.")
@click.option(
    "--z-near",
    "z_near",
    type=Interval(),
    help="Near (obstruction) depth, or a range that must hold throughout: 45mm or 40mm:50mm.",
)
@click.option(
    "--sensor-range", type=WavelengthInterval(), help="Sensor's wavelength range [default: preset's, else 400nm:700nm]."
)
@click.option(
    "--max-incidence",
    type=Angle(),
    help="Steepest ray on the filter, e.g. 25deg; the bands move blue for it "
    "[default: the preset's filter.max_incidence, else 0deg].",
)
@click.option(
    "--n-eff", type=Number(1, 5), help="The filter coating's effective index [default: the preset's, else 1.8]."
)
@json_option
@plot_option
@click.pass_context
def check(
    ctx,
    preset_path,
    band_specs,
    filter_csv,
    threshold,
    f_m,
    z_near,
    sensor_range,
    max_incidence,
    n_eff,
    as_json,
    plot_path,
):
    """Check the split-spectrum conditions (Suppl. Note 1). Exit 0: all hold; 1: one fails; 2: bad input."""
    preset = load_preset_option(preset_path)
    filter_bands = _filter_bands(preset, band_specs, filter_csv, threshold)
    f_m = pick(f_m, preset, lambda p: p.lens.focal_length_m, "--f", LENGTH_FORM)
    z_near = pick(z_near, preset, lambda p: p.scene.z_near_m, "--z-near", INTERVAL_FORM)
    sensor_range = sensor_range or (preset.sensor.wavelength_range_m if preset else SENSOR_RANGE_M)
    report = model.check_bands(
        filter_bands, f_m, z_near, sensor_range_m=sensor_range, incidence=_incidence(preset, max_incidence, n_eff)
    )
    efficiency = None
    if preset is not None:
        from metalens_cli.cli.progress import efficiency_used

        efficiency = efficiency_used(preset, bands_m=[(b.lo_m, b.hi_m) for b in report.bands])
    if plot_path:
        from metalens_cli.plotting.bands import plot_bands

        plot_bands(plot_path, report)
    if as_json:
        out = report_json(report)
        if efficiency is not None:
            out["efficiency"] = efficiency
        if plot_path:
            out["plot"] = str(plot_path)
        render.emit_json(out)
    else:
        _render(report, efficiency)
    ctx.exit(0 if report.ok else 1)
