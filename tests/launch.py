"""``metalens`` in a subprocess, as one process or as two torchrun ranks (gloo), for the tests
that compare data-parallel training with a single process."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings
from pathlib import Path

TORCHRUN = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "2"]


def run_metalens(args: list[str], out: Path, *, ranks: int = 1) -> Path:
    """Run ``metalens ARGS -o OUT --threads 1 --quiet`` (one thread per process), assert that it
    succeeded and return the run directory it wrote.

    With ``ranks=2`` it runs under torchrun and keeps each rank's stdout and stderr beside ``out``
    (torchrun's own summary names a failed rank's signal, not what the rank printed). A rank that
    dies by SIGABRT without a Python error crashed in native code below this package, most likely
    torch's gloo backend at teardown ("terminate called without an active exception"; seen a few
    times in CI and fresh venvs, not reproduced in ~100 runs here): that run is repeated once, in a
    fresh folder, with a warning that carries its logs. torchrun then stops the other rank with
    SIGTERM, whose ``Terminated`` traceback is not a Python error of the run. Any other failure, or
    a second crash, fails.
    """
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONFAULTHANDLER": "1"}  # a native crash prints the Python stack

    def attempt(folder: Path) -> tuple[subprocess.CompletedProcess, str]:
        logs = folder.with_name(folder.name + "-logs")
        launcher = [sys.executable] if ranks == 1 else [*TORCHRUN, "--log-dir", str(logs), "--redirects", "3"]
        cmd = [*launcher, "-m", "metalens_cli", *args, "-o", str(folder), "--threads", "1", "--quiet"]
        done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
        return done, _rank_logs(logs)

    done, logs = attempt(out)
    python_errors = logs.count("Traceback (most recent call last)") - logs.count("metalens_cli.errors.Terminated")
    native_crash = "exitcode  : -6" in done.stderr and python_errors <= 0
    if ranks > 1 and done.returncode != 0 and native_crash:
        warnings.warn(f"torchrun: a rank aborted in native code; repeated once. Its logs:\n{logs}", stacklevel=2)
        out = out.with_name(out.name + "-again")
        done, logs = attempt(out)
    assert done.returncode == 0, logs + done.stderr[-1500:]
    return out


def _rank_logs(folder: Path) -> str:
    """The non-empty std*.log files torchrun wrote under ``folder`` (LOG_DIR/run/attempt/rank/)."""
    if not folder.is_dir():
        return ""
    return "\n".join(
        f"--- {p.relative_to(folder)}:\n{text[-3000:]}"
        for p in sorted(folder.rglob("std*.log"))
        if (text := p.read_text(errors="replace")).strip()
    )
