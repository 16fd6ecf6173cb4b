"""Figures of MTFs: frequency × wavelength heatmaps per depth (paper Suppl. Note 13), near vs far
curves with the diffraction limit and the Nyquist line, MTF50 against field angle (tangential and
sagittal) for a field cube, and slanted-edge SFRs per channel."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from metalens_cli.analysis.mtf import DIRECTIONS, RGB_NAMES, CubeMtf, diffraction_mtf
from metalens_cli.analysis.slanted_edge import EdgeAnalysis
from metalens_cli.plotting.common import depth_label, new_figure, save_figure

CHANNEL_COLOURS = {"R": "tab:red", "G": "tab:green", "B": "tab:blue", "Y": "black"}
CURVE_WAVELENGTHS = 4  # wavelengths drawn as curves, spread over the cube's range
DIRECTION_STYLES = {"tangential": "-", "sagittal": "--"}


def plot_cube_mtf(path: str | Path, result: CubeMtf) -> Path:
    """Top: MTF over (frequency, wavelength) for each depth, the MTF50 drawn in white. Bottom
    left: curves for a few wavelengths, nearest depth dashed, farthest solid, the analytic
    diffraction limit dotted (to its cutoff 2·NA/λ) and the Nyquist line; bottom right: the
    R, G, B channel curves when the cube has them."""
    depths = result.depths_m.size
    fig, axes = new_figure(2, max(depths, 2), figsize=(4.2 * max(depths, 2), 7.5), squeeze=False, layout="constrained")
    freqs, wl_nm = result.frequencies_lpmm, result.wavelengths_m * 1e9
    for i, z in enumerate(result.depths_m):
        ax = axes[0, i]
        mesh = ax.pcolormesh(freqs, wl_nm, result.mtf[i], shading="nearest", cmap="viridis", vmin=0, vmax=1)
        ax.plot(result.mtf50_lpmm[i], wl_nm, color="w", lw=1, label="MTF50")
        ax.set_title(f"MTF, {depth_label(z)}", fontsize=9)
        ax.set_xlabel("frequency (lp/mm)")
        ax.set_ylabel("wavelength (nm)")
        ax.legend(fontsize=7, loc="upper right")
    fig.colorbar(mesh, ax=list(axes[0, :depths]), label="MTF", shrink=0.9)
    for ax in axes[0, depths:]:
        ax.axis("off")
    _wavelength_curves(axes[1, 0], result)
    if result.rgb_mtf is None:
        axes[1, 1].axis("off")
    else:
        _channel_curves(axes[1, 1], result)
    for ax in axes[1, 2:]:
        ax.axis("off")
    return save_figure(fig, path)


def plot_field_mtf50(path: str | Path, result: CubeMtf) -> Path:
    """MTF50 against field angle (the lens-design figure) of a field cube's MTFs, one panel per
    depth: tangential solid, sagittal dashed, one colour per R, G, B channel (for a few
    wavelengths when the cube has no channels); the Nyquist frequency dash-dotted. A missing point
    is an MTF that stays above 0.5 up to Nyquist."""
    field = result.field
    depths = result.depths_m.size
    fig, axes = new_figure(1, depths, figsize=(4.6 * depths, 3.8), squeeze=False, layout="constrained")
    order = np.argsort(field.angles_rad)
    degrees = np.degrees(field.angles_rad[order])
    if field.rgb_tangential is not None:
        series = [(name, CHANNEL_COLOURS[name], c, True) for c, name in enumerate(RGB_NAMES)]
    else:
        series = [
            (f"{result.wavelengths_m[j] * 1e9:.0f} nm", colour, j, False) for colour, j in _wavelength_choice(result)
        ]
    for i, z in enumerate(result.depths_m):
        ax = axes[0, i]
        missing = False
        for label, colour, j, channel in series:
            for direction in DIRECTIONS:
                values = field.mtf50(direction, channel)[order, i, j]
                missing |= bool(np.isnan(values).any())
                ax.plot(
                    degrees,
                    values,
                    color=colour,
                    ls=DIRECTION_STYLES[direction],
                    marker="o",
                    ms=3,
                    label=label if direction == "tangential" else None,
                )
        ax.axhline(result.nyquist_lpmm, color="0.4", lw=0.8, ls="-.", label="Nyquist")
        for direction, style in DIRECTION_STYLES.items():
            ax.plot([], [], color="0.3", ls=style, label=direction)
        note = "\nmissing points: MTF above 0.5 up to Nyquist" if missing else ""
        ax.set_title(f"MTF50 over the field, {depth_label(z)}{note}", fontsize=9)
        ax.set_xlabel(f"field angle (°), azimuth {np.degrees(field.azimuth_rad):.3g}°")
        ax.set_ylabel("MTF50 (lp/mm)" + (" (pixel MTF removed)" if result.pixel_mtf_removed else ""))
        ax.set_xlim(0, max(degrees[-1] * 1.05, 1.0))
        ax.set_ylim(0, result.nyquist_lpmm * 1.05)
        ax.legend(fontsize=7, loc="best")
    return save_figure(fig, path)


def _wavelength_choice(result: CubeMtf) -> list[tuple[np.ndarray, int]]:
    """(colour, wavelength index) of at most CURVE_WAVELENGTHS wavelengths spread over the cube's."""
    import matplotlib

    chosen = np.unique(np.linspace(0, result.wavelengths_m.size - 1, CURVE_WAVELENGTHS).round().astype(int))
    colours = matplotlib.colormaps["turbo"](np.linspace(0.05, 0.95, chosen.size))
    return list(zip(colours, chosen.tolist()))


