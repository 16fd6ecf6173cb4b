"""Figures of simulated captures: a contact sheet (simulate) and a designs × conditions comparison (evaluate)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from metalens_cli.plotting.common import new_figure, save_figure


def _show(ax, image, title):
    from metalens_cli.io.image_files import linear_to_srgb

    ax.imshow(
        np.transpose(linear_to_srgb(image), (1, 2, 0)) if image.shape[0] == 3 else np.clip(image[0], 0, 1),
        cmap=None if image.shape[0] == 3 else "gray",
        vmin=0,
        vmax=1,
    )
    ax.set_title(title, fontsize=8)
    ax.set_axis_off()


def _over_grey(obstruction) -> np.ndarray:
    """The obstruction composited over mid grey (where the mask is 0 nothing is drawn)."""
    rgb, mask = obstruction.sensor_rgb, obstruction.sensor_mask
    return rgb * mask + 0.5 * (1 - mask)


def obstruction_sheet(path: str | Path, rows: list[tuple[str, list]]) -> Path:
    """One row per depth label, one column per obstruction (``rows``: [(label, [Obstruction…])])."""
    cols = max(len(obstructions) for _, obstructions in rows)
    fig, axes = new_figure(len(rows), cols, figsize=(2.6 * cols, 2.8 * len(rows)), squeeze=False)
    for row, (label, obstructions) in zip(axes, rows):
        for ax in row:
            ax.set_axis_off()
        for ax, o in zip(row, obstructions):
            _show(ax, _over_grey(o), f"{o.kind} at {label} ({100 * o.coverage:.0f} %)")
    return save_figure(fig, path)


def contact_sheet(path: str | Path, captures) -> Path:
    """One row per image: clean, obstruction (over grey), α (R channel), unobstructed, obstructed."""
    rows = len(captures)
    fig, axes = new_figure(rows, 5, figsize=(12, 2.6 * rows), squeeze=False)
    for row, c in zip(axes, captures):
        _show(row[0], c.clean, f"{c.name}: clean")
        _show(row[1], _over_grey(c.obstruction), f"{c.obstruction.kind} ({100 * c.obstruction.coverage:.0f} %)")
        _show(row[2], np.clip(c.alpha[:1], 0, 1) ** (1 / 2.2), "α (R, γ 2.2)")
        _show(row[3], c.unobstructed, "unobstructed")
        _show(row[4], c.obstructed, "obstructed")
    return save_figure(fig, path)


def comparison_figure(path: str | Path, designs: list[str], panels: dict) -> Path:
    """Rows: designs; columns: clean, unobstructed, then obstructed per obstruction.

    ``panels[design]`` is a list of (title, (3, H, W) linear image)."""
    cols = max(len(p) for p in panels.values())
    fig, axes = new_figure(len(designs), cols, figsize=(2.6 * cols, 2.7 * len(designs)), squeeze=False)
    for row, design in zip(axes, designs):
        for ax in row:
            ax.set_axis_off()
        for ax, (title, image) in zip(row, panels[design]):
            _show(ax, image, title)
        row[0].set_title(f"{design}\n{row[0].get_title()}", fontsize=8)
    return save_figure(fig, path)
