"""`metalens psf`: measured PSFs. `psf import` turns bench frames into a PSF cube; `psf compare`
sets a measured cube beside a simulated one; `psf retrieve` fits the fabricated lens's radial phase
to a measured cube."""

from __future__ import annotations

import math
import time

import click

from metalens_cli.cli import render
from metalens_cli.cli.options import (
    DESIGN_HELP,
    Length,
    LengthList,
    MetalensGroup,
    Number,
    OutputFile,
    announce,
    device_option,
    geometry_options,
    json_option,
    load_preset_option,
    max_memory_option,
    plot_option,
    quiet_option,
    refuse_overwriting,
    torch_device,
)
from metalens_cli.cli.progress import progress_bar

NORMALIZATIONS = ("sum-to-one", "peak-one")  # analysis.measured_psf.NORMALIZATIONS (numpy-free import)
CENTRINGS = ("centroid", "peak")


@click.group("psf", cls=MetalensGroup, context_settings={"help_option_names": ["-h", "--help"]})
def psf():
    """Measured PSFs: import bench frames into a PSF cube, compare it with a simulation, retrieve the
    lens's phase from it."""


def _hot_sigma(ctx, param, value: float) -> float:
    """0 (off) or at least 3: below, noise itself would be replaced."""
    if 0 < value < 3:
        raise click.BadParameter(
            f"{value:g} would take noise for hot pixels (expected 0 to turn removal off, or at least 3)"
        )
    return value


