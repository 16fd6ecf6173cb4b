"""Hostile input, round two (issue 29), on the reconstruction tools: a full disk or file-size limit
under `reconstruct export`, model files with fields no training run writes, a memory budget too
small for the network, output folders holding the user's files. Each refusal is one stderr line
(docs/failures.md) and leaves nothing behind."""

import resource
import shutil

import numpy as np
import pytest
from cli.test_hostile import _cli  # tests/ is on the path (pyproject's pythonpath)

from metalens_cli.cli.main import run
from metalens_cli.imaging.network import NetworkShape, ReconstructionNet
from metalens_cli.imaging.restore import save_model
from metalens_cli.io.image_files import write_exr_rgb


def _model(folder, shape: NetworkShape, **extra):
    """A run folder holding an untrained network's model.pt (what apply and export read)."""
    folder.mkdir()
    save_model(folder / "model.pt", ReconstructionNet(shape), {"spec": "x", "fingerprint": "abc"}, extra)
    return folder


@pytest.fixture
def tiny(tmp_path):
    return _model(tmp_path / "run", NetworkShape(width=4, depth=2, frequencies=2))


def _one_line(capsys, *words) -> None:
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and err.startswith("metalens: error: "), err
    assert all(word in err for word in words), err


def test_export_under_a_file_size_limit_exits_1_without_aborting(tiny, tmp_path):
    """torch's own writer aborts the process (SIGABRT, a C++ stack) on EFBIG; ours raises in Python."""
    target = tmp_path / "model.pt2"
    proc = _cli(
        "reconstruct",
        "export",
        str(tiny),
        "-o",
        str(target),
        preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096)),
    )
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 1 and err.count("\n") == 1 and "file-size limit" in err, err
    assert "terminate called" not in err and not target.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_export_to_a_full_disk_is_refused_before_writing(tiny, tmp_path, monkeypatch, capsys):
    usage = shutil.disk_usage(tmp_path)
    monkeypatch.setattr("metalens_cli.imaging.export.shutil.disk_usage", lambda folder: usage._replace(free=1000))
    assert run(["reconstruct", "export", str(tiny), "-o", str(tmp_path / "model.pt2")]) == 1
    _one_line(capsys, "model.pt2", "No space left")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


@pytest.mark.parametrize(
    ("extra", "words"),
    [
        ({"steps": -5}, "steps is -5, not an integer ≥ 0"),
        ({"steps": 2.5}, "steps is 2.5"),
        ({"loss_terms": ["l1", "magic"]}, "loss_terms"),
    ],
)
def test_apply_refuses_model_fields_no_training_writes(tmp_path, capsys, extra, words):
    run_dir = _model(tmp_path / "run", NetworkShape(width=4, depth=2, frequencies=2), **extra)
    write_exr_rgb(tmp_path / "capture.exr", np.full((3, 16, 16), 0.5, np.float32))
    assert run(["reconstruct", "apply", str(run_dir), str(tmp_path / "capture.exr"), "-o", str(tmp_path / "out")]) == 2
    _one_line(capsys, "RUN", "model.pt", words)
    assert not (tmp_path / "out").exists()


def test_a_memory_budget_below_the_network_tiles_names_memory_mib(tmp_path, capsys):
    """The default network needs ~25 MiB for its smallest tile (136² px beside a 64 px overlap):
    --memory-mib 16 is refused before any image is read, naming the option and what it needs."""
    run_dir = _model(tmp_path / "run", NetworkShape())
    write_exr_rgb(tmp_path / "small.exr", np.full((3, 16, 16), 0.5, np.float32))
    write_exr_rgb(tmp_path / "large.exr", np.full((3, 200, 200), 0.5, np.float32))
    inputs = [str(run_dir), str(tmp_path / "small.exr"), str(tmp_path / "large.exr"), "-o", str(tmp_path / "out")]
    assert run(["reconstruct", "apply", *inputs, "--memory-mib", "16"]) == 2
    _one_line(capsys, "--memory-mib: 16 MiB", "at least 25 MiB")
    assert not (tmp_path / "out").exists()
    assert run(["reconstruct", "apply", *inputs, "--memory-mib", "25", "--quiet"]) == 0


def test_apply_never_writes_over_the_users_files_unless_told(tiny, tmp_path, capsys):
    write_exr_rgb(tmp_path / "photo.exr", np.full((3, 16, 16), 0.5, np.float32))
    out = tmp_path / "out"
    out.mkdir()
    (out / "photo.png").write_bytes(b"the user's own photo")
    apply = ["reconstruct", "apply", str(tiny), str(tmp_path / "photo.exr"), "-o", str(out), "--quiet"]
    assert run(apply) == 2
    _one_line(capsys, "--output", "'photo.png'", "--overwrite")
    assert [p.name for p in out.iterdir()] == ["photo.png"] and (
        out / "photo.png"
    ).read_bytes() == b"the user's own photo"
    assert run([*apply, "--overwrite"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["photo.exr", "photo.png"]
    assert (out / "photo.png").read_bytes() != b"the user's own photo"
