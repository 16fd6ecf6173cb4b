"""`metalens mtf`: MTFs of a PSF cube (EXR, .npz, .mat or TIFF), or the slanted-edge SFR of an image."""

from __future__ import annotations

import csv
import math

import click

from metalens_cli.cli import render
from metalens_cli.cli.options import Length, MetalensCommand, Number, OutputFile, json_option, plot_option
from metalens_cli.io.atomic import atomic_write

NYQUIST_CY_PER_PX = 0.5
CUBE_ONLY = {"at_lpmm": "--at", "na": "--na", "remove_pixel_mtf": "--remove-pixel-mtf"}
EDGE_ONLY = {"roi": "--roi", "pixel_pitch_m": "--pixel-pitch", "srgb": "--srgb"}


def _frequencies(ctx, param, text: str | None) -> list[float] | None:
    """``--at 50,100`` → [50.0, 100.0] (lp/mm, finite, ≥ 0)."""
    if text is None:
        return None
    try:
        values = [float(part) for part in text.split(",")]
    except ValueError:
        raise click.BadParameter(f"{text!r} is not a list of numbers (expected lp/mm, e.g. 50,100)") from None
    if not all(0 <= value < math.inf for value in values):
        raise click.BadParameter(f"{text!r} (expected finite frequencies ≥ 0 in lp/mm)")
    return values


def _roi(ctx, param, text: str | None) -> tuple[int, int, int, int] | None:
    """``--roi x,y,w,h`` → 4 non-negative integers (pixels; x = column, y = row)."""
    if text is None:
        return None
    parts = [part.strip() for part in text.split(",")]
    if len(parts) != 4 or not all(part.isdigit() for part in parts):
        raise click.BadParameter(f"{text!r} is not x,y,w,h (expected 4 non-negative integers, e.g. 100,80,64,128)")
    return tuple(int(part) for part in parts)


@click.command("mtf", cls=MetalensCommand)
@click.argument("cube", required=False, type=click.Path(dir_okay=False))
@click.option(
    "--edge",
    "edge_path",
    type=click.Path(dir_okay=False),
    help="Slanted-edge image (PNG/TIFF 8/16-bit, EXR float; 1 or 3 channels) instead of a cube.",
)
@click.option(
    "--at",
    "at_lpmm",
    callback=_frequencies,
    help="Cube: also report the MTF at these frequencies (lp/mm), e.g. 50,100.",
)
@click.option(
    "--na",
    type=Number(0, 1, min_open=True, max_open=True),
    help="Cube: NA for the diffraction-limited reference [the file's na].",
)
@click.option(
    "--remove-pixel-mtf",
    is_flag=True,
    help="Cube: divide the square-pixel aperture MTF out of every curve (included by default).",
)
@click.option("--roi", callback=_roi, help="Edge: region x,y,w,h in pixels [automatic: around the one dominant edge].")
@click.option(
    "--pixel-pitch",
    "pixel_pitch_m",
    type=Length(),
    help="Edge: pixel pitch, to add lp/mm to cycles/pixel, e.g. 1.85um.",
)
@click.option(
    "--srgb", is_flag=True, help="Edge: decode 8/16-bit sRGB values to linear first (default: taken as linear)."
)
@click.option(
    "--csv", "csv_path", type=OutputFile(), help="Also write the curves as CSV (one row per curve and frequency)."
)
@json_option
@plot_option
def mtf(cube, edge_path, at_lpmm, na, remove_pixel_mtf, roi, pixel_pitch_m, srgb, csv_path, as_json, plot_path):
    """MTFs of a PSF cube, or the slanted-edge SFR of an image (--edge).

    CUBE (.exr, .npz, .mat or .tif/.tiff, as psf-scan writes them; docs/formats.md): for every
    (depth, wavelength) PSF and every R, G, B channel PSF, the OTF modulus, normalised at zero
    frequency and radially averaged from 0 to the sampling Nyquist 1/(2·pitch), in lp/mm; MTF50;
    the diffraction limit of the NA. The pixel aperture is part of the curves unless
    --remove-pixel-mtf.

    A field cube (off-axis fields): the radial MTFs of field 0, and per field the tangential and
    sagittal MTFs and their MTF50 (JSON "fields"; CSV rows with field, field_angle_deg and
    direction); --plot draws MTF50 against field angle.

    --edge IMAGE: ISO 12233-style slanted-edge SFR per channel (4× oversampled ESF, Tukey
    window), 0 to 1 cycle/pixel, for edges tilted 2°-10° from the pixel grid.
    """
    options = {
        "at_lpmm": at_lpmm,
        "na": na,
        "remove_pixel_mtf": remove_pixel_mtf,
        "roi": roi,
        "pixel_pitch_m": pixel_pitch_m,
        "srgb": srgb,
    }
    if (cube is None) == (edge_path is None):
        raise click.UsageError("give either a PSF cube (metalens mtf CUBE.exr) or --edge IMAGE")
    wrong = EDGE_ONLY if cube is not None else CUBE_ONLY
    used = [flag for key, flag in wrong.items() if options[key]]
    if used:
        raise click.UsageError(
            f"{', '.join(used)} only applies {'with --edge' if cube is not None else 'to a PSF cube'}"
        )
    if cube is not None:
        _cube(cube, at_lpmm or [], na, remove_pixel_mtf, csv_path, as_json, plot_path)
    else:
        _edge(edge_path, roi, pixel_pitch_m, srgb, csv_path, as_json, plot_path)


