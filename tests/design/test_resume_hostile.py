"""Hostile checkpoints and models (issue 18): `optimize --resume`, `reconstruct train --resume` and
`reconstruct apply` refuse a corrupt or foreign file with one line on stderr and exit 2, and leave
every file of the run directory as it was."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from metalens_cli.cli.main import run
from metalens_cli.imaging.network import NetworkShape, ReconstructionNet
from metalens_cli.imaging.restore import save_model
from metalens_cli.io.image_files import write_exr_rgb

TINY = Path(__file__).with_name("tiny.toml")
TINY_RECONSTRUCT = Path(__file__).with_name("tiny_reconstruct.toml")
LENS = ["hyperbolic:532nm", "--f", "1mm", "--aperture", "0.2mm"]


def _edit(change):
    """A corruption that rewrites a torch file after ``change(contents)``."""

    def corrupt(path: Path) -> None:
        state = torch.load(path, weights_only=True)
        change(state)
        torch.save(state, path)

    return corrupt


def _truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def _garbage(path: Path) -> None:
    path.write_bytes(b"not a checkpoint")


def _set(key: str, value):
    return _edit(lambda state: state.update({key: value}))


def _nan_theta(state: dict) -> None:
    state["model"]["theta"][0] = math.nan


def _inf_moment(state: dict) -> None:
    state["optimizer"]["state"][0]["exp_avg"][0] = math.inf


def _short_moment(state: dict) -> None:
    state["optimizer"]["state"][0]["exp_avg"] = torch.zeros(7, dtype=torch.float64)


def _snapshot(folder: Path) -> dict:
    """Bytes and modification time of every file under ``folder``."""
    return {
        p.relative_to(folder): (p.read_bytes(), p.stat().st_mtime_ns) for p in sorted(folder.rglob("*")) if p.is_file()
    }


def _refused(capsys, field: str, *fragments: str) -> None:
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith(f"metalens: error: {field}: ") and all(f in lines[0] for f in fragments), lines[0]


@pytest.fixture(scope="module")
def optimized(tmp_path_factory) -> Path:
    """An optimize run of 3 steps: its only checkpoint is checkpoints/step_000003.pt."""
    out = tmp_path_factory.mktemp("optimize") / "run"
    assert run(["optimize", str(TINY), "-o", str(out), "--steps", "3", "--quiet"]) == 0
    return out


@pytest.mark.parametrize(
    "corrupt, field, message",
    [
        (_truncate, "--resume", "truncated, damaged or not a torch file"),
        (_garbage, "--resume", "truncated, damaged or not a torch file"),
        (lambda path: torch.save(torch.zeros(3), path), "--resume", "holds a Tensor, not a checkpoint"),
        (lambda path: torch.save({"step": 1}, path), "--resume", "lacks model, optimizer, scheduler, history"),
        (
            _edit(lambda state: state["model"].update(theta=torch.zeros(7, dtype=torch.float64))),
            "--resume",
            "size mismatch for theta",
        ),
        (_edit(_nan_theta), "--resume", "NaN or infinite values in its model state"),
        (_edit(_inf_moment), "--resume", "NaN or infinite values in its optimizer state"),
        (_edit(_short_moment), "--resume", "moment's shape differs"),
        (_set("step", -1), "--resume", "has step -1"),
        (_set("step", 3.0), "--resume", "has step 3.0"),
        (_set("step", 9), "--steps", "4 is below the 9 steps already run"),
    ],
    ids=[
        "truncated",
        "not-torch",
        "tensor",
        "other-dict",
        "theta-shape",
        "nan-theta",
        "inf-moment",
        "moment-shape",
        "negative-step",
        "float-step",
        "step-past-steps",
    ],
)
def test_optimize_resume_refuses_a_hostile_checkpoint(optimized, tmp_path, capsys, corrupt, field, message):
    out = tmp_path / "run"
    shutil.copytree(optimized, out)
    checkpoint = out / "checkpoints" / "step_000003.pt"
    corrupt(checkpoint)
    before = _snapshot(out)
    capsys.readouterr()
    # --steps 4 would rewrite preset.toml on an accepted resume
    assert run(["optimize", str(TINY), "-o", str(out), "--resume", "--steps", "4", "--quiet"]) == 2
    _refused(capsys, field, message, *([str(checkpoint)] if field == "--resume" else []))
    assert _snapshot(out) == before


@pytest.fixture(scope="module")
def reconstructed(tmp_path_factory) -> Path:
    """A reconstruct train run of 2 steps: its only checkpoint is checkpoints/step_000002.pt."""
    out = tmp_path_factory.mktemp("reconstruct") / "run"
    assert (
        run(
            [
                "reconstruct",
                "train",
                *LENS,
                "--preset",
                str(TINY_RECONSTRUCT),
                "-o",
                str(out),
                "--steps",
                "2",
                "--quiet",
            ]
        )
        == 0
    )
    return out


def _wide_head(state: dict) -> None:
    state["model"]["head.weight"] = torch.zeros(5, *state["model"]["head.weight"].shape[1:])


@pytest.mark.parametrize(
    "corrupt, message",
    [
        (_garbage, "truncated, damaged or not a torch file"),
        (_edit(_wide_head), "size mismatch for head.weight"),
    ],
    ids=["not-torch", "weight-shape"],
)
def test_reconstruct_resume_refuses_a_hostile_checkpoint(reconstructed, tmp_path, capsys, corrupt, message):
    out = tmp_path / "run"
    shutil.copytree(reconstructed, out)
    checkpoint = out / "checkpoints" / "step_000002.pt"
    corrupt(checkpoint)
    before = _snapshot(out)
    capsys.readouterr()
    assert run(["reconstruct", "train", *LENS, "-o", str(out), "--resume", "--steps", "3", "--quiet"]) == 2
    _refused(capsys, "--resume", message, str(checkpoint))
    assert _snapshot(out) == before


def _nan_weight(state: dict) -> None:
    state["state_dict"]["head.weight"][0] = math.nan


@pytest.mark.parametrize(
    "corrupt, message",
    [
        (_truncate, "truncated, damaged or not a torch file"),
        (_edit(_nan_weight), "NaN or infinite weights"),
        (
            _edit(lambda state: state["shape"].update(position_scale=math.inf)),
            "NaN or infinite weights or position scale",
        ),
        (_set("design", "x"), "is not a metalens reconstruction model"),
    ],
    ids=["truncated", "nan-weight", "inf-position-scale", "design-not-a-dict"],
)
def test_apply_refuses_a_hostile_model(tmp_path, capsys, corrupt, message):
    model = tmp_path / "run" / "model.pt"
    model.parent.mkdir()
    save_model(
        model, ReconstructionNet(NetworkShape(width=4, depth=2, frequencies=2)), {"spec": "x", "fingerprint": "abc"}
    )
    corrupt(model)
    capture = tmp_path / "capture.exr"
    write_exr_rgb(capture, np.full((3, 16, 16), 0.5, dtype=np.float32))
    assert run(["reconstruct", "apply", str(model.parent), str(capture), "-o", str(tmp_path / "out")]) == 2
    _refused(capsys, "RUN", message, str(model))
    assert not (tmp_path / "out").exists()


def test_checkpoints_past_a_million_steps_keep_their_order(tmp_path):
    """Checkpoint names pad the step to six digits, so step 1 000 000 sorts before 999 500 as
    text: the newest is found, and pruning keeps the newest, by the step itself."""
    from metalens_cli.design.rundir import KEEP, RunDirectory

    run = RunDirectory(tmp_path / "run")
    run.path.mkdir()
    for step in (999_000, 999_500, 1_000_000, 1_000_500)[-(KEEP + 1) :]:
        run.save_checkpoint({"step": step})
    names = [p.name for p in run.checkpoint_files()]
    assert names[-1] == "step_1000500.pt" and len(names) == KEEP
    assert "step_1000000.pt" in names
