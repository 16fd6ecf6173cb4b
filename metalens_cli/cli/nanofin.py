"""`metalens nanofin`: the meta-atom's geometric-phase conversion efficiency η(λ) by RCWA."""

from __future__ import annotations

import click

from metalens_cli.cli import render
from metalens_cli.cli.options import (
    BandSpec,
    Length,
    LengthList,
    MetalensGroup,
    Number,
    OutputFolder,
    WavelengthList,
    announce,
    check_output_unused,
    device_option,
    flatten,
    json_option,
    load_preset_option,
    max_memory_option,
    overwrite_option,
    plot_option,
    quiet_option,
    torch_device,
)
from metalens_cli.cli.progress import progress_bar
from metalens_cli.errors import InputError
from metalens_cli.optics.nanofin import FIRST_HARMONICS, SOLVERS

MAX_HARMONICS = 41
LEAST_MAX_HARMONICS = FIRST_HARMONICS + 4
MAX_FINS = 10_000
TYPICAL_HARMONICS = 25  # what auto picks for the paper's fin (docs/benchmarks.md)
solver_option = click.option(
    "--solver",
    type=click.Choice(tuple(SOLVERS)),
    default="modes",
    show_default=True,
    help="RCWA: modes (fast, symmetric subspaces, --device) or meent (the slower reference, CPU).",
)


def _odd_harmonics(least: int, auto: bool = False):
    """A callback parsing an odd number of Fourier harmonics per axis from ``least`` to
    MAX_HARMONICS (or ``auto``, as None, when ``auto``)."""

    def parse(ctx, param, text) -> int | None:
        text = str(text)
        if auto and text == "auto":
            return None
        if not text.isdigit() or int(text) % 2 == 0 or not least <= int(text) <= MAX_HARMONICS:
            raise click.BadParameter(
                f"{text!r} (expected {'auto, or ' if auto else ''}an odd number of Fourier harmonics per axis "
                f"from {least} to {MAX_HARMONICS})"
            )
        return int(text)

    return parse


max_harmonics_option = click.option(
    "--max-harmonics",
    default=35,
    show_default=True,
    callback=_odd_harmonics(LEAST_MAX_HARMONICS),
    help=f"The largest N tried when converging (odd, {LEAST_MAX_HARMONICS} to {MAX_HARMONICS}: N = {FIRST_HARMONICS}, "
    f"{FIRST_HARMONICS + 2}, … until η moves less than the tolerance from both N − 2 and N − 4).",
)


@click.group("nanofin", cls=MetalensGroup, context_settings={"help_option_names": ["-h", "--help"]})
def nanofin():
    """The nanofin (meta-atom): conversion efficiency η(λ) by RCWA."""


