"""`metalens psf-scan`: PSF cubes over wavelength and depth, written as EXR, .npz, .mat or TIFF."""

from __future__ import annotations

import math

import click

from metalens_cli.cli import render
from metalens_cli.cli.options import (
    AngleList,
    Azimuth,
    HeightList,
    Length,
    LengthList,
    MetalensCommand,
    OutputFile,
    WavelengthList,
    announce,
    design_options,
    device_option,
    flatten,
    json_option,
    load_preset_option,
    max_memory_option,
    plot_option,
    quiet_option,
    torch_device,
)
from metalens_cli.cli.progress import efficiency_used, progress_bar
from metalens_cli.io.psf_cube_files import CUBE_SUFFIXES

PROPAGATORS = ("auto", "asm", "radial", "rs")
DEFAULT_PIXELS, DEFAULT_PIXEL_PITCH_M = 512, 1.85e-6  # the paper's sensor


@click.command("psf-scan", cls=MetalensCommand)
@design_options
@click.option(
    "--wavelengths",
    type=WavelengthList(),
    multiple=True,
    help="Wavelengths, e.g. 430:645:5nm (default) or 457nm,530nm.",
)
@click.option(
    "--depths", type=LengthList(allow_inf=True), multiple=True, help="Source depths, e.g. 45mm,inf (default)."
)
@click.option(
    "--field-angles",
    "field_angles",
    type=AngleList(),
    help="Off-axis fields as angles from 0 to 60deg, e.g. 0deg,3deg,6.75deg or 0:6:1.5deg: a field cube (.exr), "
    "each window centred on its chief ray.",
)
@click.option(
    "--field-heights",
    "field_heights",
    type=HeightList(),
    help="Off-axis fields as chief-ray heights on the sensor, e.g. 0um,250um (angle atan(h/f), up to 60deg).",
)
@click.option(
    "--field-azimuth",
    "field_azimuth",
    type=Azimuth(),
    help="Azimuth of the fields, counter-clockwise from the sensor's +x axis [0deg]; needs --field-angles or "
    "--field-heights.",
)
@click.option("--pixels", type=click.IntRange(1, 8192), help="Sensor window N × N [preset's, else 512].")
@click.option("--pixel-pitch", "pixel_pitch_m", type=Length(), help="Sensor pixel pitch [preset's, else 1.85um].")
@click.option(
    "--propagator",
    type=click.Choice(PROPAGATORS),
    default="auto",
    show_default=True,
    help="auto: radial for radially symmetric designs, else asm.",
)
@click.option("--dtype", type=click.Choice(("float32", "float64")), default="float32", show_default=True)
@device_option
@click.option("--force", is_flag=True, help="Compute even when the sampling guard refuses the grid.")
@click.option(
    "--check-accuracy",
    is_flag=True,
    help="Recompute the sharpest PSF with doubled sampling and with the rs reference; report relative L2.",
)
@click.option(
    "-o",
    "--output",
    type=OutputFile(CUBE_SUFFIXES),
    required=True,
    help="Output cube, format by suffix: .exr, .npz (numpy), .mat (MATLAB v5) or .tif/.tiff (float32 stack, one page "
    "per PSF); see docs/formats.md.",
)
@quiet_option()
@max_memory_option
@json_option
@plot_option
def psf_scan(
    spec,
    preset_path,
    f_m,
    aperture_m,
    pitch_m,
    wavelengths,
    depths,
    field_angles,
    field_heights,
    field_azimuth,
    pixels,
    pixel_pitch_m,
    propagator,
    dtype,
    device,
    force,
    check_accuracy,
    output,
    quiet,
    max_memory,
    as_json,
    plot_path,
):
    """PSF cube over wavelength × depth of a design, with cost and accuracy, written as EXR,
    .npz, .mat or TIFF (by the suffix of -o).

    Each PSF is the fraction of the power through the aperture landing on each pixel of an
    N × N window centred on the axis (pixel N//2, N//2). With a preset (given or carried by the
    design), R, G, B channel PSFs are mixed with the spectral sensitivity S^c. With
    --field-angles or --field-heights, a field cube: each field's window centred on the pixel
    where its chief ray lands (off-axis fields by the 2-D shifted angular spectrum).
    """
    import torch

    from metalens_cli.errors import InputError
    from metalens_cli.imaging.psf_scan import (
        check_scan_size,
        estimate_scan,
        run_scan,
        scan_metadata,
        scan_report,
        write_scan,
    )
    from metalens_cli.io.designs import resolve_design
    from metalens_cli.io.units import parse_length_list
    from metalens_cli.optics.sampling import PsfGrid

    preset = load_preset_option(preset_path)
    design = resolve_design(spec, preset, f_m=f_m, aperture_m=aperture_m, pitch_m=pitch_m)
    sensor = design.preset.sensor if design.preset is not None else None
    pixels = pixels or (sensor.pixels if sensor else DEFAULT_PIXELS)
    pixel_pitch_m = pixel_pitch_m or (sensor.pixel_pitch_m if sensor else DEFAULT_PIXEL_PITCH_M)
    wavelengths_m = flatten(wavelengths) or parse_length_list("430:645:5nm", "--wavelengths")
    depths_m = flatten(depths) or [0.045, math.inf]
    angles = _field_angles(field_angles, field_heights, design.focal_length_m, propagator)
    if field_azimuth is not None and angles is None:
        raise InputError("--field-azimuth", "given without fields", "--field-angles or --field-heights beside it")
    field_azimuth = field_azimuth or 0.0
    check_scan_size(output, wavelengths_m, depths_m, pixels, field_cube=angles is not None)
    run_device = torch_device(device)  # resolved before the estimate: a CUDA job is checked against the GPU's memory
    grid = PsfGrid(wavelengths_m, depths_m, pixels, pixel_pitch_m, design.focal_length_m)
    psf_options = dict(
        field_angles_rad=angles,
        azimuth_rad=field_azimuth,
        propagator=propagator,
        dtype=getattr(torch, dtype),
        force=force,
    )
    estimate = estimate_scan(design, grid, **psf_options)
    announce(estimate, max_memory, output, run_device)
    efficiency = efficiency_used(design.preset, quiet)
    with progress_bar("psf-scan", quiet) as update:
        options = dict(**psf_options, device=run_device, check_accuracy=check_accuracy, progress=update)
        scan = run_scan(design, grid, **options)
    metadata = scan_metadata(design, scan, dtype, efficiency)
    write_scan(output, design, scan, metadata)
    if plot_path:
        from metalens_cli.plotting.psf_scan import plot_scan

        plot_scan(plot_path, scan, design.preset)
    render.say(scan.warnings)
    if as_json:
        render.emit_json(scan_report(design, scan, metadata, output, plot_path))
        return
    _render(scan, design, output)


