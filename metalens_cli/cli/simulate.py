"""`metalens simulate`: captures of clean images through a design with a near obstruction."""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING

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
    quiet_option,
    torch_device,
)
from metalens_cli.cli.progress import efficiency_used, progress_bar
from metalens_cli.errors import InputError

if TYPE_CHECKING:
    from metalens_cli.imaging.pipeline import CaptureSetup


class Photons(Number):
    """A full well in electrons: 0 (no shot noise) or at least 1."""

    def convert(self, value, param, ctx):
        """The full well in electrons (float): 0, or from 1 to the range's maximum; a value between
        0 and 1, out of range or not finite fails with the accepted form."""
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
        click.option(
            "--field",
            "field_model",
            type=click.Choice(("on-axis", "auto")),
            default="on-axis",
            show_default=True,
            help="on-axis: one PSF per depth everywhere; auto: PSFs that vary over the field where the sensor spans "
            "more than the lens's isoplanatic patch (minutes per design and depths on 2 CPU cores, then cached).",
        ),
        click.option(
            "--field-tolerance",
            type=Number(0, 1, min_open=True, max_open=True),
            default=0.01,  # field_formation.DEFAULT_TOLERANCE (not imported: it pulls in torch)
            show_default=True,
            help="With --field auto: the space-variant formation's relative L2 error of the PSF field (that of a "
            "white-noise scene, a bound for photographs); larger is faster and needs less memory.",
        ),
        click.option(
            "--halo-scale",
            type=click.IntRange(1, 31),
            default=1,
            show_default=True,
            help="Convolve each PSF's halo in blocks of up to N × N pixels (odd; at most the window/200) around a "
            "65-pixel core at the sensor's pixels: 512² captures 3-10× faster, within 2e-3 relative L2 and 0.002 dB "
            "of PSNR of the single-scale capture (docs/benchmarks.md); 1: one scale, exact.",
        ),
        click.option("--photons", type=Photons(0, 1e15), help="Full-well electrons for shot noise (0/absent: none)."),
        click.option("--read-noise", type=Number(0, 1), default=0.0, help="Read-noise σ as a fraction of full scale."),
        device_option,
    ]
    return geometry_options(apply_options(f, options))


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
    from metalens_cli.imaging.pipeline import DEFAULT_WAVELENGTHS, DEFAULT_Z_FAR_M, DEFAULT_Z_NEAR_M, CaptureSetup
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


# the parameters of capture_options that setup() resolves
SETUP_OPTIONS = (
    "preset_path",
    "f_m",
    "aperture_m",
    "pitch_m",
    "z_near_m",
    "z_far_m",
    "pixels",
    "pixel_pitch_m",
    "wavelengths",
    "device",
)


def setup_from(spec_list, params: dict) -> CaptureSetup:
    """:func:`setup` of the designs ``spec_list`` with the values of a command's
    :func:`capture_options` among its ``params`` (``click.Context.params``)."""
    return setup(spec_list, **{name: params[name] for name in SETUP_OPTIONS})


@click.command("simulate", cls=MetalensCommand)
@click.argument("spec", metavar="DESIGN")
@capture_options
@click.option(
    "--seed", type=click.IntRange(0), default=0, show_default=True, help="Seed of depths, obstructions and noise."
)
@click.option("--obstruction", default="dirt", show_default=True, help="dirt, fence, drops, rain or file:PATH.png.")
@click.option("-o", "--output", type=OutputFolder(), required=True, help="Output folder (created).")
@overwrite_option
@quiet_option()
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
    field_model,
    field_tolerance,
    halo_scale,
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
    from metalens_cli.imaging.pipeline import capture_psfs, draw_depths, estimate_capture_runs, simulate_captures
    from metalens_cli.imaging.simulation_output import simulation_report, write_captures
    from metalens_cli.io.atomic import atomic_folder
    from metalens_cli.io.json_files import write_json
    from metalens_cli.optics.two_scale import halo_sampling
    from metalens_cli.plotting.imaging import contact_sheet

    start = time.perf_counter()
    check_output_unused(output, overwrite)
    (kind,) = _single(parse_obstructions(obstruction))
    s = setup_from([spec], click.get_current_context().params)
    design = s.designs[0]
    depths = draw_depths(s.z_near_interval_m, s.z_far_interval_m, seed)
    what = f"simulate on {s.pixels}² pixels"
    estimate = estimate_capture_runs(
        s, what, depths, image_count(images, limit), window=psf_pixels, field_model=field_model
    )
    announce(estimate, max_memory, device=s.device)
    efficiency = efficiency_used(design.preset, quiet)
    psfs = capture_psfs(
        design, *depths, s.wavelengths_m, s.pixel_pitch_m, s.pixels, field_model=field_model, device=s.device,
        window=psf_pixels, field_tolerance=field_tolerance, two_scale=halo_sampling(halo_scale),
    )  # fmt: skip
    clean = load_images(images, (s.pixels, s.pixels), limit, psfs.margin)
    formation_options = dict(formation=formation, alpha_gain=alpha_gain, photons=photons, read_noise=read_noise)
    with progress_bar("simulate", quiet) as update:
        captures = simulate_captures(
            clean,
            kind,
            psfs,
            design.focal_length_m,
            s.pixel_pitch_m,
            seed,
            params=s.obstruction_params,
            **formation_options,
            on_progress=update,
        )
    out = Path(output)
    with atomic_folder(out) as staging:  # the folder gets every file or none (failure, Ctrl-C, SIGTERM)
        names = [*write_captures(staging, captures), "contact_sheet.png"]
        contact_sheet(staging / names[-1], captures)
        files = [str(out / name) for name in names]
        total = time.perf_counter() - start
        report = simulation_report(
            s, kind, seed, psfs, captures, formation_options, efficiency=efficiency, files=files, seconds=total
        )
        write_json(staging / "simulate.json", report)
    render.say(report["warnings"])
    if as_json:
        render.emit_json(report)
        return
    _render(report, design.spec, kind, psfs, out)


def _render(report: dict, spec: str, kind: str, psfs, out: Path) -> None:
    """The table of images (obstruction and α coverage, seconds), the PSF windows, the file count."""
    con = render.console()
    rows = [
        [i["name"], f"{100 * i['obstruction_coverage']:.1f}", f"{100 * i['alpha_coverage']:.1f}", f"{i['seconds']:.2f}"]
        for i in report["images"]
    ]
    con.print(
        render.table(
            f"simulate {spec}: {kind} at {psfs.z_near_m * 1e3:.1f} mm, scene at {psfs.z_far_m:.2f} m",
            ["image", "obstruction %", "α %", "s"],
            rows,
        )
    )
    con.print(kept_line(psfs))
    con.print(f"wrote {len(report['files']) + 1} files to {out}")


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