@psf.command("import")
@click.argument("manifest", type=click.Path())
@click.option(
    "--pattern",
    help="MANIFEST is a folder: file names such as psf_{wavelength}_{depth}.png ({exposure} optional; "
    "{wavelength:nm} gives bare numbers a unit).",
)
@click.option("-o", "--output", type=OutputFile((".exr",)), required=True, help="PSF cube to write (docs/formats.md).")
@click.option(
    "--dark",
    "dark_path",
    type=click.Path(dir_okay=False),
    help="Dark frame (image, .npy, or a .npy stack averaged) subtracted from every frame [manifest's dark].",
)
@click.option(
    "--pixels", type=click.IntRange(3, 8192), help="Window N × N [automatic: as large as the light of every frame]."
)
@click.option(
    "--pixel-pitch", "pixel_pitch_m", type=Length(), help="Camera pixel pitch, e.g. 3.45um [manifest's pixel_pitch]."
)
@click.option(
    "--magnification",
    type=Number(0, 1e4, min_open=True),
    help=(
        "Magnification of the relay optics onto the camera; the cube's pitch is pitch / magnification "
        "[manifest's, else 1]."
    ),
)
@click.option(
    "--normalize", "normalization", type=click.Choice(NORMALIZATIONS), default="sum-to-one", show_default=True
)
@click.option(
    "--centre",
    "centring",
    type=click.Choice(CENTRINGS),
    default="centroid",
    show_default=True,
    help="Put the light's centroid or its peak on pixel (N//2, N//2).",
)
@click.option(
    "--saturation",
    type=Number(0, 1e30, min_open=True),
    help="Saturation level in the frames' units, e.g. 4095 for 12-bit data in 16-bit files [the file's full scale].",
)
@click.option(
    "--allow-saturated", is_flag=True, help="Import frames with saturated pixels (reported) instead of refusing them."
)
@click.option(
    "--hot-pixel-sigma",
    type=Number(0, 1e3),
    default=6.0,
    show_default=True,
    callback=_hot_sigma,
    help="Hot pixels stand this many σ (at least 3) above their neighbours; 0 turns removal off.",
)
@click.option(
    "--design", help="What was measured, stored as the cube's design [manifest's design, else 'measured: MANIFEST']."
)
@quiet_option()
@max_memory_option
@json_option
@plot_option
def import_frames(
    manifest,
    pattern,
    output,
    dark_path,
    pixels,
    pixel_pitch_m,
    magnification,
    normalization,
    centring,
    saturation,
    allow_saturated,
    hot_pixel_sigma,
    design,
    quiet,
    max_memory,
    as_json,
    plot_path,
):
    """Measured PSF frames listed in MANIFEST → a PSF cube (EXR).

    MANIFEST: a CSV with a header and columns file,wavelength,depth[,exposure] (values with
    units: 530nm, 45mm, inf, 10ms; paths relative to the manifest; stack.npy#K for frame K of a
    .npy stack), a TOML with [[frame]] tables (and optional pixel_pitch, magnification, dark,
    saturation, design), or a folder with --pattern. Frames: 8/16-bit PNG or TIFF, EXR, .npy.

    Per frame: saturated pixels refused (or reported with --allow-saturated); dark frame and
    border background subtracted; hot pixels replaced; the centroid (or peak) moved onto pixel
    (N//2, N//2) by a Fourier shift; cropped to N; repeats averaged; normalised.
    """
    from metalens_cli.analysis.measured_psf import import_psfs
    from metalens_cli.analysis.psf_import import (
        WORKERS,
        cube_metadata,
        estimate_import,
        import_report,
        import_settings,
        read_dark,
        write_measured_cube,
    )
    from metalens_cli.io.atomic import atomic_files
    from metalens_cli.io.psf_manifest import read_manifest

    m = read_manifest(manifest, pattern)
    refuse_overwriting(
        [("-o", output), ("--plot", plot_path)],
        [f.path for f in m.frames] + [p for p in (dark_path, m.settings.get("dark")) if p is not None],
    )
    settings = import_settings(
        m,
        manifest,
        pixel_pitch_m=pixel_pitch_m,
        magnification=magnification,
        pixels=pixels,
        normalization=normalization,
        centring=centring,
        saturation=saturation,
        allow_saturated=allow_saturated,
        hot_pixel_sigma=hot_pixel_sigma,
    )
    announce(estimate_import(m, pixels), max_memory, output)
    dark_source, dark = read_dark(m, manifest, dark_path, hot_pixel_sigma)
    start = time.perf_counter()
    with progress_bar("psf import", quiet) as update:
        cube = import_psfs(m, settings, dark, update, WORKERS)
    seconds = time.perf_counter() - start
    name = design or m.settings.get("design") or f"measured: {click.format_filename(manifest)}"
    metadata = cube_metadata(cube, settings, dark_source)
    with atomic_files(output, plot_path) as (cube_file, plot_file):  # both or neither
        write_measured_cube(cube_file, cube, name, normalization, metadata)
        if plot_file is not None:
            from metalens_cli.plotting.psf_scan import plot_psf_scan

            plot_psf_scan(plot_file, cube.psf, cube.wavelengths_m, cube.depths_m, cube.pixel_pitch_m)
    render.say(cube.warnings)
    if as_json:
        render.emit_json(import_report(output, cube, name, normalization, metadata, seconds, plot_path))
        return
    _render_import(cube, output, seconds)


def _render_import(cube, output, seconds: float) -> None:
    from metalens_cli.io.units import format_length

    rows = [
        [
            f["file"],
            render.nm(f["wavelength_m"], 1),
            format_length(math.inf if f["depth_m"] is None else f["depth_m"]),
            f"{f['peak_snr']:.0f}",
            f"{f['noise']:.3g}",
            str(f["saturated_pixels"]),
            f"{f['centre_px'][0]:.2f}, {f['centre_px'][1]:.2f}",
        ]
        for f in cube.frames
    ]
    con = render.console()
    con.print(
        render.table(
            f"Frames imported into {output}",
            ["file", "λ (nm)", "depth", "peak/σ", "noise σ", "saturated", "centre (row, col)"],
            rows,
        )
    )
    n = cube.psf.shape[-1]
    con.print(
        f"{len(cube.depths_m)} depths × {len(cube.wavelengths_m)} wavelengths of {n} × {n} pixels at "
        f"{cube.pixel_pitch_m * 1e6:.4g} µm; {cube.hot_pixels} hot pixel(s) replaced; {seconds:.2f} s"
    )


