"""`metalens nanofin`: the meta-atom's geometric-phase conversion efficiency η(λ) by RCWA."""

from __future__ import annotations

import click

from metalens_cli.cli import render
from metalens_cli.cli.options import announce, json_option, Length, max_memory_option, MetalensGroup, Number, plot_option, WavelengthList
from metalens_cli.cli.progress import progress_bar

MAX_HARMONICS = 41
TYPICAL_HARMONICS = 17
BYTES_PER_UNKNOWN_SQUARED = 16 * 12  # complex128 matrices of (2·N²)² that meent holds at once


def _harmonics(ctx, param, text: str) -> int | None:
    """``auto`` (None) or an odd number of harmonics per axis."""
    if text == "auto":
        return None
    if not text.isdigit() or int(text) % 2 == 0 or not 1 <= int(text) <= MAX_HARMONICS:
        raise click.BadParameter(f"{text!r} (expected auto, or an odd number of Fourier harmonics per axis from 1 to {MAX_HARMONICS})")
    return int(text)


@click.group("nanofin", cls=MetalensGroup, context_settings={"help_option_names": ["-h", "--help"]})
def nanofin():
    """The nanofin (meta-atom): conversion efficiency η(λ) by RCWA."""


@nanofin.command("efficiency")
@click.option("--period", "period_m", type=Length(), default="395nm", show_default=True, help="Square lattice period.")
@click.option("--height", "height_m", type=Length(), default="700nm", show_default=True, help="Fin height (film thickness).")
@click.option("--width", "width_m", type=Length(), default="305nm", show_default=True, help="Fin width, along x.")
@click.option("--length", "length_m", type=Length(), default="125nm", show_default=True, help="Fin length, along y.")
@click.option("--material", default="sinx", show_default=True,
              help="Fin: sinx, fused-silica, tio2, a-si, air; a number (2.0, 2.0+0.01j); cauchy:A,B[,C] (λ in µm); a CSV wavelength_nm,n[,k].")
@click.option("--substrate", default="fused-silica", show_default=True, help="Substrate, in the forms of --material (its real index is used).")
@click.option("--wavelengths", type=WavelengthList(), multiple=True, help="Wavelengths [430:660:10nm].")
@click.option("--harmonics", default="auto", show_default=True, callback=_harmonics,
              help="Fourier harmonics N per axis (odd), or auto: the first N whose η is within --tolerance of N − 2's.")
