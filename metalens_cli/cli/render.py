"""Rendering results: JSON on stdout, rich tables, and lazily imported plotting.

Rich and matplotlib are imported only when used, so JSON pipelines start fast.
"""

from __future__ import annotations

import json
import sys
from typing import Any

from metalens_cli.io.json_files import jsonable


def emit_json(obj: Any) -> None:
    """Write one JSON object and a newline to stdout."""
    sys.stdout.write(json.dumps(jsonable(obj), allow_nan=False) + "\n")


def console(stderr: bool = False):
    """A rich console on stdout (results) or stderr (messages); 120 columns when piped, so
    tables are not truncated to the 80-column default in logs and CI."""
    from rich.console import Console

    stream = sys.stderr if stderr else sys.stdout
    return Console(stderr=stderr, highlight=False, width=None if stream.isatty() else 120)


def say(lines, kind: str = "warning") -> None:
    """Each of ``lines`` as one stderr line ``metalens: KIND: …`` (the prefix every message
    of the tool carries, docs/failures.md)."""
    err = console(stderr=True)
    for line in lines:
        err.print(f"metalens: {kind}: {line}", markup=False, soft_wrap=True)


TEXT_COLUMNS = {"note", "condition", "holds", "band", "key", "value", "design", "obstruction", "kind"}


def table(title: str, columns: list[str], rows: list[list[str]]):
    """A rich table with right-aligned numeric-looking columns."""
    from rich.table import Table

    t = Table(title=title, title_justify="left")
    for name in columns:
        t.add_column(name, justify="left" if name in TEXT_COLUMNS else "right")
    for row in rows:
        t.add_row(*row)
    return t


def nm(value_m: float | None, digits: int = 2) -> str:
    """Format a wavelength in nm."""
    return "—" if value_m is None else f"{value_m * 1e9:.{digits}f}"