@psf.command("compare")
@click.argument("measured", type=click.Path(dir_okay=False))
@click.argument("simulated", type=click.Path(dir_okay=False))
@click.option(
    "--radii",
    "radii_m",
    type=LengthList(),
    multiple=True,
    help="Encircled-energy radii, e.g. 2um,5um [2, 5 and 10 measured pixels].",
)
@click.option(
    "--no-interpolate",
    is_flag=True,
    help="Refuse measured wavelengths the simulated cube lacks instead of interpolating.",
)
@click.option("--csv", "csv_path", type=OutputFile((".csv",)), help="Also write the table as CSV.")
@json_option
@plot_option
def compare(measured, simulated, radii_m, no_interpolate, csv_path, as_json, plot_path):
    """A measured PSF cube against a simulated one, per common (depth, wavelength).

    Cubes: .exr, .npz, .mat or .tif/.tiff files (docs/formats.md).

    After sub-pixel registration: the peak ratio (Strehl-like, simulated = 1), FWHM, encircled
    energy at radii, relative L2 error and MTF50 of both. Simulated wavelengths that do not
    match exactly are interpolated linearly between their neighbours (said per row) or, outside
    the simulated range or with --no-interpolate, refused (listed). A simulated cube of another
    pixel pitch is resampled onto the measured pixels (warned about when over 2× coarser);
    pitches no PSF can have (a window under half a wavelength, a measured window inside 3
    simulated pixels) and a common window under 8 × 8 pixels are refused; encircled energy at a
    radius over half the common window is not reported (—, null), with a warning. --plot: the x-λ scans of both side by
    side per depth (the paper's Fig. 4c). --csv and --plot are published together or not at all.

    Field cubes (off-axis fields) are compared field by field, at matching field angles; the
    shift on the sensor takes each field's window centre into account. A field cube against an
    on-axis cube: its field 0, with a warning.
    """
    from metalens_cli.analysis.psf_compare import compare_cubes
    from metalens_cli.io.atomic import atomic_files
    from metalens_cli.io.psf_cube_files import read_psf_cube

    radii = [r for group in radii_m for r in group] or None
    result = compare_cubes(read_psf_cube(measured), read_psf_cube(simulated), radii, not no_interpolate)
    with atomic_files(csv_path, plot_path) as (csv_file, plot_file):  # both or neither
        if csv_file is not None:
            csv_file.write_text(_compare_csv(result), encoding="utf-8")
        if plot_file is not None:
            from metalens_cli.plotting.psf_compare import plot_psf_comparison

            plot_psf_comparison(plot_file, result)
    render.say(result.warnings)
    if as_json:
        render.emit_json(
            {
                "measured": str(measured),
                "simulated": str(simulated),
                "pixels": result.pixels,
                "pixel_pitch_m": result.pixel_pitch_m,
                "simulated_resampled": result.resampled,
                "radii_m": result.radii_m,
                **({"fields": result.fields} if result.fields else {}),
                "pairs": result.pairs,
                "refused": result.refused,
                "warnings": result.warnings,
                **({"csv": str(csv_path)} if csv_path else {}),
                **({"plot": str(plot_path)} if plot_path else {}),
            }
        )
        return
    _render_compare(result, measured, simulated)


def _compare_rows(result) -> tuple[list[str], list[list]]:
    """Header and rows (numbers) of the comparison table, shared by the CSV and the screen."""
    header = [
        "depth_m",
        "wavelength_m",
        "simulated",
        "peak_ratio",
        "relative_l2",
        "fwhm_measured_m",
        "fwhm_simulated_m",
        "mtf50_measured_lpmm",
        "mtf50_simulated_lpmm",
        *[f"ee_{which}_{r * 1e6:g}um" for r in result.radii_m for which in ("measured", "simulated")],
        "shift_y_px",
        "shift_x_px",
    ]
    fields = bool(result.fields)
    if fields:
        header += ["field", "field_angle_deg", "sensor_shift_y_px", "sensor_shift_x_px"]
    rows = []
    for p in result.pairs:
        ee = [
            p["encircled_energy"][which][k] for k in range(len(result.radii_m)) for which in ("measured", "simulated")
        ]
        rows.append(
            [
                p["depth_m"] if p["depth_m"] is not None else "inf",
                p["wavelength_m"],
                p["simulated"],
                p["peak_ratio"],
                p["relative_l2"],
                p["fwhm_m"]["measured"],
                p["fwhm_m"]["simulated"],
                p["mtf50_lpmm"]["measured"],
                p["mtf50_lpmm"]["simulated"],
                *ee,
                *p["shift_px"],
                *([p["field"], p["field_angle_deg"], *p["sensor_shift_px"]] if fields else []),
            ]
        )
    return header, rows