@click.option("--max-harmonics", type=click.IntRange(3, MAX_HARMONICS), default=25, show_default=True, help="auto: the largest N tried.")
@click.option("--tolerance", type=Number(1e-6, 0.1), default=1e-3, show_default=True, help="auto: the change of η that counts as converged.")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@max_memory_option
@json_option
@plot_option
def efficiency(period_m, height_m, width_m, length_m, material, substrate, wavelengths, harmonics, max_harmonics, tolerance,
               quiet, max_memory, as_json, plot_path):
    """η(λ) of a rectangular fin in air on a substrate, light from the substrate at normal
    incidence: η = |t_xx − t_yy|²/4 (power into the opposite circular polarisation),
    co-polarised |t_xx + t_yy|²/4, T and R, by RCWA with Li's factorisation (meent).

    With --harmonics auto, η at the middle wavelength is computed for N = 5, 7, … (the
    convergence report: η and seconds per N) and the first N whose η is within --tolerance of
    the N − 2 result is used for every wavelength.
    """
    from metalens_cli.io.materials import parse_material
    from metalens_cli.io.resources import Estimate
    from metalens_cli.io.units import parse_length_list
    from metalens_cli.optics.nanofin import converge, estimate_seconds, Fin, fin_response

    fin = Fin(period_m, height_m, width_m, length_m)
    fin.check()
    wavelengths_m = [w for group in wavelengths for w in group] or parse_length_list("430:660:10nm", "--wavelengths")
    fin_material, substrate_material = parse_material(material, "--material"), parse_material(substrate, "--substrate")
    n_fin, n_sub = fin_material.index(wavelengths_m, "--material"), substrate_material.index(wavelengths_m, "--substrate")
    worst = harmonics or max_harmonics
    typical = harmonics or min(TYPICAL_HARMONICS, max_harmonics)  # auto: Li's factorisation converges near N = 17
    seconds = estimate_seconds(typical, len(wavelengths_m)) + (0 if harmonics else sum(estimate_seconds(n, 1) for n in range(5, typical + 3, 2)))
    announce(Estimate(f"nanofin efficiency at {len(wavelengths_m)} wavelengths, up to {worst} × {worst} harmonics",
                      BYTES_PER_UNKNOWN_SQUARED * (2 * worst**2) ** 2, "--harmonics", seconds), max_memory)
    table, chosen = [], harmonics
    warnings = []
    if harmonics is None:
        middle = len(wavelengths_m) // 2
        chosen, table = converge(fin, n_fin[middle], n_sub[middle], wavelengths_m[middle], 5, max_harmonics, tolerance)
        if chosen is None:
            chosen = table[-1]["harmonics"]
            warnings.append(f"η moved {abs(table[-1]['conversion'] - table[-2]['conversion']):.2g} from N = {table[-2]['harmonics']} "
                            f"to {chosen}, more than --tolerance {tolerance:g}; using N = {chosen} (raise --max-harmonics)")
    with progress_bar("nanofin efficiency", quiet) as update:
        r = fin_response(fin, n_fin, n_sub, wavelengths_m, chosen, update)
    if plot_path:
        from metalens_cli.plotting.nanofin import plot_efficiency

        plot_efficiency(plot_path, r, table)
    err = render.console(stderr=True)
    for warning in warnings:
        err.print(f"warning: {warning}", markup=False, soft_wrap=True)
    report = {
        "fin": {"period_m": period_m, "height_m": height_m, "width_m": width_m, "length_m": length_m},
        "material": fin_material.describe(), "substrate": substrate_material.describe(),
        "wavelengths_m": r.wavelengths_m.tolist(), "conversion_efficiency": r.conversion.tolist(),
        "co_polarized": r.co_polarized.tolist(), "transmittance": r.transmittance.tolist(), "reflectance": r.reflectance.tolist(),
        "t_xx": [[z.real, z.imag] for z in r.t_xx.tolist()], "t_yy": [[z.real, z.imag] for z in r.t_yy.tolist()],
        "harmonics": chosen, "convergence": table, "tolerance": tolerance if harmonics is None else None,
        "solver": "meent (RCWA, Li's factorisation)", "seconds": float(r.seconds.sum()), "warnings": warnings,
        **({"plot": str(plot_path)} if plot_path else {}),
    }
    if as_json:
        render.emit_json(report)
        return
    con = render.console()
    rows = [[render.nm(w, 1), f"{e:.4f}", f"{c:.4f}", f"{t:.4f}", f"{rr:.4f}"]
            for w, e, c, t, rr in zip(r.wavelengths_m, r.conversion, r.co_polarized, r.transmittance, r.reflectance)]
    con.print(render.table(f"Nanofin {width_m * 1e9:g} × {length_m * 1e9:g} × {height_m * 1e9:g} nm at period {period_m * 1e9:g} nm, "
                           f"{fin_material.name} on {substrate_material.name}, {chosen} × {chosen} harmonics",
                           ["λ (nm)", "η conversion", "co-polarised", "T", "R"], rows))
    if table:
        con.print("convergence at " + render.nm(wavelengths_m[len(wavelengths_m) // 2], 1) + " nm: "
                  + ", ".join(f"N = {t['harmonics']}: η {t['conversion']:.4f} ({t['seconds']:.2f} s)" for t in table))
    con.print(f"{r.seconds.sum():.1f} s for {r.wavelengths_m.size} wavelengths")
