"""`metalens obstruction preview`: a sheet of generated obstructions as the sensor sees them."""

from __future__ import annotations

import click

from metalens_cli.cli import render
from metalens_cli.cli.options import (
    Length,
    LengthList,
    MetalensGroup,
    OutputFile,
    flatten,
    json_option,
    load_preset_option,
    preset_option,
)
from metalens_cli.constants import OBSTRUCTION_KINDS, PAPER_FOCAL_LENGTH_M
from metalens_cli.errors import InputError

DEFAULT_KINDS = ",".join(OBSTRUCTION_KINDS)


MAX_ROWS = 16  # depths on one preview sheet


@click.group(cls=MetalensGroup)
def obstruction():
    """Obstruction generators."""


@obstruction.command()
@preset_option
@click.option(
    "--kinds",
    default=DEFAULT_KINDS,
    show_default=True,
    help="Comma-separated: dirt, fence, drops, rain, file:PATH.png.",
)
@click.option(
    "--z-near",
    "depths",
    type=LengthList(),
    multiple=True,
    help="Depths on the cover glass, e.g. 40mm,50mm [preset's z_near range ends, else 45mm].",
)
@click.option("--f", "f_m", type=Length(), help="Focal length [preset's, else 4mm].")
@click.option("--pixels", type=click.IntRange(16, 4096), help="Sensor N × N [preset's, else 512].")
@click.option("--pixel-pitch", "pixel_pitch_m", type=Length(), help="Pixel pitch [preset's, else 1.85um].")
@click.option("--seed", type=click.IntRange(0), default=0, show_default=True)
@click.option("-o", "--output", type=OutputFile((".png",)), required=True, help="Sheet PNG.")
@json_option
def preview(preset_path, kinds, depths, f_m, pixels, pixel_pitch_m, seed, output, as_json):
    """Write a sheet of example obstructions (rows: depths; columns: kinds) with their coverage.

    Sizes are set in metres on the cover glass (preset's [obstruction]) and scale as f/z/pitch.
    """
    from metalens_cli.imaging.images import load_images
    from metalens_cli.imaging.obstructions import make_obstruction, parse_obstructions
    from metalens_cli.io.units import format_length
    from metalens_cli.plotting.imaging import obstruction_sheet

    preset = load_preset_option(preset_path)
    f_m = f_m or (preset.lens.focal_length_m if preset else PAPER_FOCAL_LENGTH_M)
    pixels = pixels or (preset.sensor.pixels if preset else 512)
    pixel_pitch_m = pixel_pitch_m or (preset.sensor.pixel_pitch_m if preset else 1.85e-6)
    depths_m = flatten(depths) or (sorted(set(preset.scene.z_near_m)) if preset else [0.045])
    if len(depths_m) > MAX_ROWS:
        raise InputError(
            "--z-near", f"{len(depths_m)} depths; a sheet shows at most {MAX_ROWS} rows", f"at most {MAX_ROWS} depths"
        )
    params = preset.obstruction if preset else None
    clean = load_images("photos", (pixels, pixels), limit=1)[0].linear  # rain refracts a scene
    rows = []
    for depth in depths_m:
        made = [
            make_obstruction(kind, (pixels, pixels), depth, f_m, pixel_pitch_m, seed, params=params, clean=clean)
            for kind in parse_obstructions(kinds)
        ]
        rows.append((format_length(depth), made))
    obstruction_sheet(output, rows)
    report = {
        "file": str(output),
        "seed": seed,
        "f_m": f_m,
        "pixel_pitch_m": pixel_pitch_m,
        "pixels": pixels,
        "obstructions": [
            {"kind": o.kind, "depth_m": o.depth_m, "coverage": o.coverage} for _, made in rows for o in made
        ],
    }
    if as_json:
        render.emit_json(report)
    else:
        con = render.console()
        con.print(
            render.table(
                "Obstructions",
                ["kind", "depth", "coverage"],
                [
                    [o["kind"], format_length(o["depth_m"]), f"{100 * o['coverage']:.1f} %"]
                    for o in report["obstructions"]
                ],
            )
        )
        con.print(f"wrote {output}")
