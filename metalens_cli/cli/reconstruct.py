"""`metalens reconstruct`: train the reconstruction network of a design, apply it, export it."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import click

from metalens_cli.cli import render
from metalens_cli.cli.options import (
    Interval,
    Length,
    MetalensGroup,
    Number,
    OutputFile,
    OutputFolder,
    check_output_unused,
    device_option,
    json_option,
    lpips_weights_option,
    overwrite_option,
    quiet_option,
    torch_device,
    training_options,
)
from metalens_cli.cli.progress import run_training
from metalens_cli.errors import InputError
from metalens_cli.io.input_files import IMAGE_SUFFIXES


@click.group("reconstruct", cls=MetalensGroup)
def reconstruct():
    """The neural back end of a lens (Suppl. Note 5): train, apply, export.

    A network is trained per design on pairs simulated through it (or captured pairs), cleans
    captures of any size, and exports to a file torch can run without this package.
    """


@reconstruct.command("train")
@click.argument("spec", metavar="DESIGN")
@click.option(
    "--preset",
    "preset_path",
    type=click.Path(dir_okay=False),
    help="Reconstruction preset TOML ([network], [train], [data]) [built-in defaults]; with --resume the run's own is "
    "used, and one given must match it (steps and seed aside).",
)
@click.option("-o", "--output", type=OutputFolder(), required=True, help="Run directory (created).")
@click.option(
    "--camera",
    "camera_path",
    type=click.Path(dir_okay=False),
    help=(
        "Preset giving the camera (lens geometry, filter, sensor, depths) [the design's own, else the paper's sensor]."
    ),
)
@click.option("--f", "f_m", type=Length(), help="Lens-to-sensor distance (focal length) [camera's].")
@click.option("--aperture", "aperture_m", type=Length(), help="Lens diameter D [camera's].")
@click.option("--pitch", "pitch_m", type=Length(), help="Meta-atom pitch [camera's; hyperbolic default 395nm].")
@click.option(
    "--pairs",
    type=click.Path(exists=True, file_okay=False),
    help="Captured pairs DIR/gt, DIR/captures instead of simulation.",
)
@click.option("--z-near", "z_near_m", type=Interval(), help="Obstruction depth interval [camera's, else 40mm:50mm].")
@click.option("--z-far", "z_far_m", type=Interval(), help="Scene depth interval [camera's, else 1m:20m].")
@click.option("--pixel-pitch", "pixel_pitch_m", type=Length(), help="Sensor pixel pitch [camera's, else 1.85um].")
@lpips_weights_option(
    "Directory with the LPIPS weights for the loss's LPIPS term (else looked up as evaluate does; none: left out)."
)
@training_options("train")
def train(
    spec,
    preset_path,
    output,
    camera_path,
    f_m,
    aperture_m,
    pitch_m,
    pairs,
    z_near_m,
    z_far_m,
    pixel_pitch_m,
    lpips_weights,
    steps,
    seed,
    device,
    resume,
    threads,
    quiet,
    as_json,
):
    """Train the reconstruction network of DESIGN into a run directory.

    Pairs are simulated on the fly through DESIGN with the image formation of `simulate`
    (generated scenes or the preset's data.images, obstructions of data.obstructions, depths
    from the camera's intervals, sensor noise), or read from --pairs. Ctrl-C writes a
    checkpoint; --resume continues exactly. Under `torchrun --nproc-per-node N -m metalens_cli
    reconstruct train ...` the batch is split over ranks.
    """
    import torch

    from metalens_cli.cli.simulate import setup
    from metalens_cli.design.reconstruct_data import Camera
    from metalens_cli.design.reconstruct_training import train_reconstruction
    from metalens_cli.io.reconstruct_presets import load_reconstruct_preset

    if threads:
        torch.set_num_threads(threads)
    from metalens_cli.io.atomic import ensure_folder

    preset = load_reconstruct_preset(preset_path) if preset_path else None
    ensure_folder(Path(output).parent, "--output")
    s = setup(
        [spec],
        preset_path=camera_path,
        f_m=f_m,
        aperture_m=aperture_m,
        pitch_m=pitch_m,
        z_near_m=z_near_m,
        z_far_m=z_far_m,
        pixels=None,
        pixel_pitch_m=pixel_pitch_m,
        wavelengths=(),
        device=device,
    )
    camera = Camera(s.pixel_pitch_m, s.z_near_interval_m, s.z_far_interval_m, s.obstruction_params)
    report = run_training(
        "reconstruct",
        quiet,
        f"metalens reconstruct train {spec} -o {output} --resume",
        lambda progress: train_reconstruction(
            s.designs[0],
            camera,
            preset,
            output,
            steps=steps,
            seed=seed,
            device=s.device,
            resume=resume,
            pairs=pairs,
            lpips_weights=lpips_weights,
            on_step=progress.step,
            on_stage=progress.stage,
        ),
    )
    if report is None:
        return
    if as_json:
        render.emit_json({"run_dir": str(output), **report})
        return
    final, cost = report["validation"]["final"], report["cost"]
    rows = [
        [
            condition,
            f"{final[f'raw_{condition}_psnr_db']:.2f}",
            f"{final[f'recon_{condition}_psnr_db']:.2f}",
            f"{final[f'raw_{condition}_ssim']:.3f}",
            f"{final[f'recon_{condition}_ssim']:.3f}",
        ]
        for condition in ("obstructed", "unobstructed")
        if f"raw_{condition}_psnr_db" in final
    ]
    con = render.console()
    con.print(
        render.table(
            f"Validation pairs of {output} (after the photometric match, sRGB)",
            ["condition", "Raw PSNR", "Recon PSNR", "Raw SSIM", "Recon SSIM"],
            rows,
        )
    )
    per_step = cost["seconds_per_step_median"]
    con.print(
        f"{cost['steps_run']} steps"
        + (f", {per_step:.3f} s/step (median)" if per_step else "")
        + f"; loss terms: {', '.join(report['loss_terms'])}"
    )
    con.print(f"wrote {output}/ (model.pt, loss.csv, validation/, run.json, …)")


def _inputs(paths) -> list[Path]:
    """Image files named directly or found in folders (sorted), refused before any work."""
    files = []
    for text in paths:
        path = Path(text)
        if path.is_dir():
            found = sorted(
                p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith(".")
            )
            if not found:
                raise InputError("INPUT", f"{text!r} holds no images", f"files ending in {', '.join(IMAGE_SUFFIXES)}")
            files += found
        elif path.is_file():
            if path.suffix.lower() not in IMAGE_SUFFIXES:
                raise InputError("INPUT", f"{text!r} is not an image file", ", ".join(IMAGE_SUFFIXES))
            files.append(path)
        else:
            raise InputError("INPUT", f"no such file or folder {text!r}", "image files or folders of them")
    stems = [p.stem for p in files]
    twice = sorted({s for s in stems if stems.count(s) > 1})
    if twice:
        raise InputError(
            "INPUT", f"two inputs named {twice[0]!r} would write the same outputs", "inputs with distinct names"
        )
    return files


@reconstruct.command("apply")
@click.argument("run", metavar="RUN")
@click.argument("inputs", metavar="INPUT...", nargs=-1, required=True)
@click.option("-o", "--output", type=OutputFolder(), required=True, help="Output folder (created).")
@overwrite_option
@device_option
@click.option(
    "--memory-mib",
    type=click.IntRange(16),
    default=1024,
    show_default=True,
    help="Memory budget of one forward pass; larger images are tiled with overlap.",
)
@click.option(
    "--compile",
    "compile_net",
    is_flag=True,
    help="torch.compile the network: ~30 s more for the first image (and each new size), then 0.7-0.85× the time "
    "per image; for many captures.",
)
@quiet_option()
@json_option
def apply(run, inputs, output, overwrite, device, memory_mib, compile_net, quiet, as_json):
    """Clean captures with the network of RUN: INPUT is PNG/JPEG/TIFF/EXR files or folders.

    Writes OUT/NAME.exr (linear, float32) and OUT/NAME.png (sRGB, 8-bit) per input; 8/16-bit
    inputs are taken as sRGB-encoded, EXR as linear.
    """

    from metalens_cli.cli.progress import progress_bar
    from metalens_cli.imaging.images import read_linear
    from metalens_cli.imaging.restore import load_reconstructor
    from metalens_cli.io.atomic import atomic_folder
    from metalens_cli.io.image_files import linear_to_srgb, write_exr_rgb, write_png
    from metalens_cli.io.input_files import check_image_size

    files = _inputs(inputs)
    check_output_unused(output, overwrite)
    recon = load_reconstructor(run, torch_device(device), memory_mib << 20, compile=compile_net)
    for path in files:  # a --memory-mib too small for the network's tiles: refused before any work
        recon.tile_side(*check_image_size(path, "INPUT"))
    out = Path(output)
    rows = []
    with progress_bar("reconstruct apply", quiet) as update, atomic_folder(out) as staging:  # every file or none
        for k, path in enumerate(files):
            linear = read_linear(path)
            start = time.perf_counter()
            estimate = recon(linear)
            seconds = time.perf_counter() - start
            write_exr_rgb(staging / f"{path.stem}.exr", estimate)
            write_png(staging / f"{path.stem}.png", linear_to_srgb(estimate))
            side = recon.tile_side(*linear.shape[-2:])
            rows.append(
                {
                    "input": str(path),
                    "exr": str(out / f"{path.stem}.exr"),
                    "png": str(out / f"{path.stem}.png"),
                    "height": int(linear.shape[1]),
                    "width": int(linear.shape[2]),
                    "tile_px": side,
                    "seconds": seconds,
                }
            )
            update(k + 1, len(files))
    if as_json:
        render.emit_json(
            {
                "run": str(run),
                "device": str(recon.device),
                "design": recon.design,
                "images": rows,
                "seconds_total": sum(r["seconds"] for r in rows),
            }
        )
        return
    con = render.console()
    con.print(
        render.table(
            f"Reconstructed with {run}",
            ["input", "size", "tiles", "seconds"],
            [
                [
                    r["input"],
                    f"{r['width']} × {r['height']}",
                    "—" if r["tile_px"] is None else f"{r['tile_px']} px",
                    f"{r['seconds']:.3f}",
                ]
                for r in rows
            ],
        )
    )
    con.print(f"wrote {len(rows)} × (EXR, PNG) to {out}/")


@reconstruct.command("export")
@click.argument("run", metavar="RUN")
@click.option("-o", "--output", type=OutputFile((".pt2",)), required=True, help="Exported program (.pt2).")
@click.option(
    "--tolerance",
    type=Number(0, min_open=True),
    default=1e-5,
    show_default=True,
    help="Largest absolute difference from `apply` accepted in the check.",
)
@json_option
def export(run, output, tolerance, as_json):
    """Export the network of RUN with torch.export (any image size; load with
    torch.export.load(PATH).module()(x), x a (3, H, W) float32 linear capture), then check it
    against `apply` on test captures; exit 1 if they differ by more than --tolerance.
    """
    from metalens_cli.imaging.export import export_program
    from metalens_cli.imaging.restore import load_reconstructor
    from metalens_cli.io.atomic import check_output_file

    if not str(output).endswith(".pt2"):
        raise InputError(
            "--output", f"{output!r} does not end in .pt2", "a file name ending in .pt2 (torch.export's format)"
        )
    check_output_file(output, "--output")
    recon = load_reconstructor(run)
    report = export_program(recon, output, tolerance)
    if as_json:
        render.emit_json({"run": str(run), **report})
    else:
        con = render.console()
        con.print(
            f"wrote {output} ({report['bytes']} bytes, {report['seconds']:.1f} s); max |export − apply| = "
            f"{report['max_abs_difference']:.2e} over {len(report['checked_sizes'])} sizes (tolerance {tolerance:g})"
        )
    if not report["passed"]:
        click.echo(
            f"metalens: export differs from apply by {report['max_abs_difference']:.2e} > {tolerance:g}", err=True
        )
        sys.exit(1)
