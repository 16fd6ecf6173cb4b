"""Figure of a nanofin's efficiency: η, co-polarised fraction, T and R against wavelength, and
the convergence of η with the number of Fourier harmonics."""

from __future__ import annotations

from pathlib import Path

from metalens_cli.plotting.common import new_figure, save_figure


def plot_efficiency(path: str | Path, response, convergence: list[dict]) -> Path:
    """Left: the efficiencies (power fractions) against λ; right (when given): the largest
    change of η over the wavelengths from N − 2, and the seconds for all wavelengths, against N
    harmonics per axis (speed against error)."""
    fig, axes = new_figure(1, 2 if convergence else 1, figsize=(10 if convergence else 5.5, 3.8), squeeze=False)
    ax = axes[0, 0]
    wl = response.wavelengths_m * 1e9
    for values, label in (
        (response.conversion, "η conversion"),
        (response.co_polarized, "co-polarised"),
        (response.transmittance, "T"),
        (response.reflectance, "R"),
    ):
        ax.plot(wl, values, marker=".", label=label)
    ax.set_xlabel("wavelength (nm)")
    ax.set_ylabel("power fraction")
    ax.set_ylim(0, 1.02)
    ax.set_title(f"{response.harmonics} × {response.harmonics} harmonics", fontsize=9)
    ax.legend(fontsize=8)
    if convergence:
        ax = axes[0, 1]
        rows = [c for c in convergence if c["max_change"] is not None]
        n = [c["harmonics"] for c in rows]
        ax.semilogy(n, [max(c["max_change"], 1e-12) for c in rows], marker="o", label="largest change of η")
        ax.set_xlabel("harmonics N per axis")
        ax.set_ylabel("largest |η(N) − η(N − 2)| over λ")
        twin = ax.twinx()
        twin.semilogy(n, [c["seconds"] for c in rows], marker="s", color="0.5", label="seconds")
        twin.set_ylabel("seconds, all wavelengths")
        ax.set_title("convergence", fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path)


def plot_fin_map(path: str | Path, fin_map, choice: dict) -> Path:
    """Heatmaps of η over fin width × length: one per pass band and their mean, the recommended
    fin marked."""
    import numpy as np

    panels = [(f"{c * 1e9:g} nm band", fin_map.eta[:, :, k]) for k, (c, _) in enumerate(fin_map.bands_m)]
    panels.append(("mean over the bands", fin_map.score))
    fig, axes = new_figure(1, len(panels), figsize=(3.6 * len(panels), 3.4), squeeze=False)
    w, length = fin_map.widths_m * 1e9, fin_map.lengths_m * 1e9
    extent = (w[0], w[-1], length[0], length[-1]) if w.size > 1 and length.size > 1 else None
    for ax, (title, values) in zip(axes[0], panels):
        image = ax.imshow(
            np.ma.masked_invalid(values), origin="lower", aspect="auto", extent=extent, vmin=0, vmax=1, cmap="viridis"
        )
        ax.plot(choice["width_m"] * 1e9, choice["length_m"] * 1e9, "r+", markersize=12)
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("width (nm)")
        ax.set_ylabel("length (nm)")
    fig.colorbar(image, ax=axes[0].tolist(), label="η")
    return save_figure(fig, path)
