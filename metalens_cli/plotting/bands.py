"""Band diagram: pass/stop bands over wavelength, their depth-wavelength curves and z_near."""

from __future__ import annotations

from pathlib import Path

from metalens_cli.analysis.bands import BandsReport
from metalens_cli.plotting.common import new_figure, save_figure

BAND_COLOURS = {"B": "#3b6fd8", "G": "#2e9b4f", "R": "#d8453b"}


def plot_bands(path: str | Path, report: BandsReport) -> Path:
    """Each pass band edge λe focuses from depth z at λe(1 + f/z): draw those curves (log z),
    the pass bands (coloured) and stop bands (grey), z_near, and the shifted bands there."""
    lo, hi = report.sensor_range_m
    f = report.f_m
    z_lo, z_hi = report.z_near_m
    fig, ax = new_figure(figsize=(7, 4.5))
    ax.axvspan(lo * 1e9, hi * 1e9, color="0.85", zorder=0, label="stop band")
    depths = [10 ** (-3 + 4.7 * i / 399) for i in range(400)]  # 1 mm to 50 m
    for i, band in enumerate(report.bands):
        colour = BAND_COLOURS.get(band.label, f"C{i}")
        ax.axvspan(band.lo_m * 1e9, band.hi_m * 1e9, color=colour, alpha=0.25, zorder=1, label=f"pass {band.label}")
        for edge, style in ((band.lo_m, "--"), (band.hi_m, ":")):
            ax.plot([edge * (1 + f / z) * 1e9 for z in depths], depths, color=colour, ls=style, lw=1.2)
        shifted = (band.lo_m * report.s[0] * 1e9, band.hi_m * report.s[1] * 1e9)
        ax.fill_between(shifted, z_lo, z_hi if z_hi > z_lo else z_lo * 1.04, color=colour, alpha=0.8, zorder=3)
    ax.axhspan(z_lo, z_hi if z_hi > z_lo else z_lo, color="k", alpha=0.1)
    ax.axhline(z_lo, color="k", lw=0.8)
    ax.axhline(
        z_hi,
        color="k",
        lw=0.8,
        label=f"z_near {z_lo * 1e3:g}-{z_hi * 1e3:g} mm" if z_hi > z_lo else f"z_near {z_lo * 1e3:g} mm",
    )
    ax.set_xlim(lo * 1e9 - 10, hi * 1e9 + 10)
    ax.set_ylim(depths[0], depths[-1])
    ax.set_yscale("log")
    ax.set_xlabel("wavelength (nm)")
    ax.set_ylabel("source depth z (m)")
    verdict = "all conditions hold" if report.ok else "conditions FAIL"
    ax.set_title(
        f"Split-spectrum bands, f = {f * 1e3:g} mm: {verdict}\n(curves: band edges λe(1 + f/z); bars: shifted pass "
        "bands at z_near)",
        fontsize=9,
    )
    ax.legend(fontsize=7, loc="upper right", ncol=2)
    return save_figure(fig, path)
