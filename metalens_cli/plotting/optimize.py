"""Figures of an optimisation run: loss curves, the learned rotation map and a learned filter's bands."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from metalens_cli.plotting.common import new_figure, save_figure

PARTS = ("total", "l1", "ssim", "domain_adaptation", "bright", "sharp", "split", "light")


def loss_figure(path: str | Path, history: list[dict], parts: tuple[str, ...] = PARTS) -> Path:
    """One panel per loss term against step, each on a log scale where its values are positive
    (L_sharp falls by decades early on and the image terms by per cent later: one linear axis
    shows only the first), the raw values thin and a running mean thick."""
    present = [name for name in parts if any(np.isfinite(row.get(name, np.nan)) for row in history)]
    cols = min(3, max(len(present), 1))
    rows = -(-len(present) // cols) or 1
    fig, axes = new_figure(rows, cols, figsize=(4 * cols, 2.8 * rows), squeeze=False)
    steps = np.array([row["step"] for row in history])
    k = max(len(steps) // 20, 5)
    for ax, name in zip(axes.ravel(), present):
        values = np.array([row.get(name, np.nan) for row in history], dtype=float)
        ax.plot(steps, values, lw=0.5, alpha=0.5, color="C0")
        if len(values) >= k:
            ax.plot(
                steps[k - 1 :],
                np.convolve(values, np.ones(k) / k, mode="valid"),
                lw=1.5,
                color="k",
                label=f"{k}-step mean",
            )
            ax.legend(fontsize=6)
        if np.nanmin(values) > 0:
            ax.set_yscale("log")
        ax.set_title(name, fontsize=9)
        ax.set_xlabel("step")
        ax.grid(alpha=0.3, which="both")
    for ax in axes.ravel()[len(present) :]:
        ax.set_visible(False)
    fig.tight_layout()
    return save_figure(fig, path)


def steering_figure(path: str | Path, steering: dict) -> Path:
    """loss.png's companion: what steers θ at the run's start and end (``design.validation.
    steering``): per term and for the image and PSF sums, the gradient's RMS signal-to-noise
    ratio over draws (log scale; 1 marked: below it a term's pull is mostly noise) and its mean
    norm; the cosine between the image and PSF pulls in the title."""
    stages = [s for s in ("initial", "final") if "terms" in steering.get(s, {})]
    names = [t for t in ("l1", "ssim", "domain_adaptation", "image", "bright", "sharp", "psf")
             if any(t in steering[s]["terms"] for s in stages)]  # fmt: skip
    fig, axes = new_figure(1, 2, figsize=(11, 3.6))
    x = np.arange(len(names))
    for k, stage in enumerate(stages):
        terms = steering[stage]["terms"]
        for ax, key in zip(axes, ("rms_snr", "mean_norm")):
            values = [terms.get(t, {}).get(key) or np.nan for t in names]
            ax.bar(x + (k - 0.5) * 0.38, values, width=0.38, label=stage)
    cosines = ", ".join(
        f"{s} {steering[s]['cosine_image_psf']:+.2f}" for s in stages if steering[s].get("cosine_image_psf") is not None
    )
    for ax, label in zip(axes, ("RMS SNR over draws", "mean ‖gradient‖")):
        ax.set_xticks(x, names, fontsize=8)
        ax.set_yscale("log")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3, which="both", axis="y")
        ax.legend(fontsize=7)
    axes[0].axhline(1.0, color="k", lw=0.8, ls="--")
    fig.suptitle(f"What steers θ ({steering.get(stages[0], {}).get('draws', '?')} draws); cos(image, PSF): {cosines}",
                 fontsize=9)  # fmt: skip
    fig.tight_layout()
    return save_figure(fig, path)


def theta_figure(path: str | Path, theta: np.ndarray, pitch_m: float, initial: np.ndarray | None = None) -> Path:
    """Radial profile φ(r) = 2θ (unwrapped, and wrapped to 0..2π) or the 2-D map of 2θ mod 2π."""
    if theta.ndim == 1:
        fig, axes = new_figure(1, 2, figsize=(10, 3.5))
        r_mm = np.arange(theta.size) * pitch_m * 1e3
        if initial is not None:
            axes[0].plot(r_mm, 2 * initial, lw=0.8, color="0.6", label="initial")
        axes[0].plot(r_mm, 2 * theta, lw=0.8, label="learned")
        axes[0].set_ylabel("φ = 2θ (rad)")
        axes[0].legend(fontsize=7)
        axes[1].plot(r_mm, np.mod(2 * theta, 2 * np.pi), lw=0.3)
        axes[1].set_ylabel("φ mod 2π")
        for ax in axes:
            ax.set_xlabel("r (mm)")
            ax.grid(alpha=0.3)
    else:
        fig, ax = new_figure(figsize=(5, 4.5))
        step = max(theta.shape[0] // 1024, 1)
        half = theta.shape[0] // 2 * pitch_m * 1e3
        im = ax.imshow(
            np.mod(2 * theta[::step, ::step], 2 * np.pi),
            cmap="twilight",
            extent=(-half, half, -half, half),
            origin="lower",
        )
        fig.colorbar(im, ax=ax, label="φ mod 2π (rad)")
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
    return save_figure(fig, path)


def filter_figure(path: str | Path, history: list[dict], sensor_range_m: tuple[float, float]) -> Path:
    """A learned filter over the steps: each pass band [c − w/2, c + w/2] shaded against step
    (wavelength up); beside it the edge width and the split-spectrum penalty (symlog axis)."""
    steps = np.array([row["step"] for row in history])
    n = sum(1 for key in history[-1] if key.startswith("filter_center_"))
    fig, axes = new_figure(1, 2, figsize=(10, 3.8), gridspec_kw={"width_ratios": [2, 1]})
    colours = ("tab:blue", "tab:green", "tab:red") if n == 3 else [f"C{i}" for i in range(n)]
    for i, colour in zip(range(n), colours):
        c = np.array([row[f"filter_center_{i}_nm"] for row in history])
        w = np.array([row[f"filter_width_{i}_nm"] for row in history])
        axes[0].fill_between(steps, c - w / 2, c + w / 2, color=colour, alpha=0.35, lw=0)
        axes[0].plot(steps, c, color=colour, lw=1)
    axes[0].set_ylim(sensor_range_m[0] * 1e9, sensor_range_m[1] * 1e9)
    axes[0].set_xlabel("step")
    axes[0].set_ylabel("pass band (nm, FWHM)")
    axes[0].grid(alpha=0.3)
    axes[1].plot(steps, [row["filter_edge_nm"] for row in history], color="k", lw=1)
    axes[1].set_ylabel("edge width, 10-90 % (nm)")
    axes[1].set_ylim(bottom=0)
    axes[1].set_xlabel("step")
    axes[1].grid(alpha=0.3)
    penalty = axes[1].twinx()
    penalty.plot(steps, [row.get("split", np.nan) for row in history], color="tab:orange", lw=0.8)
    penalty.set_yscale("symlog", linthresh=1e-3)
    penalty.set_ylabel("split-spectrum penalty (nm²)", color="tab:orange")
    fig.tight_layout()
    return save_figure(fig, path)
