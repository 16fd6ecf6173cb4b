"""The run directory written by ``metalens optimize`` (a design spec everywhere else).

    RUN_DIR/
      preset.toml            the resolved preset (steps and seed as run), read back by --resume
      theta.npy              θ (rad): the radial profile θ(k·p) (radial) or the M × M map (2-D)
      theta_radial.csv       radial runs: r_m, theta_rad
      theta.png              the profile or the map
      psf.exr                near and far PSFs, per wavelength and R, G, B (docs/formats.md)
      loss.csv, loss.png     one row per step: lr, loss parts, depths, seconds
      samples/step_NNNNNN.png   clean | obstruction | capture every optimize.sample_every steps
      checkpoints/step_NNNNNN.pt   θ, optimiser, scheduler and history (the last ``KEEP`` kept)
      run.json               settings, cost, accuracy and final metrics

Every file is written atomically (temporary file, then rename). ``metalens reconstruct train``
uses the same class for its own run directory (``design.reconstruct_training``).
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np
import torch

from metalens_cli.errors import InputError
from metalens_cli.io.atomic import atomic_write
from metalens_cli.io.presets import load_preset

KEEP = 2
LOSS_COLUMNS = ("step", "lr", "total", "l1", "ssim", "domain_adaptation", "bright", "sharp", "z_near_m", "z_far_m", "seconds")


class RunDirectory:
    """Paths and writers of one run directory: its preset file is ``preset_name``, its loss table
    has ``columns``, and ``made_by`` names the command that writes it (for error messages)."""

    def __init__(self, path: str | Path, preset_name: str = "preset.toml", columns: tuple[str, ...] = LOSS_COLUMNS,
                 made_by: str = "metalens optimize"):
        self.path = Path(path)
        self.preset_name, self.columns, self.made_by = preset_name, columns, made_by

    @property
    def preset_path(self) -> Path:
        return self.path / self.preset_name

    @property
    def checkpoints(self) -> Path:
        return self.path / "checkpoints"

    def holds_run(self) -> bool:
        return self.preset_path.exists() or self.checkpoints.exists() or (self.path / "run.json").exists()

    def create(self, preset_text: str, folders: tuple[str, ...] = ("samples",)) -> None:
        """Start a fresh run with its preset file: refuse a folder that already holds one."""
        if self.holds_run():
            raise InputError("--output", f"{str(self.path)!r} already holds a run", "another folder, or --resume to continue it")
        for folder in folders:
            (self.path / folder).mkdir(parents=True, exist_ok=True)
        self.checkpoints.mkdir(parents=True, exist_ok=True)
        self.write_text(self.preset_name, preset_text)

    def load_preset(self):
        return load_preset(self.preset_path)

    def write_text(self, name: str, text: str) -> Path:
        with atomic_write(self.path / name) as temporary:
            temporary.write_text(text, encoding="utf-8")
        return self.path / name

    # ------------------------------------------------------------------ checkpoints

    def save_checkpoint(self, state: dict) -> Path:
        """Write ``state`` (with key ``step``) and drop all but the newest ``KEEP`` checkpoints."""
        target = self.checkpoints / f"step_{state['step']:06d}.pt"
        with atomic_write(target) as temporary:
            torch.save(state, temporary)
        for old in sorted(self.checkpoints.glob("step_*.pt"))[:-KEEP]:
            old.unlink()
        return target

    def latest_checkpoint(self) -> dict | None:
        found = sorted(self.checkpoints.glob("step_*.pt"))
        if not found:
            return None
        try:
            return torch.load(found[-1], map_location="cpu", weights_only=False)
        except (OSError, RuntimeError, EOFError) as exc:
            raise InputError("--resume", f"cannot read {found[-1]}: {exc}", f"a checkpoint written by {self.made_by}") from None

    # ------------------------------------------------------------------ results

    def write_theta(self, theta: np.ndarray, pitch_m: float) -> None:
        with atomic_write(self.path / "theta.npy") as temporary:
            with open(temporary, "wb") as handle:
                np.save(handle, theta)
        if theta.ndim == 1:
            rows = "\n".join(f"{k * pitch_m!r},{value!r}" for k, value in enumerate(theta))
            self.write_text("theta_radial.csv", "r_m,theta_rad\n" + rows + "\n")

    def write_loss_csv(self, history: list[dict]) -> None:
        buffer = io.StringIO()
        writer = csv.DictWriter(buffer, fieldnames=self.columns, extrasaction="ignore", lineterminator="\n")
        writer.writeheader()
        writer.writerows(history)
        self.write_text("loss.csv", buffer.getvalue())
