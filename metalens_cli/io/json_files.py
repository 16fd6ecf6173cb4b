"""Strict JSON for reports and run files: non-finite floats become null; files written atomically."""

from __future__ import annotations

import json
import math
import os
from typing import Any

from metalens_cli.io.atomic import atomic_write


def jsonable(obj: Any) -> Any:
    """Replace non-finite floats by None (JSON has no inf/NaN) recursively."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    return obj


def write_json(path: str | os.PathLike[str], obj: Any) -> None:
    """Write ``obj`` as indented strict JSON to ``path`` (temporary file, then rename)."""
    with atomic_write(path) as temporary:
        temporary.write_text(json.dumps(jsonable(obj), indent=2, allow_nan=False) + "\n", encoding="utf-8")