def _wavelength_curves(ax, result: CubeMtf) -> None:
    """MTF curves of a few wavelengths, near (dashed) and far (solid), with references."""
    near, far = int(np.argmin(result.depths_m)), int(np.argmax(result.depths_m))
    for colour, j in _wavelength_choice(result):
        label = f"{result.wavelengths_m[j] * 1e9:.0f} nm"
        ax.plot(result.frequencies_lpmm, result.mtf[far, j], color=colour, label=label)
        if near != far:
            ax.plot(result.frequencies_lpmm, result.mtf[near, j], color=colour, ls="--")
        if result.na is not None:
            cutoff_lpmm = 2 * result.na / result.wavelengths_m[j] * 1e-3
            fine = np.linspace(0, cutoff_lpmm, 200)
            ax.plot(fine, diffraction_mtf(fine * 1e3, result.na, result.wavelengths_m[j]), color=colour, ls=":", lw=1)
    _references(ax, result)
    styles = f"solid {depth_label(result.depths_m[far])}" + (
        f", dashed {depth_label(result.depths_m[near])}" if near != far else ""
    )
    extra = f"\ndotted: diffraction limit, NA {result.na:.3g}" if result.na is not None else ""
    ax.set_title(f"MTF per wavelength ({styles}){extra}", fontsize=8)
    ax.legend(fontsize=7, loc="upper right")


def _channel_curves(ax, result: CubeMtf) -> None:
    """R, G, B channel MTFs, near (dashed) and far (solid)."""
    near, far = int(np.argmin(result.depths_m)), int(np.argmax(result.depths_m))
    for c, name in enumerate(RGB_NAMES):
        ax.plot(result.frequencies_lpmm, result.rgb_mtf[far, c], color=CHANNEL_COLOURS[name], label=name)
        if near != far:
            ax.plot(result.frequencies_lpmm, result.rgb_mtf[near, c], color=CHANNEL_COLOURS[name], ls="--")
    _references(ax, result)
    ax.set_title("MTF per colour channel (solid far, dashed near)", fontsize=8)
    ax.legend(fontsize=7, loc="upper right")


def _references(ax, result: CubeMtf) -> None:
    """Nyquist line, pixel-aperture MTF (when included in the curves), axis labels."""
    ax.axvline(result.nyquist_lpmm, color="0.4", lw=0.8, ls="-.", label="Nyquist")
    if not result.pixel_mtf_removed:
        ax.plot(result.frequencies_lpmm, result.pixel_mtf, color="0.6", lw=0.8, label="pixel aperture")
    ax.set_ylim(0, 1.05)
    ax.set_xlim(left=0)
    ax.set_xlabel("frequency (lp/mm)")
    ax.set_ylabel("MTF" + (" (pixel MTF removed)" if result.pixel_mtf_removed else ""))


def plot_edge_sfr(path: str | Path, analysis: EdgeAnalysis, pixel_pitch_m: float | None = None) -> Path:
    """SFR per channel against cycles/pixel (lp/mm on a top axis with a pixel pitch), MTF50
    marked, the pixel Nyquist 0.5 cycle/pixel drawn."""
    fig, ax = new_figure(figsize=(6.5, 4.2), layout="constrained")
    for sfr in analysis.channels:
        colour = CHANNEL_COLOURS.get(sfr.channel, "black")
        ax.plot(sfr.frequencies_cy_per_px, sfr.mtf, color=colour, label=f"{sfr.channel} (tilt {sfr.angle_deg:.2f}°)")
        if np.isfinite(sfr.mtf50_cy_per_px):
            ax.plot(sfr.mtf50_cy_per_px, 0.5, "o", ms=4, color=colour)
    ax.axvline(0.5, color="0.4", lw=0.8, ls="-.", label="Nyquist")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.05)
    ax.set_xlabel("frequency (cycles/pixel)")
    ax.set_ylabel("SFR")
    if pixel_pitch_m is not None:
        scale = 1 / (pixel_pitch_m * 1e3)
        top = ax.secondary_xaxis("top", functions=(lambda f: f * scale, lambda f: f / scale))
        top.set_xlabel(f"frequency (lp/mm, pitch {pixel_pitch_m * 1e6:g} µm)")
    x, y, w, h = analysis.roi
    ax.set_title(f"Slanted-edge SFR ({analysis.orientation} edge, ROI {x},{y},{w},{h}; dots: MTF50)", fontsize=9)
    ax.legend(fontsize=8)
    return save_figure(fig, path)
