"""Figure of a fabrication tolerance analysis (``metalens tolerance --plot``): per error source,
the change of each metric against the design, per pass band; the Monte Carlo spread beside it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from metalens_cli.plotting.common import new_figure, save_figure

PANELS = (
    ("strehl", "Strehl ratio (far)"),
    ("core_far", "far 5×5 core"),
    ("core_near", "near 5×5 core"),
    ("mtf50_lpmm", "MTF50 (far)"),
)
BAND_COLOURS = ("tab:blue", "tab:green", "tab:red", "tab:purple", "tab:orange")


def plot_tolerance(path: str | Path, result) -> Path:
    """One panel per metric: grouped bars of the percentage change per source (x) and band
    (colour); with a Monte Carlo, its mean Strehl change per band with the 95 % CI as error bars
    in the first panel, beside the expected value of the combined errors."""
    cases = result.cases
    bands = [f"{c * 1e9:.0f} nm" for c, _ in result.settings["bands_m"]]
    fig, axes = new_figure(1, len(PANELS), figsize=(3.6 * len(PANELS), 3.6), squeeze=False, layout="constrained")
    x = np.arange(len(cases))
    width = 0.8 / len(bands)
    for ax, (metric, title) in zip(axes[0], PANELS):
        for b, band in enumerate(bands):
            values = [100 * (np.nan_to_num(c["relative"][metric][b], nan=1.0) - 1) for c in cases]
            ax.bar(x + (b - (len(bands) - 1) / 2) * width, values, width, color=BAND_COLOURS[b % 5], label=band)
        ax.axhline(0, color="k", lw=0.6)
        ax.set_xticks(x, [c["source"] for c in cases], rotation=35, ha="right", fontsize=7)
        ax.set_ylabel("change against the design (%)")
        ax.set_title(title, fontsize=9)
    mc = result.monte_carlo
    if mc is not None:
        ax = axes[0, 0]
        for b, s in enumerate(mc["relative"]["strehl"]):
            mean, (lo, hi) = 100 * (s["mean"] - 1), s["ci"]
            ax.errorbar(
                len(cases) - 0.5 + 0.15 * b,
                mean,
                yerr=[[mean - 100 * (lo - 1)], [100 * (hi - 1) - mean]],
                fmt="o",
                color=BAND_COLOURS[b % 5],
                ms=3,
            )
        ax.text(len(cases) - 0.5, ax.get_ylim()[0], f"MC, {mc['draws']} draws", fontsize=6, ha="center", va="bottom")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(f"Fabrication tolerance: {result.design['spec']}", fontsize=10)
    return save_figure(fig, path)