def _compare_csv(result) -> str:
    """The comparison table as CSV text (empty cells for figures that could not be measured)."""
    import csv
    import io

    header, rows = _compare_rows(result)
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(header)
    writer.writerows([["" if v is None else v for v in row] for row in rows])
    return buffer.getvalue()


def _render_compare(result, measured, simulated) -> None:
    from metalens_cli.io.units import format_length

    def um(value):
        return "—" if value is None else f"{value * 1e6:.2f}"

    def number(value, digits):
        return "—" if value is None else f"{value:.{digits}f}"

    rows = []
    for p in result.pairs:
        ee = [
            f"{number(m, 3)} / {number(s, 3)}"
            for m, s in zip(p["encircled_energy"]["measured"], p["encircled_energy"]["simulated"])
        ]
        rows.append(
            [
                *([f"{p['field_angle_deg']:.3g}"] if result.fields else []),
                format_length(math.inf if p["depth_m"] is None else p["depth_m"]),
                render.nm(p["wavelength_m"], 1),
                p["simulated"],
                f"{p['peak_ratio']:.3f}",
                f"{p['relative_l2']:.3f}",
                f"{um(p['fwhm_m']['measured'])} / {um(p['fwhm_m']['simulated'])}",
                f"{number(p['mtf50_lpmm']['measured'], 1)} / {number(p['mtf50_lpmm']['simulated'], 1)}",
                *ee,
            ]
        )
    con = render.console()
    con.print(
        render.table(
            f"{measured} (measured) against {simulated} (simulated), {result.pixels}² pixels of "
            f"{result.pixel_pitch_m * 1e6:.4g} µm",
            [
                *(["field (°)"] if result.fields else []),
                "depth",
                "λ (nm)",
                "simulated",
                "peak ratio",
                "rel. L2",
                "FWHM (µm) meas / sim",
                "MTF50 (lp/mm) meas / sim",
                *[f"EE {r * 1e6:.3g} µm meas / sim" for r in result.radii_m],
            ],
            rows,
        )
    )
    if result.resampled:
        con.print("the simulated cube was resampled onto the measured pixel pitch")
    for r in result.refused:
        depth = format_length(math.inf if r["depth_m"] is None else r["depth_m"])
        at_field = f", field {r['field_angle_deg']:.3g}°" if "field" in r else ""
        con.print(f"refused: {render.nm(r['wavelength_m'], 1)} nm at {depth}{at_field}: {r['reason']}")
    for f in result.fields:
        if f["simulated_field"] is not None and any(f["window_offset_px"]):
            dy, dx = f["window_offset_px"]
            con.print(
                f"field {f['angle_deg']:.3g}°: the simulated window's centre lies ({dy:.3g}, {dx:.3g}) measured pixels "
                "(y, x) from the measured one's; sensor_shift_px in --json and --csv takes it into account"
            )


NUISANCE_FORM = "a comma list of shift and background, or none"


def _nuisance(ctx, param, value: str) -> tuple[str, ...]:
    """The per-PSF parameters fitted besides the scale: 'shift,background' → ('shift', 'background')."""
    text = value.strip().lower()
    if text in ("", "none"):
        return ()
    names = tuple(dict.fromkeys(part.strip() for part in text.split(",")))
    unknown = [n for n in names if n not in ("shift", "background")]
    if unknown:
        raise click.BadParameter(f"unknown {', '.join(repr(n) for n in unknown)} (expected {NUISANCE_FORM})")
    return names


