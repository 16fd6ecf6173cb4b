"""Shared figure handling: a headless backend and atomic PNG writing."""

from __future__ import annotations

import math
from pathlib import Path

from metalens_cli.io.atomic import atomic_write


def new_figure(*args, **kwargs):
    """``plt.subplots`` on the non-interactive Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt.subplots(*args, **kwargs)


def save_figure(fig, path: str | Path, dpi: int = 150) -> Path:
    """Save ``fig`` to ``path`` atomically (temp file + rename) and close it."""
    import matplotlib.pyplot as plt

    path = Path(path)
    try:
        with atomic_write(path) as temporary:
            fig.savefig(temporary, dpi=dpi, bbox_inches="tight", format=path.suffix.lstrip(".") or "png")
    finally:
        plt.close(fig)
    return path


def depth_label(z_m: float) -> str:
    """``z = ∞``, ``z = 45 mm`` or ``z = 2 m`` for titles and legends."""
    return "z = ∞" if math.isinf(z_m) else f"z = {z_m * 1e3:g} mm" if z_m < 1 else f"z = {z_m:g} m"