def _field_angles(angles, heights, focal_length_m, propagator) -> list[float] | None:
    """The field angles (rad) from --field-angles or --field-heights (atan(h/f)), or None."""
    from metalens_cli.analysis.psf_compare import FIELD_ANGLE_TOLERANCE_RAD
    from metalens_cli.errors import InputError
    from metalens_cli.io.units import format_length
    from metalens_cli.optics.field import MAX_FIELD_ANGLE, field_angle

    if angles and heights:
        raise InputError("--field-heights", "given with --field-angles", "one of --field-angles or --field-heights")
    if heights:
        if focal_length_m is None:
            raise InputError("--field-heights", "the design has no focal length", "--field-angles, or a design with f")
        angles = [field_angle(h, focal_length_m) for h in heights]
    if not angles:
        return None
    top, steepest = math.degrees(MAX_FIELD_ANGLE), max(angles)
    if steepest > MAX_FIELD_ANGLE:
        if heights:
            highest = focal_length_m * math.tan(MAX_FIELD_ANGLE)
            raise InputError(
                "--field-heights",
                f"{format_length(max(heights))} is a field angle of {math.degrees(steepest):.4g}° at f = "
                f"{format_length(focal_length_m)}, past the {top:g}° the off-axis model covers",
                f"heights up to {format_length(highest)} (atan(h/f) ≤ {top:g}°)",
            )
        raise InputError(
            "--field-angles",
            f"{math.degrees(steepest):.4g}° is past the {top:g}° the off-axis model covers",
            f"angles from 0 to {top:g}°",
        )
    ordered = sorted(angles)
    if any(b - a <= FIELD_ANGLE_TOLERANCE_RAD for a, b in zip(ordered, ordered[1:])):
        option, what = ("--field-heights", "height") if heights else ("--field-angles", "angle")
        raise InputError(
            option,
            f"the fields repeat a{'n' if what == 'angle' else ''} {what}",
            f"distinct fields (angles more than {FIELD_ANGLE_TOLERANCE_RAD:g} rad apart, as psf compare matches them)",
        )
    if propagator not in ("auto", "asm"):
        raise InputError(
            "--propagator", f"{propagator} with off-axis fields", "auto or asm (off axis: the shifted angular spectrum)"
        )
    return angles