@psf.command("retrieve")
@click.argument("measured", type=click.Path(dir_okay=False))
@click.option(
    "-o",
    "--output",
    type=OutputFile((".npy",)),
    required=True,
    help="The retrieved radial θ (rad) at r = k·pitch: a design spec with the nominal's --f/--aperture/--pitch.",
)
@click.option("--design", "spec", help=DESIGN_HELP + " The nominal lens [the cube's header design].")
@geometry_options
@click.option(
    "--terms",
    type=click.IntRange(1, 10),
    default=4,
    show_default=True,
    help="Even Zernike radial terms of δ: defocus, primary, secondary spherical, ...",
)
@click.option(
    "--nuisance",
    default="shift,background",
    show_default=True,
    callback=_nuisance,
    help="Per-PSF parameters fitted besides the scale: shift (sub-pixel), background (constant), or none.",
)
@click.option(
    "--max-iterations",
    type=click.IntRange(1, 1000),
    default=50,
    show_default=True,
    help="Levenberg-Marquardt iterations per stage (two stages).",
)
@device_option
@quiet_option()
@max_memory_option
@json_option
def retrieve(
    measured,
    output,
    spec,
    preset_path,
    f_m,
    aperture_m,
    pitch_m,
    terms,
    nuisance,
    max_iterations,
    device,
    quiet,
    max_memory,
    as_json,
):
    """The effective radial phase of a fabricated lens from a measured PSF cube.

    MEASURED: a PSF cube (.exr, .npz, .mat, .tif; docs/formats.md) of two or more depths or
    wavelengths. The lens's phase is φ = φ_nominal + δ, δ(r) = Σ c_k·R_2k(ρ) over ρ = r/(D/2)
    (Zernike radial polynomials, R(1) = 1: defocus, primary spherical, ...; one δ at every
    wavelength, as a geometric phase is). Each measured PSF is modelled as the lens's simulated
    PSF on the cube's pixels (radial propagator) with its own scale and, with --nuisance, a
    sub-pixel shift and a constant background. Levenberg-Marquardt from δ = 0, the Jacobian by
    forward-mode automatic differentiation through the propagator; PSFs weighted by their norm,
    then each pixel by its noise, σ² = a + b·model (read and shot noise) fitted per PSF to the
    residual; 1-σ uncertainties from the Gauss-Newton covariance. The defocus term also absorbs
    an error in the lens-to-sensor distance.

    Refused: one depth and one wavelength (δ and −δ give the same PSF), non-finite values,
    frames imported with saturated pixels, pixels wider than the Airy core, a 2-D design, terms
    the cube cannot tell apart (named). -o gets θ = (φ_nominal + δ)/2 at the nominal's radii.
    """
    from metalens_cli.analysis.phase_retrieval import (
        check_retrievable,
        estimate_retrieval,
        model_grid,
        retrieve_phase,
    )
    from metalens_cli.io.atomic import atomic_write
    from metalens_cli.io.psf_cube_files import read_psf_cube

    refuse_overwriting([("-o", output)], [measured] + ([spec] if spec else []))
    cube = read_psf_cube(measured)
    if cube.is_field_cube and (cube.field_count > 1 or float(cube.field_angles_rad[0]) != 0.0):
        from metalens_cli.errors import InputError

        raise InputError("MEASURED", "a field cube (off-axis PSFs)", "an on-axis PSF cube")
    design = _retrieval_design(cube, spec, load_preset_option(preset_path), f_m, aperture_m, pitch_m)
    check_retrievable(
        cube.psf,
        cube.wavelengths_m,
        cube.depths_m,
        cube.pixel_pitch_m,
        design.lens,
        design.focal_length_m,
        cube.metadata,
    )
    run_device = torch_device(device)
    grid = model_grid(cube.wavelengths_m, cube.depths_m, cube.psf.shape[-1], cube.pixel_pitch_m, design.focal_length_m)
    announce(estimate_retrieval(design.lens, grid, terms, max_iterations), max_memory, output, run_device)
    with progress_bar("psf retrieve", quiet) as update:
        result = retrieve_phase(
            cube.psf,
            cube.wavelengths_m,
            cube.depths_m,
            cube.pixel_pitch_m,
            design.lens,
            distance_m=design.focal_length_m,
            terms=terms,
            nuisance=nuisance,
            max_iterations=max_iterations,
            device=run_device,
            progress=update,
            metadata=cube.metadata,
        )
    import numpy as np

    with atomic_write(output) as temporary, open(temporary, "wb") as handle:
        np.save(handle, result.theta)
    render.say(result.warnings)
    if as_json:
        render.emit_json(_retrieve_report(measured, output, design, result))
        return
    _render_retrieve(result, measured, output, design)


