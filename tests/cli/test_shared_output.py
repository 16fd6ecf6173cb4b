"""Two runs into one output folder: the second is refused while the first writes and after it
has written (without --overwrite), for every command that writes a folder; a killed run never
blocks the next (issue 60)."""

import json
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from metalens_cli.cli.main import run
from metalens_cli.errors import InputError
from metalens_cli.io.atomic import claim_folder
from metalens_cli.io.image_files import write_png

SIM = ["simulate", "hyperbolic:532nm", "--f", "1mm", "--aperture", "0.1mm", "--pixels", "32"]
SIM += ["--wavelengths", "520nm,540nm", "--quiet", "--json"]


def test_a_held_folder_is_refused_to_a_second_claim_and_free_once_released(tmp_path):
    out = tmp_path / "a" / "b" / "out"
    with claim_folder(out, "--output"):
        with pytest.raises(InputError, match="being written by another run") as error:
            with claim_folder(out, "--output"):
                pass
        assert error.value.field == "--output" and "--overwrite" in error.value.expected
    with claim_folder(out, "--output"):  # released: claimed again
        pass
    assert not (tmp_path / "a").exists()  # the parents it made, left empty, are gone with the lock


def test_a_killed_holder_does_not_block_the_next_run(tmp_path):
    out = tmp_path / "out"
    code = (
        "from metalens_cli.io.atomic import claim_folder\n"
        f"with claim_folder({str(out)!r}, '-o'):\n    print('held', flush=True)\n    input()"
    )
    holder = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert holder.stdout.readline().strip() == "held"
    with pytest.raises(InputError, match="being written"):
        with claim_folder(out, "--output"):
            pass
    holder.send_signal(signal.SIGKILL)
    holder.wait()
    assert (tmp_path / ".out.metalens-lock").exists()  # left by the killed run ...
    with claim_folder(out, "--output"):  # ... and taken over
        pass
    assert not (tmp_path / ".out.metalens-lock").exists()


@pytest.fixture
def images(tmp_path):
    folder = tmp_path / "images"
    folder.mkdir()
    write_png(folder / "a.png", np.random.default_rng(0).random((40, 40, 3)).astype(np.float32))
    return folder


def test_two_simulate_runs_started_together_leave_one_whole_run(tmp_path, images):
    out = tmp_path / "out"
    runs = [
        subprocess.Popen(
            [sys.executable, "-m", "metalens_cli", *SIM, "--images", str(images), "--seed", str(seed), "-o", str(out)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for seed in (0, 1)
    ]
    results = [(p.wait(timeout=300), *p.communicate()) for p in runs]
    codes = sorted(code for code, _, _ in results)
    assert codes == [0, 2], results
    winner = next(i for i, (code, _, _) in enumerate(results) if code == 0)
    refusal = results[1 - winner][2]
    assert str(out) in refusal and "--overwrite" in refusal and len(refusal.strip().splitlines()) == 1
    assert json.loads((out / "simulate.json").read_text())["seed"] == winner
    assert sorted(p.name for p in tmp_path.iterdir()) == ["images", "out"]  # no lock, no staging left


def test_every_command_that_writes_a_folder_holds_it(tmp_path, images, capsys):
    """The same refusal through the CLI for each folder writer, while a run holds the folder."""
    tiny = Path(__file__).parents[1] / "design" / "tiny.toml"
    commands = {
        "simulate": [*SIM, "--images", str(images)],
        "optimize": ["optimize", str(tiny), "--quiet"],
        "reconstruct apply": ["reconstruct", "apply", "runs/none", str(images)],
        "nanofin sweep": ["nanofin", "sweep", "--width", "300nm", "--length", "100nm"],
        "reconstruct train": ["reconstruct", "train", "hyperbolic:532nm"],
        "align": ["align", str(images), str(images)],
    }
    for name, command in commands.items():
        out = tmp_path / name.replace(" ", "-")
        with claim_folder(out, "--output"):
            code = run([*command, "-o", str(out)])
            err = capsys.readouterr().err
        assert code == 2 and "being written by another run" in err and str(out) in err, (name, err)


def test_optimize_under_its_default_run_directory_is_held_too(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    tiny = Path(__file__).parents[1] / "design" / "tiny.toml"
    with claim_folder(Path("runs") / "tiny", "--output"):
        assert run(["optimize", str(tiny), "--quiet"]) == 2
    assert "being written by another run" in capsys.readouterr().err
