"""One results file for every benchmark: each script replaces its own section of docs/benchmarks.md.

A section lies between ``<!-- bench:NAME -->`` and ``<!-- /bench:NAME -->``; a missing one is
appended, the others are left untouched, so the benchmarks can be re-run one at a time.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

RESULTS = Path(__file__).resolve().parents[1] / "docs" / "benchmarks.md"
TITLE = (
    "# Benchmarks\n\nMeasured on this project's machines (2 CPU cores). Each section names the command that "
    "produced it.\n"
)


def write_section(name: str, markdown: str, path: Path = RESULTS) -> Path:
    """Replace (or append) section ``name`` of ``path`` with ``markdown``."""
    block = f"<!-- bench:{name} -->\n{markdown.strip()}\n<!-- /bench:{name} -->"
    text = path.read_text(encoding="utf-8") if path.exists() else TITLE
    pattern = re.compile(rf"<!-- bench:{re.escape(name)} -->.*?<!-- /bench:{re.escape(name)} -->", re.S)
    text = pattern.sub(lambda _: block, text) if pattern.search(text) else text.rstrip() + "\n\n" + block + "\n"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return path


def run_in_checkout(checkout: Path, worker: str, options: dict, label: str) -> dict:
    """Run the Python source ``worker`` with ``json.dumps(options)`` as its argument in a process
    that imports the package from ``checkout`` (ahead of any PYTHONPATH already set); return the
    JSON object its last line of output prints. The worker reports the ``module`` it imported,
    which must lie in ``checkout``."""
    print(f"{label} ...", file=sys.stderr, flush=True)
    path = os.pathsep.join(filter(None, [str(checkout), os.environ.get("PYTHONPATH")]))
    done = subprocess.run(
        [sys.executable, "-c", worker, json.dumps(options)],
        cwd=checkout,
        env={**os.environ, "PYTHONPATH": path},
        check=True,
        capture_output=True,
        text=True,
    )
    result = json.loads(done.stdout.strip().splitlines()[-1])
    if not result["module"].startswith(str(checkout)):
        raise SystemExit(f"{label}: imported {result['module']}, not the checkout's")
    return result