def _retrieval_design(cube, spec, preset, f_m, aperture_m, pitch_m):
    """The nominal design: --design, else the cube header's design (psf-scan writes its spec and
    geometry; options win over the header's f, aperture and pitch)."""
    from metalens_cli.errors import InputError
    from metalens_cli.io.designs import resolve_design

    if spec:
        return resolve_design(spec, preset, f_m=f_m, aperture_m=aperture_m, pitch_m=pitch_m)
    header = cube.metadata.get("design")
    record = header if isinstance(header, dict) else {}
    named = record.get("spec") if record else header
    if not isinstance(named, str) or not named.strip():
        raise InputError("--design", "not given, and the cube's header names no design", "--design SPEC")
    geometry = {
        "f_m": f_m or record.get("f_m") or cube.metadata.get("f_m"),
        "aperture_m": aperture_m or record.get("aperture_m") or cube.metadata.get("aperture_m"),
        "pitch_m": pitch_m or record.get("pitch_m"),
    }
    try:
        return resolve_design(named, preset, **geometry)
    except InputError as exc:
        raise InputError(
            "--design", f"not given, and the cube's design {named!r} does not resolve: {exc.message}", exc.expected
        ) from None


def _retrieve_report(measured, output, design, result) -> dict:
    """The --json object: inputs, design, terms with uncertainties, per-PSF fit, fit statistics."""
    return {
        "measured": str(measured),
        "output": str(output),
        "design": design.describe(),
        "model": "phi = phi_nominal + sum_k c_k R_2k^0(r / (D/2)); theta = phi / 2",
        "nuisance": ["scale", *result.nuisance],
        "terms": result.terms,
        "correlation": result.correlation.tolist(),
        "condition_number": result.condition_number,
        "chi2_reduced": result.chi2_reduced,
        "noise": "per pixel sigma^2 = a + b * model, a and b fitted per PSF to its residual",
        "iterations": result.iterations,
        "converged": result.converged,
        "seconds": result.seconds,
        "psfs": result.psfs,
        "warnings": result.warnings,
    }


def _render_retrieve(result, measured, output, design) -> None:
    from metalens_cli.io.units import format_length

    con = render.console()
    con.print(
        render.table(
            f"Phase of {design.spec} retrieved from {measured}: δ(r) = Σ c·R_n(r/(D/2))",
            ["term", "c (rad)", "± 1σ (rad)", "c (waves)", "± 1σ (waves)"],
            [
                [
                    t["name"],
                    f"{t['coefficient_rad']:+.4f}",
                    f"{t['sigma_rad']:.4f}",
                    f"{t['coefficient_waves']:+.4f}",
                    f"{t['sigma_waves']:.4f}",
                ]
                for t in result.terms
            ],
        )
    )
    con.print(
        render.table(
            "Fit per PSF (relative L2 error: ‖measured − model‖/‖measured‖)",
            ["depth", "λ (nm)", "rel. L2 nominal", "rel. L2 fitted", "noise σ", "shift (y, x) px"],
            [
                [
                    format_length(math.inf if p["depth_m"] is None else p["depth_m"]),
                    render.nm(p["wavelength_m"], 1),
                    f"{p['relative_l2_nominal']:.4f}",
                    f"{p['relative_l2']:.4f}",
                    f"{p['noise_sigma']:.3g}",
                    f"{p['shift_px'][0]:+.3f}, {p['shift_px'][1]:+.3f}",
                ]
                for p in result.psfs
            ],
        )
    )
    con.print(
        f"condition number {result.condition_number:.3g}; reduced χ² {result.chi2_reduced:.3g}; "
        f"{result.iterations} iterations{'' if result.converged else ' (not converged)'}; {result.seconds:.2f} s; "
        f"θ written to {output}"
    )
