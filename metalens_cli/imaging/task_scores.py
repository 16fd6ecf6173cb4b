"""Task scores of an evaluation: how often each design's captures let a detector find the targets.

Per task × design × capture × obstruction × condition (and light level), over the units (image,
seed): the found rate (the mean over units of each unit's fraction of its targets found, with its
95 % bootstrap CI), wrong detections per unit, the median corner error of the targets found, and
size50 (``analysis.size50``). The clean scenes give the ceiling (design "clean"). Paired
differences of the found rate: design against design on the same capture, and each design's
restorations against its raw capture.
"""

from __future__ import annotations

import numpy as np

from metalens_cli.analysis.size50 import size50
from metalens_cli.analysis.statistics import mean_ci, paired_difference_ci
from metalens_cli.imaging.targets import SIZE_MEANING
from metalens_cli.imaging.task_detection import Outcome

CONDITIONS = ("unobstructed", "obstructed")


def task_row(task: str, outcomes: list[Outcome], targets: list[list], labels: dict) -> dict:
    """One row: ``labels`` plus the scores of ``outcomes`` (one per unit) of the units' ``targets``
    (each unit's targets of ``task``, in the outcome's order)."""
    rates = [_fraction(o) for o in outcomes]
    found = np.concatenate([o.found for o in outcomes])
    sizes = np.array([t.size_px for unit in targets for t in unit])
    units = np.repeat(np.arange(len(outcomes)), [len(unit) for unit in targets])
    errors = np.concatenate([o.corner_error_px[o.found] for o in outcomes])
    rate = mean_ci(rates, metric="found_rate")
    wrong = mean_ci([float(o.wrong) for o in outcomes], metric="wrong_per_unit")
    fit = size50(sizes, found, units)
    return {
        "task": task,
        **labels,
        "n": len(outcomes),
        "targets": int(found.size),
        "found_rate": rate["mean"],
        "found_rate_ci": rate["ci"],
        "wrong_per_unit": wrong["mean"],
        "wrong_per_unit_ci": wrong["ci"],
        "corner_error_px": float(np.median(errors)) if errors.size else None,
        "size50": fit["size50"],
        "size50_ci": fit["ci"],
        "size50_bound": fit["bound"],
        "size_unit": SIZE_MEANING[task],
        **(_text_scores(outcomes) if task == "text" else {}),
    }


def _text_scores(outcomes: list[Outcome]) -> dict:
    """Text's line recall (detected at IoU ≥ 0.5) and character error rate, means over units with CIs."""
    out = {}
    for name, values in (
        ("line_recall", [float(o.detected.mean()) if o.detected.size else 0.0 for o in outcomes]),
        ("cer", [float(o.cer.mean()) if o.cer.size else 1.0 for o in outcomes]),
    ):
        stats = mean_ci(values, metric=name)
        out[name], out[f"{name}_ci"] = stats["mean"], stats["ci"]
    return out


def summarise_tasks(
    tasks, specs, captures_of, kinds, units, outcomes: dict, clean: dict, targets: dict, light: str | None = None
) -> tuple[list[dict], list[dict]]:
    """(rows, comparisons) of one camera.

    Args:
        tasks: the task names.
        specs: the designs' specs; ``captures_of[d]`` the captures design d was scored on.
        kinds: obstruction kinds.
        units: the (seed, image index) units, in order.
        outcomes: ``outcomes[capture, d, kind or "unobstructed", seed, index][task]``.
        clean: ``clean[seed, index][task]``: the clean scene's outcomes (the ceiling).
        targets: ``targets[seed, index]``: the unit's drawn targets.
        light: the camera's label (added to every entry), None for none.
    """
    extra = {} if light is None else {"light": light}
    rows, comparisons = [], []
    for task in tasks:
        drawn = [[t for t in targets[u] if t.task == task] for u in units]

        def rate(capture, d, kind, condition, task=task):
            key = "unobstructed" if condition == "unobstructed" else kind
            return [outcomes[capture, d, key, *u][task] for u in units]

        rows.append(
            task_row(
                task,
                [clean[u][task] for u in units],
                drawn,
                {"design": "clean", "capture": "clean", "obstruction": None, "condition": "clean", **extra},
            )
        )
        cells = [(capture, d) for d in range(len(specs)) for capture in captures_of[d]]
        for kind in kinds:
            for capture, d in cells:
                for condition in CONDITIONS:
                    labels = {"design": specs[d], "capture": capture, "obstruction": kind, "condition": condition}
                    rows.append(task_row(task, rate(capture, d, kind, condition), drawn, {**labels, **extra}))
            for first, second in compared_pairs(cells):
                for condition in CONDITIONS:
                    x, y = ([_fraction(o) for o in rate(*cell, kind, condition)] for cell in (first, second))
                    stats = paired_difference_ci(x, y, metric="found_rate")
                    comparisons.append(
                        {
                            "task": task,
                            "design": specs[first[1]],
                            "capture": first[0],
                            "versus": specs[second[1]],
                            "versus_capture": second[0],
                            "obstruction": kind,
                            "condition": condition,
                            "metric": "found_rate",
                            "difference": stats["mean"],
                            "ci": stats["ci"],
                            "n": stats["n"],
                            **extra,
                        }
                    )
    return rows, comparisons


def compared_pairs(cells: list[tuple[str, int]]) -> list[tuple[tuple[str, int], tuple[str, int]]]:
    """The (first, second) cells (capture, design index) compared: designs on the same capture,
    and each design's restorations against its raw capture (recon − raw, wiener − raw, recon − wiener)."""
    pairs = [(a, b) for i, a in enumerate(cells) for b in cells[i + 1 :] if a[0] == b[0] or a[1] == b[1]]
    return [((b, a) if a[1] == b[1] else (a, b)) for a, b in pairs]


def _fraction(outcome: Outcome) -> float:
    """The fraction of a unit's targets found."""
    return float(outcome.found.mean()) if outcome.found.size else 0.0


def unit_tasks(targets: list, unobstructed: dict, obstructed: dict) -> dict:
    """One unit's task outcomes for its JSON entry: per task the targets' keys and sizes, and per
    condition which were found, their corner errors (px, None where not found) and the wrong
    detections."""
    out = {}
    for task, clear in unobstructed.items():
        drawn = [t for t in targets if t.task == task]
        out[task] = {
            "keys": [t.key for t in drawn],
            "sizes": [t.size_px for t in drawn],
            **{
                condition: {
                    "found": o.found.tolist(),
                    "corner_error_px": [None if np.isnan(e) else float(e) for e in o.corner_error_px],
                    "wrong": o.wrong,
                    **({} if o.cer is None else {"detected": o.detected.tolist(), "cer": o.cer.tolist()}),
                }
                for condition, o in (("unobstructed", clear), ("obstructed", obstructed[task]))
            },
        }
    return out