def _cube(path, at_lpmm, na, remove_pixel_mtf, csv_path, as_json, plot_path) -> None:
    from metalens_cli.analysis.mtf import cube_mtf
    from metalens_cli.io.psf_cube_files import read_psf_cube

    result = cube_mtf(read_psf_cube(path), at_lpmm=at_lpmm, na=na, remove_pixel_mtf=remove_pixel_mtf)
    curves = result.curves()
    fields = result.field_records()
    if csv_path:
        _write_csv(csv_path, *_cube_csv(result, curves))
    if plot_path:
        from metalens_cli.plotting.mtf import plot_cube_mtf, plot_field_mtf50

        (plot_cube_mtf if result.field is None else plot_field_mtf50)(plot_path, result)
    if as_json:
        diffraction = (
            None
            if result.diffraction is None
            else [
                {"wavelength_m": float(w), "mtf": d.tolist()} for w, d in zip(result.wavelengths_m, result.diffraction)
            ]
        )
        render.emit_json(
            {
                "file": str(path),
                "pixel_mtf": "removed" if remove_pixel_mtf else "included",
                "nyquist_lpmm": result.nyquist_lpmm,
                "na": result.na,
                **({"at_lpmm": list(at_lpmm)} if at_lpmm else {}),
                "frequencies_lpmm": result.frequencies_lpmm.tolist(),
                "curves": curves,
                **(
                    {"field_azimuth_rad": result.field.azimuth_rad, "fields": fields}
                    if result.field is not None
                    else {}
                ),
                "pixel_aperture_mtf": result.pixel_mtf.tolist(),
                "diffraction_limited": diffraction,
                **({"csv": str(csv_path)} if csv_path else {}),
                **({"plot": str(plot_path)} if plot_path else {}),
            }
        )
        return
    _render_cube(result, curves, at_lpmm, path)
    if fields:
        _render_fields(result, fields, path)
    _report_files(csv_path, plot_path)