def _render_fields(scan, con) -> None:
    from metalens_cli.io.units import format_length

    rows = []
    for f in scan.fields.metrics:
        entries = f.get("channel_psfs") or f["psfs"]
        for m in entries:
            um = [None if m[k] is None else m[k] * 1e6 for k in ("fwhm_tangential_m", "fwhm_sagittal_m")]
            rows.append(
                [
                    f"{f['angle_deg']:.3g}",
                    f"{f['chief_ray_m'][0] * 1e6:.1f}, {f['chief_ray_m'][1] * 1e6:.1f}",
                    format_length(m["depth_m"]),
                    m.get("channel") or render.nm(m["wavelength_m"], 1),
                    f"{m['centroid_from_chief_ray_m'][0] * 1e6:+.2f}, {m['centroid_from_chief_ray_m'][1] * 1e6:+.2f}",
                    *("—" if v is None else f"{v:.2f}" for v in um),
                    f"{m['ee80_radius_m'] * 1e6:.1f}",
                    f"{m['energy_in_window']:.4f}",
                ]
            )
    con.print(
        render.table(
            "Over the field (µm; centroid from the chief ray, FWHM through the brightest pixel)",
            ["field (°)", "chief ray", "depth", "λ/channel", "centroid", "FWHM T", "FWHM S", "EE80 r", "in window"],
            rows,
        )
    )


def _render(scan, design, output) -> None:
    from metalens_cli.io.units import format_length

    con = render.console()
    columns = ["peak", "in window", "centre 5×5", "FWHM (µm)"]

    def cells(m: dict) -> list[str]:
        return [
            f"{m['peak']:.4f}",
            f"{m['energy_in_window']:.4f}",
            f"{m['energy_center_5x5']:.4f}",
            "—" if m["fwhm_m"] is None else f"{m['fwhm_m'] * 1e6:.2f}",
        ]

    con.print(
        render.table(
            f"PSF scan of {design.spec} ({scan.propagator})",
            ["depth", "λ (nm)", *columns],
            [[format_length(m["depth_m"]), render.nm(m["wavelength_m"], 1), *cells(m)] for m in scan.metrics],
        )
    )
    if scan.fields is not None:
        _render_fields(scan, con)
    elif scan.channel_metrics:
        con.print(
            render.table(
                "Channel PSFs: the wavelengths weighted by filter × camera response",
                ["depth", "channel", *columns],
                [[format_length(m["depth_m"]), m["channel"], *cells(m)] for m in scan.channel_metrics],
            )
        )
    t = scan.timing_s
    con.print(
        f"{len(scan.metrics)} PSFs in {t['total']:.2f} s ("
        + ", ".join(f"{k} {v:.2f} s" for k, v in t.items() if k != "total")
        + ")"
    )
    if scan.accuracy:
        a = scan.accuracy
        text = (
            f"accuracy at {render.nm(a['wavelength_m'], 1)} nm, {format_length(a['depth_m'])}: doubled sampling "
            f"rel. L2 {a['doubled_sampling_rel_l2']:.2e}"
        )
        if "rs_rel_l2" in a:
            text += f", Rayleigh-Sommerfeld rel. L2 {a['rs_rel_l2']:.2e} (central {a['rs_window_pixels']}² pixels)"
        con.print(text)
    con.print(f"wrote {output}")
