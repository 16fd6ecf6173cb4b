"""`metalens board`: a printable board of vision-task targets and its layout file."""

from __future__ import annotations

import click

from metalens_cli.cli import render
from metalens_cli.cli.options import CommaChoice, MetalensCommand, OutputFile, json_option

TASKS = ("markers", "qr", "text")  # imaging.targets.TASKS (not imported: it pulls in numpy)


@click.command("board", cls=MetalensCommand)
@click.option("-o", "--output", required=True, type=OutputFile(), help="The board image, .png or .tif.")
@click.option("--task", "tasks", type=CommaChoice(TASKS), default="markers,qr", show_default=True, help="Targets.")
@click.option("--pixels", type=click.IntRange(96, 8192), default=1024, show_default=True, help="The board's side (px).")
@click.option("--seed", type=click.IntRange(0), default=0, show_default=True, help="Places, IDs and payloads.")
@json_option
def board(output, tasks, pixels, seed, as_json):
    """A board of ArUco markers and QR codes (sizes as `evaluate --task` draws them) to print and
    photograph through each lens, and its layout, OUTPUT's NAME.targets.json. With OUTPUT in
    DIR/gt/ of a pairs folder, `evaluate --pairs DIR --task ...` scores the captures' detections
    against it, each capture registered onto the board."""
    from pathlib import Path

    from metalens_cli.imaging.targets import board as make_board
    from metalens_cli.imaging.targets import to_records
    from metalens_cli.io.atomic import atomic_files
    from metalens_cli.io.image_files import linear_to_srgb, write_encoded
    from metalens_cli.io.target_files import targets_path, write_targets

    if Path(output).suffix.lower() not in (".png", ".tif", ".tiff"):
        raise click.BadParameter("expected a path ending in .png or .tif", param_hint="--output")
    image, targets = make_board(tasks, (pixels, pixels), seed)
    layout = targets_path(Path(output))
    encoded = (linear_to_srgb(image) * 255).round().astype("uint8").transpose(1, 2, 0)
    with atomic_files(output, layout) as (image_file, layout_file):
        write_encoded(image_file, encoded)
        write_targets(layout_file, (pixels, pixels), to_records(targets))
    report = {"board": str(output), "layout": str(layout), "targets": to_records(targets)}
    if as_json:
        render.emit_json(report)
    else:
        render.console().print(f"{output}: {len(targets)} targets; layout {layout}")
