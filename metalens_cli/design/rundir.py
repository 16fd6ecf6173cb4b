"""The run directory written by ``metalens optimize`` (a design spec everywhere else).

    RUN_DIR/
      preset.toml            the resolved preset (steps and seed as run), read back by --resume
      start_theta.npy        with [optimize] init_from: the θ the run started from (init_from names it)
      theta.npy              θ (rad): the radial profile θ(k·p) (radial) or the M × M map (2-D)
      theta_radial.csv       radial runs: r_m, theta_rad
      theta.png              the profile or the map
      psf.exr                near and far PSFs, per wavelength and R, G, B (docs/formats.md)
      loss.csv, loss.png     one row per step: lr, loss parts, depths, seconds
      steering.png           what steers θ at the start and the end: each term's gradient SNR over
                             draws and mean norm (run.json: validation_loss.steering)
      samples/step_NNNNNN.png   clean | obstruction | capture every optimize.sample_every steps
      checkpoints/step_NNNNNN.pt   θ, optimiser, scheduler and history (the last ``KEEP`` kept)
      run.json               settings, cost, accuracy and final metrics
      filter.csv, filter.png  with [filter] learn = true: the learned filter's transmission every
                             0.5 nm (wavelength_nm, transmission) and its bands over the steps;
                             preset.toml then holds the learned [filter]

Every file is written atomically (temporary file, then rename). ``metalens reconstruct train``
uses the same class for its own run directory (``design.reconstruct_training``).

``--resume`` trusts no checkpoint: :meth:`RunDirectory.latest_checkpoint` checks the file and
:meth:`Checkpoint.restore` that its states fit the run's model, optimiser and scheduler, both
before the run directory is written; any fault is an :class:`InputError` naming the file.
"""

from __future__ import annotations

import csv
import io
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from metalens_cli.errors import InputError
from metalens_cli.imaging.restore import load_tensors
from metalens_cli.io.atomic import atomic_write
from metalens_cli.io.presets import load_preset, to_toml

KEEP = 2
START_THETA = "start_theta.npy"  # the copy of optimize.init_from's θ a run started from
STATES = ("model", "optimizer", "scheduler")  # the state dicts of a checkpoint, restored by Checkpoint.restore
LOSS_COLUMNS = (
    "step",
    "lr",
    "total",
    "l1",
    "ssim",
    "domain_adaptation",
    "bright",
    "sharp",
    "z_near_m",
    "z_far_m",
    "seconds",
    "window_near",
    "window_far",
)


def run_preset_toml(preset) -> str:
    """The preset's TOML as an optimize run directory holds it: ``optimize.init_from``, if any,
    names the run's own copy of the start θ (``START_THETA``, beside preset.toml)."""
    return to_toml(preset, optimize={"init_from": START_THETA} if preset.optimize.init_from is not None else {})


