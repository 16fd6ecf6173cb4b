"""Crash consistency (issue 29): SIGKILL — the OOM killer, a CI job cancelled hard — cannot be
caught, so what a killed command leaves must be safe by construction. Each case below runs a
command once to the end (the reference), then kills fresh runs of it with SIGKILL at seeded
random moments over that duration (at least 50 kills in all) and checks what is left:

- no partial output is published: an output file is absent or whole (the reference's content),
  an output folder is absent or holds every file the reference holds;
- no cache entry is corrupt: the same command afterwards reads the cache without a warning and
  gives the reference's answer;
- a training run resumes: ``--resume`` (or, if the kill came before the run's preset was written,
  a fresh run in the same folder, which must accept it) ends with the reference's final θ or
  weights, bit for bit.

Hidden temporary files (``.metalens-*.tmp*``) may remain, as docs/failures.md says.
"""

from __future__ import annotations

import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).parents[1]
TINY = ROOT / "tests" / "design" / "tiny.toml"
TINY_RECONSTRUCT = ROOT / "tests" / "design" / "tiny_reconstruct.toml"
LENS = ["--f", "1mm", "--aperture", "0.2mm"]
KILLS = 10  # per case; five cases
SEED = 29

pytestmark = pytest.mark.slow


def _command(args: list[str], env: dict) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "metalens_cli", *map(str, args)],
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _finish(args: list[str], env: dict) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "metalens_cli", *map(str, args)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )


