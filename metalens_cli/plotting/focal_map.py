"""Figure of the numerical focal-intensity map over (wavelength, depth) with the model curve."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from metalens_cli.analysis.focal_map import FocalValidation
from metalens_cli.analysis.symmetry import depth_for_wavelength
from metalens_cli.plotting.common import new_figure, save_figure


def plot_focal_map(
    path: str | Path, validation: FocalValidation, f_m: float, lambda_d_m: float, aperture_m: float
) -> Path:
    """On-axis intensity at d = f (normalised to its maximum), the model z(λ) and the best depths."""
    wl_nm = validation.wavelengths_m * 1e9
    from matplotlib.colors import PowerNorm

    intensity = validation.intensity / validation.intensity.max()
    fig, ax = new_figure(figsize=(6.5, 4.5))
    mesh = ax.pcolormesh(
        wl_nm, validation.depths_m, intensity.T, shading="nearest", cmap="inferno", norm=PowerNorm(0.5)
    )
    fig.colorbar(mesh, ax=ax, label="on-axis intensity at d = f (max = 1, γ = 0.5)")
    fine = np.linspace(wl_nm[0], wl_nm[-1], 600) * 1e-9
    model = [(w * 1e9, depth_for_wavelength(float(w), lambda_d_m, f_m).depth_m) for w in fine]
    model = [(w, z) for w, z in model if z is not None and z <= validation.depths_m[-1]]
    if model:
        ax.plot(*zip(*model), color="cyan", ls="--", lw=1.2, label=r"model $\lambda_d f/(\lambda-\lambda_d)$")
    best = [
        (r.wavelength_m * 1e9, r.best_depth_m)
        for r in validation.rows
        if r.best_depth_m is not None and r.model_depth_m is not None
    ]
    if best:
        ax.plot(*zip(*best), "o", ms=3, color="white", label="max intensity (Rayleigh-Sommerfeld)")
    ax.set_yscale("log")
    ax.set_ylim(validation.depths_m[0], validation.depths_m[-1])
    ax.set_xlabel("wavelength (nm)")
    ax.set_ylabel("source depth z (m)")
    na = (aperture_m / 2) / np.hypot(aperture_m / 2, f_m)
    ax.set_title(
        f"Hyperbolic lens λd = {lambda_d_m * 1e9:g} nm, f = {f_m * 1e3:g} mm, D = {aperture_m * 1e3:g} mm "
        f"(NA {na:.2f})",
        fontsize=9,
    )
    ax.legend(fontsize=7, loc="upper right")
    return save_figure(fig, path)
