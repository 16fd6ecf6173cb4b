"""One results file for every benchmark: each script replaces its own section of docs/benchmarks.md.

A section lies between ``<!-- bench:NAME -->`` and ``<!-- /bench:NAME -->``; a missing one is
appended, the others are left untouched, so the benchmarks can be re-run one at a time.
"""

from __future__ import annotations

import re
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