def _cube_csv(result, curves) -> tuple[list[str], list[list]]:
    """Header and rows of the cube's CSV: one row per curve and frequency. A field cube's rows
    add the columns field, field_angle_deg and direction: its radial curves (field 0's,
    direction "radial") first, then every field's tangential and sagittal curves."""
    frequencies = result.frequencies_lpmm.tolist()
    header = ["depth_m", "wavelength_m", "channel", "frequency_lpmm", "mtf"]
    rows = [
        [c["depth_m"], c.get("wavelength_m", ""), c.get("channel", ""), f, m]
        for c in curves
        for f, m in zip(frequencies, c["mtf"])
    ]
    if result.field is None:
        return header, rows
    first = [0, math.degrees(float(result.field.angles_rad[0])), "radial"]
    rows = [row + first for row in rows]
    rows += [
        [c["depth_m"], c.get("wavelength_m", ""), c.get("channel", ""), f, float(m)]
        + [c["field"], c["angle_deg"], c["direction"]]
        for c in result.field_curves()
        for f, m in zip(frequencies, c["mtf"])
    ]
    return header + ["field", "field_angle_deg", "direction"], rows


def _render_fields(result, fields, path) -> None:
    """The MTF50s of a field cube, per field, tangential and sagittal."""
    from metalens_cli.io.units import format_length

    def lpmm(value):
        return "—" if value is None else f"{value:.1f}"

    rows = [
        [
            str(f["field"]),
            f"{f['angle_deg']:.3g}",
            format_length(r["depth_m"]),
            render.nm(r["wavelength_m"], 1) if "wavelength_m" in r else r["channel"],
            lpmm(r["tangential"]),
            lpmm(r["sagittal"]),
        ]
        for f in fields
        for r in f["mtf50_lpmm"]
    ]
    columns = ["field", "angle (°)", "depth", "λ (nm) / channel", "MTF50 T (lp/mm)", "MTF50 S (lp/mm)"]
    con = render.console()
    con.print(render.table(f"MTF50 over the field of {path}", columns, rows))
    con.print(
        f"{len(fields)} fields at azimuth {math.degrees(result.field.azimuth_rad):.3g}°: T tangential (radial on the "
        "sensor), S sagittal; the radial MTFs above are field 0's"
    )


def _render_cube(result, curves, at_lpmm, path) -> None:
    from metalens_cli.io.units import format_length

    rows = []
    for c in curves:
        label = render.nm(c["wavelength_m"], 1) if "wavelength_m" in c else c["channel"]
        mtf50 = "—" if c["mtf50_lpmm"] is None else f"{c['mtf50_lpmm']:.1f}"
        rows.append(
            [format_length(c["depth_m"]), label, mtf50, *(f"{v:.3f}" for v in [*c.get("mtf_at", []), c["mtf"][-1]])]
        )
    last = result.frequencies_lpmm[-1]
    columns = [
        "depth",
        "λ (nm) / channel",
        "MTF50 (lp/mm)",
        *[f"MTF @ {f:g}" for f in at_lpmm],
        f"MTF @ {last:.1f} (Nyquist)",
    ]
    con = render.console()
    con.print(render.table(f"MTF of {path}", columns, rows))
    pixel = "divided out" if result.pixel_mtf_removed else "included (--remove-pixel-mtf divides it out)"
    con.print(
        f"{result.frequencies_lpmm.size} frequencies, 0-{result.frequencies_lpmm[-1]:.1f} lp/mm (Nyquist "
        f"{result.nyquist_lpmm:.1f} lp/mm); pixel aperture {pixel}"
    )
    if result.na is None:
        con.print("no diffraction-limited reference: the file has no na (give --na)")
    else:
        cutoffs = 2 * result.na / result.wavelengths_m * 1e-3
        con.print(
            f"diffraction limit at NA {result.na:.3g}: cutoff 2·NA/λ = {cutoffs.min():.0f}-{cutoffs.max():.0f} lp/mm"
        )


