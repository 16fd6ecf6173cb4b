"""`metalens simulate`: captures of clean images through a design with a near obstruction."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import click

from metalens_cli.cli import render
from metalens_cli.cli.options import (
    Interval,
    Length,
    MetalensCommand,
    Number,
    OutputFolder,
    WavelengthList,
    announce,
    apply_options,
    check_output_unused,
    device_option,
    flatten,
    geometry_options,
    json_option,
    load_preset_option,
    max_memory_option,
    overwrite_option,
    torch_device,
)
from metalens_cli.cli.progress import efficiency_used, progress_bar
from metalens_cli.errors import InputError


class Photons(Number):
    """A full well in electrons: 0 (no shot noise) or at least 1."""

    def convert(self, value, param, ctx):
        electrons = super().convert(value, param, ctx)
        if 0 < electrons < 1:
            self.fail(f"{value!r} electrons (expected 0 for no shot noise, or at least 1)", param, ctx)
        return electrons


FORMATIONS = ("physical", "paper")  # imaging.formation.FORMATIONS (not imported: it pulls in torch)

DEFAULT_PIXELS, DEFAULT_PIXEL_PITCH_M = 512, 1.85e-6  # the paper's sensor


def capture_options(f):
    """Options shared by simulate and evaluate: geometry, sensor, depths, PSF sampling, device."""
    options = [
        click.option(
            "--images",
            default="photos",
            show_default=True,
            help="photos (the photographs scikit-image and matplotlib ship), charts (dead-leaves), all, "
            "a folder of PNG/JPEG/TIFF/EXR images, or one file.",
        ),
        click.option("--limit", type=click.IntRange(1), help="Use at most this many images."),
        click.option(
            "--z-near",
            "z_near_m",
            type=Interval(),
            help="Obstruction depth or interval, e.g. 45mm or 40mm:50mm [preset's, else 40mm:50mm].",
        ),
        click.option(
            "--z-far",
            "z_far_m",
            type=Interval(),
            help="Scene depth or interval, e.g. 1m or 1m:20m [preset's, else 1m:20m].",
        ),
        click.option("--pixels", type=click.IntRange(16, 8192), help="Sensor N × N [preset's, else 512]."),
        click.option(
            "--psf-pixels",
            type=click.IntRange(3, 8192),
            help="Force one PSF window size for both depths [from the optics: the window that holds the light].",
        ),
        click.option(
            "--pixel-pitch", "pixel_pitch_m", type=Length(), help="Sensor pixel pitch [preset's, else 1.85um]."
        ),
        click.option(
            "--wavelengths",
            type=WavelengthList(),
            multiple=True,
            help="PSF wavelengths mixed into R, G, B [400:700:5nm].",
        ),
        click.option(
            "--formation",
            type=click.Choice(FORMATIONS),
            default="physical",
            show_default=True,
            help="physical: obstruction light P̂_near ∗ (m ⊙ I_obs); paper: the paper's α ⊙ (P̂_near ∗ I_obs).",
        ),
        click.option(
            "--alpha-gain", type=Number(0, min_open=True), help="Gain-and-clamp α = min(g·α, 1) (Shi et al.)."
        ),
        click.option("--photons", type=Photons(0, 1e15), help="Full-well electrons for shot noise (0/absent: none)."),
        click.option("--read-noise", type=Number(0, 1), default=0.0, help="Read-noise σ as a fraction of full scale."),
        device_option,
    ]
    return geometry_options(apply_options(f, options))


@dataclass(frozen=True)
class CaptureSetup:
    """What simulate, evaluate and reconstruct train capture with (SI metres): the designs, the
    sensor crop, the depth intervals [lo, hi], the wavelengths integrated over, the torch device
    and the obstruction parameters in force (None: the defaults)."""

    designs: list
    pixels: int
    pixel_pitch_m: float
    z_near_interval_m: tuple[float, float]
    z_far_interval_m: tuple[float, float]
    wavelengths_m: list[float]
    device: object  # torch.device
    obstruction_params: object | None  # io.presets.ObstructionConfig


def setup(
    spec_list,
    *,
    preset_path,
    f_m,
    aperture_m,
    pitch_m,
    z_near_m,
    z_far_m,
    pixels,
    pixel_pitch_m,
    wavelengths,
    device,
    design_field="DESIGN",
) -> CaptureSetup:
    """Resolve designs, sensor, depth intervals and wavelengths (shared by simulate, evaluate and
    reconstruct train); a malformed design is refused naming ``design_field`` (their positional
    DESIGN argument), not resolve_design's ``--design``."""
    from metalens_cli.imaging.pipeline import DEFAULT_WAVELENGTHS, DEFAULT_Z_FAR_M, DEFAULT_Z_NEAR_M
    from metalens_cli.io.designs import resolve_design
    from metalens_cli.io.units import parse_length_list

    preset = load_preset_option(preset_path)
    try:
        designs = [resolve_design(spec, preset, f_m=f_m, aperture_m=aperture_m, pitch_m=pitch_m) for spec in spec_list]
    except InputError as exc:
        if exc.field != "--design":
            raise
        raise InputError(design_field, exc.message, exc.expected) from None
    in_force = preset or designs[0].preset
    sensor = in_force.sensor if in_force is not None else None
    scene = in_force.scene if in_force is not None else None
    z_near = z_near_m or (scene.z_near_m if scene else DEFAULT_Z_NEAR_M)
    z_far = z_far_m or (scene.z_far_m if scene else DEFAULT_Z_FAR_M)
    waves = flatten(wavelengths) or parse_length_list(DEFAULT_WAVELENGTHS, "--wavelengths")
    return CaptureSetup(
        designs=designs,
        pixels=pixels or (sensor.pixels if sensor else DEFAULT_PIXELS),
        pixel_pitch_m=pixel_pitch_m or (sensor.pixel_pitch_m if sensor else DEFAULT_PIXEL_PITCH_M),
        z_near_interval_m=tuple(z_near),
        z_far_interval_m=tuple(z_far),
        wavelengths_m=waves,
        device=torch_device(device),
        obstruction_params=in_force.obstruction if in_force is not None else None,
    )