def _environment(cache: Path) -> dict:
    return {**os.environ, "METALENS_CACHE": str(cache), "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}


def _visible(folder: Path) -> list[str]:
    """The names a reader sees in ``folder`` (temporaries left by a kill are hidden)."""
    return sorted(p.name for p in folder.iterdir() if not p.name.startswith(".metalens-"))


def _kill_at(args: list[str], env: dict, seconds: float) -> None:
    process = _command(args, env)
    try:
        process.wait(timeout=seconds)
    except subprocess.TimeoutExpired:
        process.send_signal(signal.SIGKILL)
    process.communicate()


def _reference(args: list[str], env: dict) -> tuple[subprocess.CompletedProcess, float]:
    t0 = time.perf_counter()
    done = _finish(args, env)
    assert done.returncode == 0, done.stderr
    return done, time.perf_counter() - t0


def _kill_times(case: str, duration: float) -> list[float]:
    """Moments spread over the whole run (start-up included) and a little past it: fractions of
    ``duration`` drawn from (SEED, case), the same on every machine."""
    rng = random.Random(f"{SEED}:{case}")
    return sorted(rng.uniform(0.05, 1.05) * duration for _ in range(KILLS))


def _theta(run: Path) -> np.ndarray:
    return np.load(run / "theta.npy")


def _weights(run: Path) -> dict:
    import torch

    return torch.load(run / "model.pt", weights_only=True)["state_dict"]


TRAININGS = {
    "optimize": (
        ["optimize", TINY, "--steps", "6", "--threads", "1", "--quiet"],
        "preset.toml",
        _theta,
        lambda a, b: np.array_equal(a, b),
    ),
    "reconstruct train": (
        ["reconstruct", "train", "hyperbolic:532nm", *LENS, "--preset", TINY_RECONSTRUCT, "--threads", "1", "--quiet"],
        "reconstruct.toml",
        _weights,
        lambda a, b: a.keys() == b.keys() and all((a[k] == b[k]).all() for k in a),
    ),
}


@pytest.mark.parametrize("name", TRAININGS)
def test_a_killed_training_run_resumes_to_the_same_result(name, tmp_path):
    args, preset_file, result, same = TRAININGS[name]
    env = _environment(tmp_path / "cache")
    _, duration = _reference([*args, "-o", tmp_path / "reference"], env)
    expected = result(tmp_path / "reference")
    for i, moment in enumerate(_kill_times(name, duration)):
        run = tmp_path / f"killed-{i}"
        _kill_at([*args, "-o", run], env, moment)
        if (run / preset_file).is_file():
            done = _finish([*args, "-o", run, "--resume"], env)
        else:  # killed before the run existed: its folder is absent or holds no file a reader sees
            assert not run.exists() or not any(
                p for p in run.rglob("*") if p.is_file() and not p.name.startswith(".metalens-")
            )
            done = _finish([*args, "-o", run], env)
        assert done.returncode == 0, f"kill at {moment:.2f} s: {done.stderr}"
        assert same(result(run), expected), f"kill at {moment:.2f} s of {duration:.2f} s: not the uninterrupted result"


def _gds_whole(path: Path, reference: Path) -> bool:
    """A whole GDSII library: the reference's length, ending in ENDLIB (its timestamps differ)."""
    data = path.read_bytes()
    return len(data) == reference.stat().st_size and data.endswith(bytes.fromhex("00040400"))


def _same_cube(path: Path, reference: Path) -> bool:
    """The reference's PSFs, every pixel (the header's timings differ)."""
    from metalens_cli.io.exr import read_exr_cube

    return np.array_equal(read_exr_cube(path).psf, read_exr_cube(reference).psf)


FILES = {
    "psf-scan": (
        [
            "psf-scan",
            "--design",
            "hyperbolic:532nm",
            *LENS,
            "--pixels",
            "256",
            "--wavelengths",
            "430:650:2nm",
            "--depths",
            "10mm,inf",
            "--quiet",
        ],
        "cube.exr",
        _same_cube,
    ),
    "export-gds": (
        [
            "export-gds",
            "--design",
            "hyperbolic:532nm",
            "--f",
            "1mm",
            "--aperture",
            "0.6mm",
            "--pitch",
            "395nm",
            "--width",
            "200nm",
            "--length",
            "100nm",
            "--quiet",
        ],
        "lens.gds",
        _gds_whole,
    ),
}


@pytest.mark.parametrize("name", FILES)
def test_a_killed_writer_publishes_a_whole_file_or_none(name, tmp_path):
    args, file_name, whole = FILES[name]
    env = _environment(tmp_path / "cache")
    reference = tmp_path / "reference" / file_name
    reference.parent.mkdir()
    _, duration = _reference([*args, "-o", reference], env)
    for i, moment in enumerate(_kill_times(name, duration)):
        folder = tmp_path / f"killed-{i}"
        folder.mkdir()
        _kill_at([*args, "-o", folder / file_name], env, moment)
        assert _visible(folder) in ([], [file_name]), _visible(folder)
        if _visible(folder):
            assert whole(folder / file_name, reference), f"kill at {moment:.2f} s: a partial {file_name} was published"
        shutil.rmtree(folder)  # a layout is 116 MB


SWEEP = [
    "nanofin",
    "sweep",
    "--width",
    "250nm,300nm",
    "--length",
    "100nm,150nm",
    "--harmonics",
    "3",
    "--max-harmonics",
    "9",
    "--band",
    "530nm:20nm",
    "--json",
    "--quiet",
]


def _recommended(done: subprocess.CompletedProcess) -> dict:
    fin = json.loads(done.stdout)["recommended"]
    return {k: v for k, v in fin.items() if "second" not in k and k != "converged"} | {
        "eta": fin["converged"]["eta_per_band"],
        "harmonics": fin["converged"]["harmonics"],
    }


def test_a_killed_sweep_leaves_no_partial_folder_and_no_corrupt_cache(tmp_path):
    """Each kill gets an empty cache of its own, so kills land while its entries are written."""
    reference, duration = _reference([*SWEEP, "-o", tmp_path / "reference"], _environment(tmp_path / "reference-cache"))
    files = _visible(tmp_path / "reference")
    for i, moment in enumerate(_kill_times("nanofin sweep", duration)):
        env = _environment(tmp_path / f"cache-{i}")
        out = tmp_path / f"killed-{i}"
        _kill_at([*SWEEP, "-o", out], env, moment)
        assert not out.exists() or _visible(out) == files, f"kill at {moment:.2f} s left {_visible(out)}"
        again = _finish([*SWEEP, "-o", tmp_path / f"again-{i}"], env)
        assert again.returncode == 0 and "CacheWarning" not in again.stderr, again.stderr
        assert _recommended(again) == _recommended(reference)
