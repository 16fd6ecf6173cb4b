"""Figure of a nanofin's efficiency: η, co-polarised fraction, T and R against wavelength, and
the convergence of η with the number of Fourier harmonics."""

from __future__ import annotations

from pathlib import Path

from metalens_cli.plotting.common import new_figure, save_figure


def plot_efficiency(path: str | Path, response, convergence: list[dict]) -> Path:
    """Left: the efficiencies (power fractions) against λ; right (when given): η and seconds
    per wavelength against N harmonics per axis."""
    fig, axes = new_figure(1, 2 if convergence else 1, figsize=(10 if convergence else 5.5, 3.8), squeeze=False)
    ax = axes[0, 0]
    wl = response.wavelengths_m * 1e9
    for values, label in ((response.conversion, "η conversion"), (response.co_polarized, "co-polarised"),
                          (response.transmittance, "T"), (response.reflectance, "R")):
        ax.plot(wl, values, marker=".", label=label)
    ax.set_xlabel("wavelength (nm)")
    ax.set_ylabel("power fraction")
    ax.set_ylim(0, 1.02)
    ax.set_title(f"{response.harmonics} × {response.harmonics} harmonics", fontsize=9)
    ax.legend(fontsize=8)
    if convergence:
        ax = axes[0, 1]
        n = [c["harmonics"] for c in convergence]
        ax.plot(n, [c["conversion"] for c in convergence], marker="o", label="η")
        ax.set_xlabel("harmonics N per axis")
        ax.set_ylabel("η")
        twin = ax.twinx()
        twin.semilogy(n, [c["seconds"] for c in convergence], marker="s", color="0.5", label="seconds")
        twin.set_ylabel("seconds per wavelength")
        ax.set_title("convergence (middle wavelength)", fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path)