class RunDirectory:
    """Paths and writers of one run directory: its preset file is ``preset_name``, its loss table
    has ``columns``, and ``made_by`` names the command that writes it (for error messages)."""

    def __init__(
        self,
        path: str | Path,
        preset_name: str = "preset.toml",
        columns: tuple[str, ...] = LOSS_COLUMNS,
        made_by: str = "metalens optimize",
    ):
        self.path = Path(path)
        self.preset_name, self.columns, self.made_by = preset_name, columns, made_by

    @property
    def preset_path(self) -> Path:
        """The run's preset file: ``path / preset_name``."""
        return self.path / self.preset_name

    @property
    def checkpoints(self) -> Path:
        """The run's checkpoints folder: ``path / "checkpoints"``."""
        return self.path / "checkpoints"

    def holds_run(self) -> bool:
        """Whether the folder holds a run: its preset file, checkpoints folder or run.json exists."""
        return self.preset_path.exists() or self.checkpoints.exists() or (self.path / "run.json").exists()

    def check_fresh(self) -> None:
        """Refuse a folder that already holds a run, or any other files it would write over
        (before any work, so nothing is half-made)."""
        if self.holds_run():
            raise InputError(
                "--output", f"{str(self.path)!r} already holds a run", "another folder, or --resume to continue it"
            )
        if self.path.is_dir() and any(self.path.iterdir()):
            raise InputError("--output", f"{str(self.path)!r} is not empty", "a new or empty folder for the run")

    def check_resumable(self) -> None:
        """Refuse --resume of a folder without the run's preset file."""
        if not self.preset_path.is_file():
            raise InputError(
                "--resume", f"{str(self.path)!r} holds no run to resume", f"a run directory written by {self.made_by}"
            )

    def create(
        self, preset_text: str, folders: tuple[str, ...] = ("samples",), copies: dict[str, Path] | None = None
    ) -> None:
        """Start a fresh run with its preset file: refuse a folder that already holds one.
        ``copies`` (name → source file) are copied in before the preset, which may name them;
        the preset is written next: a run killed (SIGKILL) at any moment leaves a folder that is
        without a preset or resumable (``--resume`` recreates missing subfolders as it writes)."""
        self.check_fresh()
        self.path.mkdir(parents=True, exist_ok=True)
        for name, source in (copies or {}).items():
            with atomic_write(self.path / name) as temporary:
                shutil.copyfile(source, temporary)
        self.write_text(self.preset_name, preset_text)
        for folder in (*folders, "checkpoints"):
            (self.path / folder).mkdir(exist_ok=True)

    def load_preset(self):
        """The run's preset file, read with :func:`~metalens_cli.io.presets.load_preset` (the
        optimize preset format)."""
        return load_preset(self.preset_path)

    def write_text(self, name: str, text: str) -> Path:
        """Write ``text`` (UTF-8) to the file ``name`` in the run directory atomically; returns its
        path."""
        with atomic_write(self.path / name) as temporary:
            temporary.write_text(text, encoding="utf-8")
        return self.path / name

    # ------------------------------------------------------------------ checkpoints

    def save_checkpoint(self, state: dict) -> Path:
        """Write ``state`` (with key ``step``) and drop all but the newest ``KEEP`` checkpoints."""
        target = self.checkpoints / f"step_{state['step']:06d}.pt"
        self.checkpoints.mkdir(exist_ok=True)
        with atomic_write(target) as temporary:
            torch.save(state, temporary)
        for old in self.checkpoint_files()[:-KEEP]:
            old.unlink()
        return target

    def checkpoint_files(self) -> list[Path]:
        """The checkpoint files, oldest first by the step in their name (``step_1000000.pt`` after
        ``step_999500.pt``: the zero padding stops at six digits, so names do not sort as text)."""

        def step(path: Path) -> tuple[int, str]:
            digits = path.stem.removeprefix("step_")
            return (int(digits) if digits.isdigit() else -1, path.name)

        return sorted(self.checkpoints.glob("step_*.pt"), key=step)

    def latest_checkpoint(self, steps: int, lists: tuple[str, ...] = ()) -> Checkpoint | None:
        """The newest checkpoint, None when there is none. It must be a dict holding ``step``, an
        int in [0, ``steps``] (past ``steps``: an error on --steps), the ``STATES`` dicts with finite
        tensors, ``history`` (a list of ``step`` dicts, one per step done) and a list of dicts under
        each key of ``lists``. Anything else is an InputError on --resume naming the file."""
        found = self.checkpoint_files()
        if not found:
            return None
        path = found[-1]

        def refuse(what: str) -> InputError:
            return InputError("--resume", f"{path} {what}", f"a checkpoint written by {self.made_by}")

        try:
            state = load_tensors(path)
        except Exception:  # torch raises many types for foreign or damaged files
            raise refuse("cannot be read: it is truncated, damaged or not a torch file") from None
        if not isinstance(state, dict):
            raise refuse(f"holds a {type(state).__name__}, not a checkpoint")
        missing = [key for key in ("step", *STATES, "history", *lists) if key not in state]
        if missing:
            raise refuse(f"lacks {', '.join(missing)}")
        step = state["step"]
        if type(step) is not int or step < 0:
            raise refuse(f"has step {step!r}, not an integer ≥ 0")
        if step > steps:
            raise InputError("--steps", f"{steps} is below the {step} steps already run", f"at least {step}")
        for key in STATES:
            if not isinstance(state[key], dict):
                raise refuse(f"has a {type(state[key]).__name__} as its {key} state")
            if not all(tensor.isfinite().all() for tensor in _tensors(state[key])):
                raise refuse(f"holds NaN or infinite values in its {key} state")
        for key in ("history", *lists):
            if not (isinstance(state[key], list) and all(isinstance(row, dict) for row in state[key])):
                raise refuse(f"has no list of records as its {key}")
        if len(state["history"]) != step:
            raise refuse(f"has {len(state['history'])} history rows for step {step}")
        return Checkpoint(path, state)

    # ------------------------------------------------------------------ results

    def write_theta(self, theta: np.ndarray, pitch_m: float) -> None:
        """Write θ (rad) to theta.npy and, for a radial profile, theta_radial.csv (columns r_m,
        theta_rad; r = k·``pitch_m``), each atomically."""
        with atomic_write(self.path / "theta.npy") as temporary:
            with open(temporary, "wb") as handle:
                np.save(handle, theta)
        if theta.ndim == 1:
            rows = "\n".join(f"{k * pitch_m!r},{value!r}" for k, value in enumerate(theta))
            self.write_text("theta_radial.csv", "r_m,theta_rad\n" + rows + "\n")

    def write_loss_csv(self, history: list[dict]) -> None:
        """Write ``history`` to loss.csv atomically: one row per dict under ``columns`` (other keys
        dropped, missing ones left empty)."""
        buffer = io.StringIO()
        writer = csv.DictWriter(buffer, fieldnames=self.columns, extrasaction="ignore", lineterminator="\n")
        writer.writeheader()
        writer.writerows(history)
        self.write_text("loss.csv", buffer.getvalue())


@dataclass
class Checkpoint:
    """A checkpoint file and its contents, as checked by :meth:`RunDirectory.latest_checkpoint`."""

    path: Path
    state: dict

    @property
    def step(self) -> int:
        """The number of steps done when the checkpoint was written."""
        return self.state["step"]

    def restore(self, **modules) -> None:
        """Load the ``STATES`` into ``modules`` (model=, optimizer=, scheduler=): an InputError on
        --resume when torch refuses a state (other keys, a tensor of another shape) or an
        optimiser moment differs in shape from its parameter (torch checks only their number)."""
        for key, module in modules.items():
            try:
                module.load_state_dict(self.state[key])
                if isinstance(module, torch.optim.Optimizer) and any(
                    torch.is_tensor(m) and m.ndim and m.shape != p.shape
                    for p, moments in module.state.items()
                    for m in moments.values()
                ):
                    raise ValueError("a moment's shape differs from its parameter's")
            except (RuntimeError, ValueError, KeyError, TypeError, IndexError, AttributeError) as exc:
                raise InputError(
                    "--resume",
                    f"{self.path} does not fit this run: its {key} state: {' '.join(str(exc).split())}",
                    "a checkpoint of this run",
                ) from None


def _tensors(value):
    """Every tensor in nested dicts, lists and tuples."""
    if torch.is_tensor(value):
        yield value
    elif isinstance(value, dict | list | tuple):
        for item in value.values() if isinstance(value, dict) else value:
            yield from _tensors(item)
