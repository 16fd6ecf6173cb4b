"""Target layouts on disk: ``NAME.targets.json`` beside a board or reference image.

Format ``metalens-targets/1``: {"format", "pixels": [H, W] of the image the corners refer to,
"targets": [{"task", "key", "size_px", "corners": [[x, y] × 4], "footprint": [x0, y0, width, height]}]},
corners in that image's pixels (pixel centres at integers, clockwise from the code's top-left;
``imaging.targets``). Written by ``metalens board``; read by ``evaluate --pairs DIR --task``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from metalens_cli.errors import InputError
from metalens_cli.io.input_files import read_text
from metalens_cli.io.json_files import write_json

FORMAT = "metalens-targets/1"
SUFFIX = ".targets.json"
FORM = f"a {FORMAT} file (metalens board writes one)"


def targets_path(image: Path) -> Path:
    """The layout file beside ``image``: ``NAME.targets.json``."""
    return Path(image).with_name(Path(image).stem + SUFFIX)


def write_targets(path: Path, pixels_hw: tuple[int, int], records: list[dict]) -> None:
    """Write a layout (``records`` as :func:`read_targets` returns them), atomically."""
    write_json(path, {"format": FORMAT, "pixels": list(pixels_hw), "targets": records})


def read_targets(path: Path, field: str) -> tuple[tuple[int, int], list[dict]]:
    """((H, W), records) of a layout file, each record checked: ``task`` and ``key`` text,
    ``size_px`` > 0, ``corners`` 4 × 2 finite, ``footprint`` four integers."""
    try:
        data = json.loads(read_text(path, field, FORM))
        if data.get("format") != FORMAT:
            raise ValueError(f"format {data.get('format')!r}")
        h, w = (int(v) for v in data["pixels"])
        records = []
        for item in data["targets"]:
            corners = np.asarray(item["corners"], dtype=np.float64)
            footprint = [int(v) for v in item["footprint"]]
            if corners.shape != (4, 2) or not np.isfinite(corners).all() or not float(item["size_px"]) > 0:
                raise ValueError(f"target {item.get('key')!r}")
            if len(footprint) != 4 or min(footprint) < 0:
                raise ValueError(f"target {item.get('key')!r}")
            records.append(
                {
                    "task": str(item["task"]),
                    "key": str(item["key"]),
                    "size_px": float(item["size_px"]),
                    "corners": corners.tolist(),
                    "footprint": footprint,
                }
            )
    except (ValueError, KeyError, TypeError, AttributeError) as error:
        raise InputError(field, f"{Path(path).name}: {error}", FORM) from None
    return (h, w), records