@nanofin.command("efficiency")
@click.option("--period", "period_m", type=Length(), default="395nm", show_default=True, help="Square lattice period.")
@click.option(
    "--height", "height_m", type=Length(), default="700nm", show_default=True, help="Fin height (film thickness)."
)
@click.option("--width", "width_m", type=Length(), default="305nm", show_default=True, help="Fin width, along x.")
@click.option("--length", "length_m", type=Length(), default="125nm", show_default=True, help="Fin length, along y.")
@click.option(
    "--material",
    default="sinx",
    show_default=True,
    help=(
        "Fin: sinx, fused-silica, tio2, a-si, air; a number (2.0, 2.0+0.01j); cauchy:A,B[,C] (λ in µm); "
        "a CSV wavelength_nm,n[,k]."
    ),
)
@click.option(
    "--substrate",
    default="fused-silica",
    show_default=True,
    help="Substrate, in the forms of --material (its real index is used).",
)
@click.option("--wavelengths", type=WavelengthList(), multiple=True, help="Wavelengths [430:660:10nm].")
@click.option(
    "--harmonics",
    default="auto",
    show_default=True,
    callback=_odd_harmonics(1, auto=True),
    help=(
        "Fourier harmonics N per axis (odd), or auto: the first N whose η moves less than --tolerance "
        "from N − 2 and N − 4."
    ),
)
@max_harmonics_option
@click.option(
    "--tolerance",
    type=Number(1e-6, 0.1),
    default=1e-3,
    show_default=True,
    help="auto: the change of η that counts as converged.",
)
@solver_option
@device_option
@quiet_option()
@max_memory_option
@json_option
@plot_option
def efficiency(
    period_m,
    height_m,
    width_m,
    length_m,
    material,
    substrate,
    wavelengths,
    harmonics,
    max_harmonics,
    tolerance,
    solver,
    device,
    quiet,
    max_memory,
    as_json,
    plot_path,
):
    """η(λ) of a rectangular fin in air on a substrate, light from the substrate at normal
    incidence: η = |t_xx − t_yy|²/4 (power into the opposite circular polarisation),
    co-polarised |t_xx + t_yy|²/4, T and R, by RCWA with Li's factorisation.

    With --harmonics auto, η at every wavelength is computed for N = 5, 7, … (the convergence
    report: the largest change of η and the seconds per N) until it moves less than
    --tolerance at every wavelength from both N − 2 and N − 4; the last N is the answer.
    """
    from metalens_cli.design.fin_efficiency import efficiency_report, fin_efficiency
    from metalens_cli.io.units import parse_length_list
    from metalens_cli.optics.fin import Fin

    fin = Fin(period_m, height_m, width_m, length_m)  # checked as it is made
    wavelengths_m = flatten(wavelengths) or parse_length_list("430:660:10nm", "--wavelengths")
    fin_material, substrate_material = _materials(material, substrate)
    n_fin, n_sub = (
        fin_material.index(wavelengths_m, "--material"),
        substrate_material.index(wavelengths_m, "--substrate"),
    )
    run_device = torch_device(device)
    announce(
        _efficiency_estimate(len(wavelengths_m), harmonics, max_harmonics, solver),
        max_memory,
        device=run_device if solver == "modes" else None,  # meent solves on the host
    )
    with progress_bar("nanofin efficiency", quiet) as update:
        result = fin_efficiency(
            fin,
            n_fin,
            n_sub,
            wavelengths_m,
            harmonics,
            max_harmonics=max_harmonics,
            tolerance=tolerance,
            device=run_device,
            solver=solver,
            on_progress=update,
        )
    if plot_path:
        from metalens_cli.plotting.nanofin import plot_efficiency

        plot_efficiency(plot_path, result.response, result.convergence)
    render.say(result.warnings)
    report = efficiency_report(fin, fin_material, substrate_material, result, solver, plot_path)
    if as_json:
        render.emit_json(report)
        return
    _render_efficiency(fin, fin_material.name, substrate_material.name, result)


def _materials(material: str, substrate: str):
    """The fin's and the substrate's :class:`~metalens_cli.optics.materials.Material`, errors
    naming --material and --substrate."""
    from metalens_cli.io.materials import parse_material

    return parse_material(material, "--material"), parse_material(substrate, "--substrate")


def _efficiency_estimate(wavelengths: int, harmonics: int | None, max_harmonics: int, solver: str):
    """What nanofin efficiency costs at N = ``harmonics``, or converging (None): typically to
    TYPICAL_HARMONICS, at most to ``max_harmonics``."""
    from metalens_cli.io.resources import Estimate
    from metalens_cli.optics.nanofin import convergence_seconds, estimate_bytes, estimate_seconds

    worst = harmonics or max_harmonics
    if harmonics:
        seconds = longest = estimate_seconds(harmonics, wavelengths, solver)
    else:
        seconds, longest = (
            convergence_seconds(n, wavelengths, solver) for n in (min(TYPICAL_HARMONICS, max_harmonics), worst)
        )
    return Estimate(
        f"nanofin efficiency at {wavelengths} wavelengths, up to {worst} × {worst} harmonics",
        estimate_bytes(worst, solver),
        "--harmonics",
        seconds,
        seconds_max=longest,
    )


def _render_efficiency(fin, material: str, substrate: str, result) -> None:
    """The table of η, co-polarised, T and R per wavelength, the convergence and the time."""
    r, table = result.response, result.convergence
    con = render.console()
    rows = [
        [render.nm(w, 1), f"{e:.4f}", f"{c:.4f}", f"{t:.4f}", f"{rr:.4f}"]
        for w, e, c, t, rr in zip(r.wavelengths_m, r.conversion, r.co_polarized, r.transmittance, r.reflectance)
    ]
    con.print(
        render.table(
            f"Nanofin {fin.width_m * 1e9:g} × {fin.length_m * 1e9:g} × {fin.height_m * 1e9:g} nm at period "
            f"{fin.period_m * 1e9:g} nm, {material} on {substrate}, {result.harmonics} × {result.harmonics} harmonics",
            ["λ (nm)", "η conversion", "co-polarised", "T", "R"],
            rows,
        )
    )
    if table:
        con.print(
            "convergence (largest change of η over the wavelengths from N − 2): "
            + ", ".join(f"N = {t['harmonics']}: {t['max_change']:.1e} ({t['seconds']:.2f} s)" for t in table[1:])
        )
    con.print(f"{result.seconds:.1f} s for {r.wavelengths_m.size} wavelengths")