@click.command("simulate", cls=MetalensCommand)
@click.argument("spec", metavar="DESIGN")
@capture_options
@click.option(
    "--seed", type=click.IntRange(0), default=0, show_default=True, help="Seed of depths, obstructions and noise."
)
@click.option("--obstruction", default="dirt", show_default=True, help="dirt, fence, drops, rain or file:PATH.png.")
@click.option("-o", "--output", type=OutputFolder(), required=True, help="Output folder (created).")
@overwrite_option
@click.option("--quiet", is_flag=True, help="No progress bar.")
@max_memory_option
@json_option
def simulate(
    spec,
    preset_path,
    f_m,
    aperture_m,
    pitch_m,
    images,
    limit,
    z_near_m,
    z_far_m,
    pixels,
    psf_pixels,
    pixel_pitch_m,
    wavelengths,
    formation,
    alpha_gain,
    photons,
    read_noise,
    device,
    seed,
    obstruction,
    output,
    overwrite,
    quiet,
    max_memory,
    as_json,
):
    """Simulated captures of clean images through DESIGN with a near obstruction.

    Writes, per image, the clean scene and the unobstructed and obstructed captures (PNG for
    viewing, linear EXR), the obstruction and α maps, a contact sheet and simulate.json.
    """
    from metalens_cli.imaging.images import image_count, load_images
    from metalens_cli.imaging.obstructions import parse_obstructions
    from metalens_cli.imaging.pipeline import channel_psfs, draw_depths, estimate_captures, simulate_captures
    from metalens_cli.io.resources import Estimate

    start = time.perf_counter()
    check_output_unused(output, overwrite)
    (kind,) = _single(parse_obstructions(obstruction))
    s = setup(
        [spec],
        preset_path=preset_path,
        f_m=f_m,
        aperture_m=aperture_m,
        pitch_m=pitch_m,
        z_near_m=z_near_m,
        z_far_m=z_far_m,
        pixels=pixels,
        pixel_pitch_m=pixel_pitch_m,
        wavelengths=wavelengths,
        device=device,
    )
    design = s.designs[0]
    z_near, z_far = draw_depths(s.z_near_interval_m, s.z_far_interval_m, seed)
    memory, psf_seconds, capture_seconds = estimate_captures(
        design,
        z_near,
        z_far,
        s.wavelengths_m,
        s.pixel_pitch_m,
        s.pixels,
        image_count(images, limit),
        window=psf_pixels,
    )
    announce(
        Estimate(
            f"simulate on {s.pixels}² pixels",
            memory,
            "--psf-pixels" if psf_pixels else "--pixels",
            psf_seconds + capture_seconds,
        ),
        max_memory,
        device=s.device,
    )
    efficiency = efficiency_used(design.preset, quiet)
    psfs = channel_psfs(design, z_near, z_far, s.wavelengths_m, s.pixel_pitch_m, device=s.device, window=psf_pixels)
    clean = load_images(images, (s.pixels, s.pixels), limit, psfs.margin)
    with progress_bar("simulate", quiet) as update:
        captures = simulate_captures(
            clean,
            kind,
            psfs,
            design.focal_length_m,
            s.pixel_pitch_m,
            seed,
            params=s.obstruction_params,
            formation=formation,
            alpha_gain=alpha_gain,
            photons=photons,
            read_noise=read_noise,
            on_progress=update,
        )
    import json

    from metalens_cli.io.atomic import atomic_folder
    from metalens_cli.plotting.imaging import contact_sheet

    out = Path(output)
    with atomic_folder(out) as staging:  # the folder gets every file or none (failure, Ctrl-C, SIGTERM)
        names = write_captures(staging, captures)
        contact_sheet(staging / "contact_sheet.png", captures)
        files = [str(out / name) for name in [*names, "contact_sheet.png"]]
        warnings = psfs.warnings()
        report = render.jsonable(
            {
                "design": design.describe(),
                "obstruction": kind,
                "seed": seed,
                "z_near_m": z_near,
                "z_far_m": z_far,
                "z_near_interval_m": list(s.z_near_interval_m),
                "z_far_interval_m": list(s.z_far_interval_m),
                "pixels": s.pixels,
                "pixel_pitch_m": s.pixel_pitch_m,
                "canvas_margin_px": psfs.margin,
                "wavelengths_m": s.wavelengths_m,
                "formation": formation,
                "alpha_gain": alpha_gain,
                "photons": photons,
                "read_noise": read_noise,
                "device": str(s.device),
                **psfs.report(),
                "spectral_coverage": dict(zip("RGB", psfs.coverage)),
                "efficiency": efficiency,
                "images": [
                    {
                        "name": c.name,
                        "obstruction_coverage": c.obstruction.coverage,
                        "alpha_coverage": c.alpha_coverage,
                        "obstruction_settings": c.obstruction.settings,
                        "seconds": c.seconds,
                    }
                    for c in captures
                ],
                "timing_s": {
                    "psf": psfs.seconds,
                    "captures": sum(c.seconds for c in captures),
                    "total": time.perf_counter() - start,
                },
                "warnings": warnings,
                "files": files,
            }
        )
        (staging / "simulate.json").write_text(json.dumps(report, indent=2, allow_nan=False) + "\n", encoding="utf-8")
    render.say(warnings)
    if as_json:
        render.emit_json(report)
        return
    con = render.console()
    rows = [
        [i["name"], f"{100 * i['obstruction_coverage']:.1f}", f"{100 * i['alpha_coverage']:.1f}", f"{i['seconds']:.2f}"]
        for i in report["images"]
    ]
    con.print(
        render.table(
            f"simulate {design.spec}: {kind} at {z_near * 1e3:.1f} mm, scene at {z_far:.2f} m",
            ["image", "obstruction %", "α %", "s"],
            rows,
        )
    )
    con.print(kept_line(psfs))
    con.print(f"wrote {len(files) + 1} files to {out}")


