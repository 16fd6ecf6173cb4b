"""Figures of a PSF scan: x-λ scans per depth (paper Fig. 3d) and focal-spot intensity vs λ (Fig. 4c);
for a scan over the field, the PSFs themselves across fields and wavelengths."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from metalens_cli.plotting.common import depth_label, new_figure, save_figure


def plot_psf_scan(
    path: str | Path,
    psf: np.ndarray,
    wavelengths_m,
    depths_m,
    pixel_pitch_m: float,
    pass_bands_m: list[tuple[float, float]] | None = None,
    half_width_px: int = 40,
) -> Path:
    """Top: the central row of each PSF (x in µm) against wavelength, one panel per depth, each
    PSF normalised to its total power. Bottom: the central-pixel power fraction against λ."""
    n_depths = psf.shape[0]
    n = psf.shape[-1]
    c = n // 2
    h = min(half_width_px, c)
    wl_nm = np.asarray(wavelengths_m) * 1e9
    x_um = (np.arange(-h, h + 1 if n % 2 or h < c else h) * pixel_pitch_m) * 1e6
    fig, axes = new_figure(2, max(n_depths, 1), figsize=(4 * max(n_depths, 2), 6.5), squeeze=False)
    totals = psf.sum(axis=(-2, -1), keepdims=True)
    normalised = psf / np.where(totals > 0, totals, 1)
    from matplotlib.colors import PowerNorm

    rows = normalised[:, :, c, c - h : c - h + x_um.size]
    norm = PowerNorm(0.35, vmin=0, vmax=float(rows.max()) or 1.0)  # shared scale; γ shows the blur
    for i, z in enumerate(depths_m):
        ax = axes[0, i]
        ax.imshow(
            rows[i],
            aspect="auto",
            origin="lower",
            cmap="inferno",
            norm=norm,
            interpolation="nearest",
            extent=(x_um[0], x_um[-1], *_row_edges(wl_nm)),
        )
        ax.set_title(f"x-λ scan, {depth_label(z)} (γ = 0.35)", fontsize=9)
        ax.set_xlabel("x (µm)")
        ax.set_ylabel("wavelength (nm)")
        for lo, hi in pass_bands_m or []:
            for edge in (lo, hi):
                ax.axhline(edge * 1e9, color="w", lw=0.6, ls=":")
    bottom = axes[1, 0]
    for i, z in enumerate(depths_m):
        bottom.plot(wl_nm, normalised[i, :, c, c], label=depth_label(z))
    for lo, hi in pass_bands_m or []:
        bottom.axvspan(lo * 1e9, hi * 1e9, color="0.85", zorder=0)
    bottom.set_xlabel("wavelength (nm)")
    bottom.set_ylabel("focal-spot intensity (fraction of total)")
    bottom.legend(fontsize=8)
    bottom.set_title("Focal-spot intensity (grey: pass bands)" if pass_bands_m else "Focal-spot intensity", fontsize=9)
    for ax in axes[1, 1:]:
        ax.axis("off")
    fig.tight_layout()
    return save_figure(fig, path)


def _row_edges(wl_nm: np.ndarray) -> tuple[float, float]:
    """The outer edges (nm) of image rows centred on the scan's wavelengths, one mean step wide
    (1 nm for a single wavelength, whose row would otherwise have no height)."""
    step = (wl_nm[-1] - wl_nm[0]) / (wl_nm.size - 1) if wl_nm.size > 1 else 1.0
    return float(wl_nm[0] - step / 2), float(wl_nm[-1] + step / 2)


FIELD_COLUMNS = 5  # wavelengths shown per field (evenly spread over the scan's)
FIELD_DECADES = 4  # log scale of the field figure: this many decades below the brightest pixel


def plot_field_psfs(path: str | Path, fields, wavelengths_m, depths_m, pixel_pitch_m: float) -> Path:
    """One row per field (``imaging.psf_scan.FieldScan``), one column per wavelength (at most
    ``FIELD_COLUMNS``, evenly spread), the farthest depth's PSFs on one log scale; axes in µm from
    the chief ray (white cross), so coma and the spread grow down the rows."""
    from matplotlib.colors import LogNorm

    depth = int(np.argmax(depths_m))
    columns = np.unique(np.linspace(0, len(wavelengths_m) - 1, min(FIELD_COLUMNS, len(wavelengths_m))).round()).astype(
        int
    )
    psf = fields.psf[:, depth][:, columns]  # (F, C, N, N)
    totals = psf.sum(axis=(-2, -1), keepdims=True)
    psf = psf / np.where(totals > 0, totals, 1)
    top = float(psf.max()) or 1.0
    norm = LogNorm(vmin=top * 10.0**-FIELD_DECADES, vmax=top)
    n = psf.shape[-1]
    rows, cols = psf.shape[:2]
    fig, axes = new_figure(rows, cols, figsize=(2.2 * cols + 1, 2.2 * rows + 0.6), squeeze=False)
    for f in range(rows):
        chief = np.asarray(fields.chief_ray_m[f]) / pixel_pitch_m - np.asarray(
            fields.centre_px[f]
        )  # px from the centre
        lo = (-(n // 2) - 0.5 - chief) * pixel_pitch_m * 1e6  # the window's edges in µm from the chief ray
        extent = (lo[0], lo[0] + n * pixel_pitch_m * 1e6, lo[1] + n * pixel_pitch_m * 1e6, lo[1])
        for c in range(cols):
            ax = axes[f, c]
            image = ax.imshow(np.clip(psf[f, c], norm.vmin, None), cmap="inferno", norm=norm, extent=extent,
                              interpolation="nearest")  # fmt: skip
            ax.plot([0], [0], "+", color="w", ms=6, mew=0.8)
            ax.set_title(
                f"{np.degrees(fields.angles_rad[f]):.3g}°, {wavelengths_m[columns[c]] * 1e9:.0f} nm", fontsize=8
            )
            ax.tick_params(labelsize=7)
            if f == rows - 1:
                ax.set_xlabel("x − chief ray (µm)", fontsize=8)
            if c == 0:
                ax.set_ylabel("y − chief ray (µm)", fontsize=8)
    fig.subplots_adjust(wspace=0.45, hspace=0.35)
    fig.colorbar(image, ax=axes, shrink=0.8, label="fraction of the PSF's light per pixel")
    fig.suptitle(f"PSFs over the field, {depth_label(depths_m[depth])} (azimuth {np.degrees(fields.azimuth_rad):.3g}°)",
                 fontsize=10)  # fmt: skip
    return save_figure(fig, path)


def plot_scan(path: str | Path, scan, preset=None) -> Path:
    """:func:`plot_psf_scan` of a scan (``imaging.psf_scan.ScanResult``), with the pass bands of
    ``preset``'s filter (centre ± width/2) when it has one; :func:`plot_field_psfs` of a scan over
    the field."""
    if scan.fields is not None:
        return plot_field_psfs(path, scan.fields, scan.wavelengths_m, scan.depths_m, scan.pixel_pitch_m)
    f = preset.filter if preset is not None else None
    bands = None if f is None else [(c - w / 2, c + w / 2) for c, w in zip(f.centers_m, f.widths_m)]
    return plot_psf_scan(path, scan.psf, scan.wavelengths_m, scan.depths_m, scan.pixel_pitch_m, bands)