def _check_bands(bands: tuple[tuple[float, float], ...]) -> None:
    """Refuse ``--band`` values (centre, FWHM in metres) that a preset's filter refuses
    (overlapping, too narrow), by the presets' rule with a filter's default edges."""
    from metalens_cli.io.presets import FilterConfig
    from metalens_cli.optics.band_rules import check_bands

    edges = FilterConfig()
    try:
        check_bands([c for c, _ in bands], [w for _, w in bands], edges.edge_width_m, edges.peak_transmission)
    except InputError as exc:
        raise InputError("--band", exc.message, exc.expected) from None


@nanofin.command("sweep")
@click.option("--width", "width_m", type=LengthList(), required=True, help="Fin widths, e.g. 210:360:5nm.")
@click.option("--length", "length_m", type=LengthList(), required=True, help="Fin lengths, e.g. 40:190:5nm.")
@click.option(
    "--preset",
    "preset_path",
    type=click.Path(dir_okay=False),
    help="Preset whose [nanofin] and filter bands are the defaults below; OUTPUT/preset.toml is this preset with the "
    "recommended fin.",
)
@click.option(
    "--period", "period_m", type=Length(), help="Square lattice period [the preset's nanofin.pitch, else 395nm]."
)
@click.option("--height", "height_m", type=Length(), help="Fin height [the preset's, else 700nm].")
@click.option("--material", help="Fin material, as for nanofin efficiency [the preset's, else sinx].")
@click.option("--substrate", help="Substrate material [the preset's, else fused-silica].")
@click.option(
    "--band",
    "bands",
    type=BandSpec(),
    multiple=True,
    help=(
        "Pass band CENTER:FWHM, repeatable [the preset's filter bands, else the paper's "
        "457nm:22nm, 530nm:20nm, 628nm:28nm]."
    ),
)
@click.option(
    "--harmonics",
    default=9,
    show_default=True,
    callback=_odd_harmonics(1),
    help="Fourier harmonics per axis for the map (odd; the chosen fin and its neighbours are recomputed converged).",
)
@max_harmonics_option
@click.option(
    "--samples-per-band",
    type=click.IntRange(1, 64),
    default=8,
    show_default=True,
    help="Wavelengths evenly across each band's FWHM whose η is averaged (3 bands × 8: 24 wavelengths).",
)
@click.option(
    "--fabrication-tolerance",
    "tolerance_m",
    type=Length(),
    default="10nm",
    show_default=True,
    help="The recommended fin keeps --keep of its η for every grid fin within ± this in width and length.",
)
@click.option("--keep", type=Number(0, 1, min_open=True), default=0.95, show_default=True)
@click.option(
    "-o",
    "--output",
    type=OutputFolder(),
    required=True,
    help="Folder for sweep.npz, sweep.csv, sweep.png, sweep.json, nanofin.toml (and preset.toml with --preset).",
)
@overwrite_option
@device_option
@quiet_option()
@max_memory_option
@json_option
def sweep(
    width_m,
    length_m,
    preset_path,
    period_m,
    height_m,
    material,
    substrate,
    bands,
    harmonics,
    max_harmonics,
    samples_per_band,
    tolerance_m,
    keep,
    output,
    overwrite,
    device,
    quiet,
    max_memory,
    as_json,
):
    """η over a grid of fin widths × lengths, per pass band and their mean (the paper's Suppl.
    Note 7), and the recommended fin: the best mean η whose neighbours within
    --fabrication-tolerance keep --keep of it, recomputed with converged harmonics.

    OUTPUT/nanofin.toml is that fin as a preset's [nanofin] (η by RCWA at the converged
    harmonics); with --preset, OUTPUT/preset.toml is the preset with it, for every later command
    (psf-scan, optimize, simulate, export-gds) to use that fin."""
    from functools import partial

    from metalens_cli.design.fin_choice import band_wavelengths, sweep_cell, sweep_fins
    from metalens_cli.design.fin_files import sweep_report, write_sweep
    from metalens_cli.optics.fin import Fin

    check_output_unused(output, overwrite)
    preset = load_preset_option(preset_path)
    cell = sweep_cell(
        preset, period_m=period_m, height_m=height_m, material=material, substrate=substrate, bands_m=bands
    )
    widths_m, lengths_m = sorted(set(width_m)), sorted(set(length_m))
    if len(widths_m) * len(lengths_m) > MAX_FINS:
        raise InputError("--width", f"{len(widths_m)} × {len(lengths_m)} fins", f"at most {MAX_FINS} fins")
    _check_bands(bands)
    waves = band_wavelengths(cell.bands_m, samples_per_band).ravel()
    fin_material, substrate_material = _materials(cell.material, cell.substrate)
    n_fin = partial(fin_material.index, field="--material")
    n_sub = partial(substrate_material.index, field="--substrate")
    n_fin(waves), n_sub(waves)  # refuse wavelengths outside a material's table before any work
    Fin(cell.period_m, cell.height_m, min(widths_m), min(lengths_m))  # the grid's sizes, checked as the fin is made
    estimate = _sweep_estimate(widths_m, lengths_m, waves.size, harmonics, max_harmonics, tolerance_m)
    run_device = torch_device(device)
    announce(estimate, max_memory, device=run_device)
    result = sweep_fins(
        cell.period_m,
        cell.height_m,
        widths_m,
        lengths_m,
        cell.bands_m,
        n_fin,
        n_sub,
        harmonics,
        samples_per_band=samples_per_band,
        tolerance_m=tolerance_m,
        keep=keep,
        max_harmonics=max_harmonics,
        device=run_device,
        progress=lambda stage: progress_bar(stage, quiet),
    )
    render.say(result.warnings)
    report = sweep_report(cell, fin_material, substrate_material, result, output, preset_path)
    write_sweep(output, cell, result, report, preset)
    if as_json:
        render.emit_json(report)
        return
    _render_sweep(result, output, preset)


