"""torchrun data parallel (gloo, 2 CPU processes) against one process with the same global batch."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

TINY = Path(__file__).with_name("tiny.toml")


def _optimize(launcher: list[str], out: Path) -> np.ndarray:
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    cmd = launcher + ["-m", "metalens_cli", "optimize", str(TINY), "-o", str(out), "--steps", "3", "--threads", "1", "--quiet"]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    return np.load(out / "theta.npy")


def test_two_process_torchrun_equals_one_process(tmp_path):
    single = _optimize([sys.executable], tmp_path / "one")
    torchrun = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "2"]
    parallel = _optimize(torchrun, tmp_path / "two")
    # same draws, batch split 1 + 1, gradients summed by all_reduce: only the summation order
    # differs (float32 PSFs and FFTs, float64 θ): a gradient moves by ~1e-7 relative, and AdamW's
    # normalised step turns that into ≤ a few 1e-6 rad on |θ| ≤ 30 rad over 3 steps
    np.testing.assert_allclose(parallel, single, rtol=0, atol=1e-5)
    from metalens_cli.design.training import build_model
    from metalens_cli.io.presets import load_preset

    initial = build_model(load_preset(TINY)).full_theta().detach().numpy()
    assert np.abs(single - initial).max() > 1e-3  # the comparison is between runs that learned something