def _edge(path, roi, pixel_pitch_m, srgb, csv_path, as_json, plot_path) -> None:
    from metalens_cli.analysis.slanted_edge import read_edge_image, slanted_edge_sfr

    image, names = read_edge_image(path, srgb)
    analysis = slanted_edge_sfr(image, names, roi=roi)
    entries = [_edge_entry(sfr, pixel_pitch_m) for sfr in analysis.channels]
    if csv_path:
        lpmm = ["frequency_lpmm"] if pixel_pitch_m else []
        rows = [
            [
                e["channel"],
                e["angle_deg"],
                *[e[key][k] for key in ("frequencies_cy_per_px", *(["frequencies_lpmm"] if lpmm else []), "mtf")],
            ]
            for e in entries
            for k in range(len(e["mtf"]))
        ]
        _write_csv(csv_path, ["channel", "angle_deg", "frequency_cy_per_px", *lpmm, "mtf"], rows)
    if plot_path:
        from metalens_cli.plotting.mtf import plot_edge_sfr

        plot_edge_sfr(plot_path, analysis, pixel_pitch_m)
    if as_json:
        render.emit_json(
            {
                "file": str(path),
                "roi": list(analysis.roi),
                "orientation": analysis.orientation,
                "values": "sRGB decoded to linear" if srgb else "linear as stored",
                **({"pixel_pitch_m": pixel_pitch_m} if pixel_pitch_m else {}),
                "edge": entries,
                **({"csv": str(csv_path)} if csv_path else {}),
                **({"plot": str(plot_path)} if plot_path else {}),
            }
        )
        return
    _render_edge(analysis, entries, pixel_pitch_m, path)
    _report_files(csv_path, plot_path)


def _edge_entry(sfr, pixel_pitch_m: float | None) -> dict:
    """The JSON record of one channel's SFR (lp/mm keys added with a pixel pitch)."""
    mtf50 = None if math.isnan(sfr.mtf50_cy_per_px) else sfr.mtf50_cy_per_px
    entry = {
        "channel": sfr.channel,
        "angle_deg": sfr.angle_deg,
        "frequencies_cy_per_px": sfr.frequencies_cy_per_px.tolist(),
        "mtf": sfr.mtf.tolist(),
        "mtf50_cy_per_px": mtf50,
    }
    if pixel_pitch_m:
        entry["frequencies_lpmm"] = sfr.frequencies_lpmm(pixel_pitch_m).tolist()
        entry["mtf50_lpmm"] = None if mtf50 is None else mtf50 / pixel_pitch_m * 1e-3
    return entry


def _render_edge(analysis, entries, pixel_pitch_m, path) -> None:
    from metalens_cli.analysis.mtf import mtf_at

    rows = []
    for sfr, e in zip(analysis.channels, entries):
        at_nyquist = float(mtf_at(sfr.frequencies_cy_per_px, sfr.mtf, [NYQUIST_CY_PER_PX])[0])
        mtf50 = "—" if e["mtf50_cy_per_px"] is None else f"{e['mtf50_cy_per_px']:.4f}"
        lpmm = [] if not pixel_pitch_m else ["—" if e["mtf50_lpmm"] is None else f"{e['mtf50_lpmm']:.1f}"]
        rows.append([sfr.channel, f"{sfr.angle_deg:.2f}", mtf50, *lpmm, f"{at_nyquist:.3f}"])
    columns = ["channel", "tilt (°)", "MTF50 (cy/px)", *(["MTF50 (lp/mm)"] if pixel_pitch_m else []), "SFR @ Nyquist"]
    con = render.console()
    x, y, w, h = analysis.roi
    con.print(
        render.table(f"Slanted-edge SFR of {path} ({analysis.orientation} edge, ROI {x},{y},{w},{h})", columns, rows)
    )


def _write_csv(path, header: list[str], rows: list[list]) -> None:
    """A CSV file written atomically; infinite depths as ``inf``."""
    with atomic_write(path) as temporary, open(temporary, "w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        writer.writerows(rows)


def _report_files(csv_path, plot_path) -> None:
    err = render.console(stderr=True)
    for written in (csv_path, plot_path):
        if written:
            err.print(f"wrote {written}")
