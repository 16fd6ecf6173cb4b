"""Figure of the depth-wavelength model: depth (log) against wavelength."""

from __future__ import annotations

from pathlib import Path

from metalens_cli.analysis.symmetry import depth_for_wavelength
from metalens_cli.constants import SENSOR_RANGE_M
from metalens_cli.plotting.common import new_figure, save_figure


def plot_symmetry(
    path: str | Path,
    f_m: float,
    lambda_d_m: float,
    wavelength_range_m: tuple[float, float] = SENSOR_RANGE_M,
    z_near_m: float | None = None,
) -> Path:
    """Depth z(λ) = λd·f/(λ − λd) on a log axis, the λd asymptote and the z_near line."""
    lo, hi = wavelength_range_m
    count = 600
    wavelengths = [lo + (hi - lo) * i / (count - 1) for i in range(count)]
    rows = [depth_for_wavelength(w, lambda_d_m, f_m) for w in wavelengths]
    real = [(r.wavelength_m * 1e9, r.depth_m) for r in rows if r.kind == "real"]
    fig, ax = new_figure(figsize=(6, 4))
    if real:
        ax.plot(
            [w for w, _ in real], [z for _, z in real], color="C0", label=r"$z = \lambda_d f / (\lambda - \lambda_d)$"
        )
    ax.axvline(lambda_d_m * 1e9, color="C3", ls="--", lw=1, label=rf"asymptote $\lambda_d$ = {lambda_d_m * 1e9:.1f} nm")
    if z_near_m is not None:
        ax.axhline(z_near_m, color="0.3", ls=":", lw=1, label=f"z_near = {z_near_m * 1e3:g} mm")
    ax.axvspan(lo * 1e9, lambda_d_m * 1e9, color="0.9", zorder=0, label="no real depth (λ < λd)")
    ax.set_xlim(lo * 1e9, hi * 1e9)
    ax.set_yscale("log")
    ax.set_xlabel("wavelength (nm)")
    ax.set_ylabel("depth z (m)")
    ax.set_title(f"Depth-wavelength symmetry, f = {f_m * 1e3:g} mm")
    ax.legend(fontsize=8, loc="upper right")
    ax.grid(True, which="both", alpha=0.3)
    return save_figure(fig, path)
