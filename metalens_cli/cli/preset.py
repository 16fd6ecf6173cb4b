"""`metalens preset show`: the resolved configuration of a preset (SI units)."""

from __future__ import annotations

from pathlib import Path

import click

from metalens_cli.cli import render
from metalens_cli.cli.options import MetalensGroup, json_option
from metalens_cli.io.presets import load_preset, read_toml, to_dict


@click.group(cls=MetalensGroup)
def preset():
    """Inspect presets."""


@preset.command()
@click.argument("file", type=click.Path(dir_okay=False))
@json_option
def show(file, as_json):
    """Validate FILE and print its resolved configuration (metres, fractions): a camera preset
    (optimize, --preset) or, with a [train] section, a reconstruction preset."""
    from metalens_cli.io.reconstruct_presets import load_reconstruct_preset

    load = load_reconstruct_preset if "train" in read_toml(Path(file)) else load_preset
    resolved = to_dict(load(file))
    if as_json:
        render.emit_json(resolved)
        return
    con = render.console()
    con.print(f"[bold]{resolved['name']}[/]: {resolved['description']}")
    for section, values in resolved.items():
        if isinstance(values, dict):
            con.print(render.table(section, ["key", "value"], [[k, _text(v)] for k, v in values.items()]))
        elif values is None and section == "filter":
            con.print("filter: none (no multi-band filter)")


def _text(value) -> str:
    if isinstance(value, list):
        return ", ".join(_text(v) for v in value)
    if isinstance(value, float):
        return f"{value:.6g}"
    return "inf" if value is None else str(value)