def _sweep_estimate(widths_m, lengths_m, wavelengths: int, harmonics: int, max_harmonics: int, tolerance_m: float):
    """What nanofin sweep costs: the map at ``harmonics``, then the chosen fin converged (typically
    to TYPICAL_HARMONICS, at most to ``max_harmonics``) and its neighbourhood recomputed at that N."""
    from metalens_cli.design.fin_choice import largest_neighbourhood
    from metalens_cli.io.resources import Estimate
    from metalens_cli.optics.nanofin import convergence_seconds, estimate_bytes, estimate_seconds

    neighbours = largest_neighbourhood(widths_m, lengths_m, tolerance_m)
    coarse = estimate_seconds(harmonics, wavelengths * len(widths_m) * len(lengths_m))
    typical, worst = (
        (coarse + convergence_seconds(n, wavelengths) + estimate_seconds(n, wavelengths * neighbours))
        for n in (min(TYPICAL_HARMONICS, max_harmonics), max_harmonics)
    )
    return Estimate(
        f"nanofin sweep of {len(widths_m)} × {len(lengths_m)} fins × {wavelengths} wavelengths at {harmonics} "
        "harmonics",
        estimate_bytes(max(harmonics, max_harmonics)),
        "--harmonics",
        typical,
        seconds_max=worst,
    )


def _render_sweep(result, output, preset) -> None:
    """The recommended fin on the map and converged, and the files written."""
    c, m = result.choice, result.map
    f, tolerance_nm = c["converged"], c["tolerance_m"] * 1e9
    con = render.console()
    con.print(
        f"recommended fin: {c['width_m'] * 1e9:g} × {c['length_m'] * 1e9:g} nm, mean η {c['score']:.4f} at "
        f"{m.harmonics} harmonics (worst within ±{tolerance_nm:g} nm: "
        f"{c['worst_neighbour']:.4f}{'' if c['robust'] else '; no fin keeps ' + format(c['keep'], 'g')})"
    )
    con.print(
        f"converged ({f['harmonics']} harmonics): mean η {f['score']:.4f}, per band "
        + " / ".join(f"{v:.4f}" for v in f["eta_per_band"])
        + f"; worst of {f['fins']} fins within ±{tolerance_nm:g} nm: {f['worst_neighbour']:.4f}"
    )
    con.print(
        f"wrote {output}/sweep.npz, sweep.csv, sweep.png, sweep.json ({m.seconds + f['seconds']:.1f} s of RCWA), "
        "nanofin.toml (the fin as a preset's [nanofin])"
        + (f", preset.toml ({preset.name} with that fin)" if preset else ""),
        markup=False,
    )
