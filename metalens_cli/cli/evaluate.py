"""`metalens evaluate`: PSNR/SSIM (and LPIPS when its weights are present) of unobstructed and
obstructed captures, design against design."""

from __future__ import annotations

import click

from metalens_cli.cli import render
from metalens_cli.cli.options import json_option, plot_option
from metalens_cli.cli.simulate import capture_options, setup


@click.command("evaluate")
@click.argument("specs", metavar="DESIGN...", nargs=-1, required=True)
@capture_options
@click.option("--obstruction", default="dirt,fence", show_default=True, help="Comma-separated: dirt, fence, drops, rain, file:PATH.png.")
@click.option("--csv", "csv_path", type=click.Path(dir_okay=False), help="Write the rows as CSV.")
@click.option("--lpips-weights", "lpips_weights", type=click.Path(exists=True, file_okay=False),
              help="Directory with alexnet-owt-7be5be79.pth and lpips's v0.1 alex.pth "
                   "(without it: $METALENS_LPIPS_WEIGHTS, then torch hub's checkpoints with an installed lpips; "
                   "none found: LPIPS is skipped with a note; nothing is downloaded).")
@json_option
@plot_option
def evaluate(specs, preset_path, f_m, aperture_m, pitch_m, images, limit, z_near_m, z_far_m, seed, pixels, psf_pixels,
             pixel_pitch_m, wavelengths, psf_normalization, alpha_gain, photons, read_noise, device, obstruction, csv_path,
             lpips_weights, as_json, plot_path):
    """Unobstructed and obstructed captures of each DESIGN against the clean images.

    PSNR and SSIM after the global gain/bias match (Suppl. Note 11), on sRGB-encoded images,
    averaged over the images; Δ = obstructed − unobstructed. The same seed gives every design
    the same depths, obstructions and noise. LPIPS (v0.1, AlexNet; lower is closer) on the same
    images when its weights are found locally (nothing is downloaded), else skipped with a note.
    """
    from metalens_cli.imaging.lpips import Lpips, find_lpips_weights
    from metalens_cli.imaging.obstructions import parse_obstructions
    from metalens_cli.imaging.pipeline import channel_psfs, score, simulate_captures

    kinds = parse_obstructions(obstruction)
    lpips_paths, lpips_skip = find_lpips_weights(lpips_weights)
    lpips_model = Lpips.from_files(lpips_paths.alexnet, lpips_paths.lin) if lpips_paths else None
    metrics = ("psnr_db", "ssim", "lpips") if lpips_model is not None else ("psnr_db", "ssim")
    s = setup(list(specs), preset_path, f_m, aperture_m, pitch_m, images, limit, z_near_m, z_far_m, seed, pixels, psf_pixels,
              pixel_pitch_m, wavelengths, device)
    rows, deltas, panels = [], [], {}
    for design in s["designs"]:
        psfs = channel_psfs(design, s["z_near_m"], s["z_far_m"], s["wavelengths_m"], s["psf_pixels"], s["pixel_pitch_m"],
                            psf_normalization, device=s["device"])
        panels[design.spec] = []
        for kind in kinds:
            captures = simulate_captures(s["images"], kind, psfs, design.focal_length_m, s["pixel_pitch_m"], seed,
                                         params=s["obstruction_params"], alpha_gain=alpha_gain, photons=photons, read_noise=read_noise)
            means = {}
            for condition in ("unobstructed", "obstructed"):
                scores = [score(getattr(c, condition), c.clean, lpips_model) for c in captures]
                means[condition] = {k: sum(x[k] for x in scores) / len(scores) for k in metrics}
                rows.append({"design": design.spec, "obstruction": kind, "condition": condition, **means[condition]})
            deltas.append({"design": design.spec, "obstruction": kind,
                           "delta_psnr_db": means["obstructed"]["psnr_db"] - means["unobstructed"]["psnr_db"],
                           "delta_ssim": means["obstructed"]["ssim"] - means["unobstructed"]["ssim"],
                           **({"delta_lpips": means["obstructed"]["lpips"] - means["unobstructed"]["lpips"]}
                              if lpips_model is not None else {})})
            first = captures[0]
            if not panels[design.spec]:
                panels[design.spec] += [("clean", first.clean), ("unobstructed", first.unobstructed)]
            panels[design.spec].append((f"obstructed: {kind}", first.obstructed))
    notes = [n for n in (lpips_skip,) if n]
    err = render.console(stderr=True)
    for note in notes:
        err.print(f"note: {note}")
    if csv_path:
        _write_csv(csv_path, rows, metrics)
    if plot_path:
        from metalens_cli.plotting.imaging import comparison_figure

        comparison_figure(plot_path, [d.spec for d in s["designs"]], panels)
    if as_json:
        render.emit_json({"rows": rows, "deltas": deltas, "images": [i.name for i in s["images"]],
                          "z_near_m": s["z_near_m"], "z_far_m": s["z_far_m"], "seed": seed, "notes": notes,
                          **({"csv": str(csv_path)} if csv_path else {}), **({"plot": str(plot_path)} if plot_path else {})})
        return
    table_rows = []
    for d in deltas:
        u = next(r for r in rows if r["design"] == d["design"] and r["obstruction"] == d["obstruction"] and r["condition"] == "unobstructed")
        o = next(r for r in rows if r["design"] == d["design"] and r["obstruction"] == d["obstruction"] and r["condition"] == "obstructed")
        table_rows.append([d["design"], d["obstruction"], f"{u['psnr_db']:.2f}", f"{o['psnr_db']:.2f}", f"{d['delta_psnr_db']:+.2f}",
                           f"{u['ssim']:.3f}", f"{o['ssim']:.3f}", f"{d['delta_ssim']:+.3f}"]
                          + ([f"{u['lpips']:.3f}", f"{o['lpips']:.3f}", f"{d['delta_lpips']:+.3f}"] if lpips_model is not None else []))
    con = render.console()
    con.print(render.table(f"Raw captures vs clean ({len(s['images'])} images; obstruction at {s['z_near_m'] * 1e3:.1f} mm, scene at {s['z_far_m']:.2f} m)",
                           ["design", "obstruction", "PSNR unobstr.", "PSNR obstr.", "Δ PSNR", "SSIM unobstr.", "SSIM obstr.", "Δ SSIM"]
                           + (["LPIPS unobstr.", "LPIPS obstr.", "Δ LPIPS"] if lpips_model is not None else []),
                           table_rows))


def _write_csv(path, rows, metrics=("psnr_db", "ssim")) -> None:
    import csv
    import io

    from metalens_cli.io.atomic import atomic_write

    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=["design", "obstruction", "condition", *metrics], lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    with atomic_write(path) as temporary:
        temporary.write_text(buffer.getvalue(), encoding="utf-8")
