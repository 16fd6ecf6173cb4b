"""Figure of a measured-against-simulated PSF comparison: the x-λ scans of both side by side per
depth (and field, comparing field cubes; the paper's Fig. 4c), and the peak ratio and relative
error against wavelength."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from metalens_cli.plotting.common import depth_label, new_figure, save_figure


def plot_psf_comparison(path: str | Path, result, half_width_px: int = 40) -> Path:
    """Per compared depth, the central rows (x in µm) of the measured and the simulated PSFs
    against wavelength on one colour scale (γ 0.35); below, peak ratio and relative L2 per λ."""
    scans = result.scans
    n = result.pixels
    c = n // 2
    h = min(half_width_px, c)
    x_um = np.arange(-h, h + 1) * result.pixel_pitch_m * 1e6
    fig, axes = new_figure(len(scans) + 1, 2, figsize=(8, 3.2 * (len(scans) + 1)), squeeze=False)
    from matplotlib.colors import PowerNorm

    for row, scan in enumerate(scans):
        images = {kind: scan[kind][:, c - h : c + h + 1] for kind in ("measured", "simulated")}
        norm = PowerNorm(0.35, vmin=0, vmax=max(float(image.max()) for image in images.values()) or 1.0)
        wl_nm = np.asarray(scan["wavelengths_m"]) * 1e9
        extent = (
            (x_um[0], x_um[-1], wl_nm[0] - 0.5, wl_nm[-1] + 0.5)
            if wl_nm.size == 1
            else (x_um[0], x_um[-1], wl_nm[0], wl_nm[-1])
        )
        for col, (kind, image) in enumerate(images.items()):
            ax = axes[row, col]
            ax.imshow(
                np.clip(image, 0, None),
                aspect="auto",
                origin="lower",
                cmap="inferno",
                norm=norm,
                interpolation="nearest",
                extent=extent,
            )
            ax.set_title(f"{kind}, {_label(scan)}", fontsize=9)
            ax.set_xlabel("x (µm)")
            ax.set_ylabel("wavelength (nm)")
    ratio_ax, error_ax = axes[-1]
    for scan in scans:
        pairs = [
            p
            for p in result.pairs
            if ((p["depth_m"] is None and np.isinf(scan["depth_m"])) or p["depth_m"] == scan["depth_m"])
            and p.get("field") == scan.get("field")
        ]
        wl = [p["wavelength_m"] * 1e9 for p in pairs]
        ratio_ax.plot(wl, [p["peak_ratio"] for p in pairs], marker=".", label=_label(scan))
        error_ax.plot(wl, [p["relative_l2"] for p in pairs], marker=".", label=_label(scan))
    ratio_ax.set_ylabel("peak ratio (measured / simulated)")
    error_ax.set_ylabel("relative L2 error")
    for ax in (ratio_ax, error_ax):
        ax.set_xlabel("wavelength (nm)")
        ax.legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)


def _label(scan: dict) -> str:
    """ "z = 45 mm", and the field angle of a field comparison's scan: "z = ∞, field 5°"."""
    field = f", field {scan['field_angle_deg']:.3g}°" if "field" in scan else ""
    return depth_label(scan["depth_m"]) + field