def kept_line(psfs) -> str:
    """One line: PSF windows and the fraction of the light each kept, per channel."""
    return (
        f"PSF windows near {psfs.near.shape[-1]} px, far {psfs.far.shape[-1]} px; light kept (R, G, B): near "
        + ", ".join(f"{e:.4f}" for e in psfs.kept_near)
        + "; far "
        + ", ".join(f"{e:.4f}" for e in psfs.kept_far)
    )


def _single(specs):
    if len(specs) != 1:
        raise InputError(
            "--obstruction", f"{len(specs)} obstructions", "one obstruction for simulate (evaluate takes a list)"
        )
    return specs


def write_captures(out: Path, captures) -> list[str]:
    """PNG (sRGB) and linear EXR of clean, unobstructed and obstructed; obstruction and α maps.
    Returns the file names written in ``out``."""
    import numpy as np

    from metalens_cli.io.image_files import linear_to_srgb, write_exr_rgb, write_png

    files = []
    for c in captures:
        grey = np.full_like(c.clean, 0.5)
        mask = c.obstruction.sensor_mask
        composite = c.obstruction.sensor_rgb * mask + grey * (1 - mask)
        for label, image in (("clean", c.clean), ("unobstructed", c.unobstructed), ("obstructed", c.obstructed)):
            write_png(out / f"{c.name}_{label}.png", linear_to_srgb(image))
            write_exr_rgb(out / f"{c.name}_{label}.exr", image)
            files += [f"{c.name}_{label}.png", f"{c.name}_{label}.exr"]
        write_png(out / f"{c.name}_obstruction.png", linear_to_srgb(composite))
        write_png(out / f"{c.name}_alpha.png", np.clip(c.alpha, 0, 1))
        write_exr_rgb(out / f"{c.name}_obstruction_mask.exr", mask)
        write_exr_rgb(out / f"{c.name}_alpha.exr", c.alpha)
        files += [f"{c.name}_{x}" for x in ("obstruction.png", "alpha.png", "obstruction_mask.exr", "alpha.exr")]
    return files
