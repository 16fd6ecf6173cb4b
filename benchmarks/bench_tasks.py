"""Benchmark: what scoring a vision task adds to a capture (``evaluate --task``).

Per task: the median seconds to score one capture (auto-levels, 8-bit sRGB, the detector, the
match against the drawn targets; ``imaging.task_detection.score_tasks``) and to place and draw the
unit's targets into the clean scene (``imaging.targets.layout`` and ``draw_targets``: the first
time a unit's targets are rendered; later draws, for the other designs and obstructions, reuse
the cached renderings), over the evaluation photographs
with their targets, sharp and blurred by a Gaussian of σ = 1, 2 and 4 px (a detector's work
depends on what it finds); with the found rate at each blur.

Run: python benchmarks/bench_tasks.py [--pixels 512] [--repeats 3]
Rewrites its section of docs/benchmarks.md. Its per-megapixel figures are the estimate
``evaluate`` announces (``imaging.task_detection.SECONDS_PER_MEGAPIXEL``).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BLURS = (0.0, 1.0, 2.0, 4.0)


def measure(pixels: int, repeats: int) -> list[dict]:
    """One row per task and blur: median seconds of scoring a capture and of drawing a unit's targets."""
    import cv2

    from metalens_cli.imaging.images import load_images
    from metalens_cli.imaging.targets import TASKS, draw_targets, layout
    from metalens_cli.imaging.task_detection import score_tasks

    images = load_images("photos", (pixels, pixels))
    rows = []
    for task in TASKS:
        for sigma in BLURS:
            score_times, draw_times, found = [], [], []
            for index, image in enumerate(images):
                start = time.perf_counter()
                targets = layout((task,), (pixels, pixels), 0, index)
                scene = draw_targets(image, targets).sensor
                draw_times.append(time.perf_counter() - start)
                if sigma:
                    scene = np.stack([cv2.GaussianBlur(c, (0, 0), sigma) for c in scene])
                for _ in range(repeats):
                    start = time.perf_counter()
                    outcome = score_tasks(scene, targets, (task,))[task]
                    score_times.append(time.perf_counter() - start)
                found.append(outcome.found.mean())
            rows.append(
                {
                    "task": task,
                    "sigma": sigma,
                    "score_s": statistics.median(score_times),
                    "draw_s": statistics.median(draw_times),
                    "found": float(np.mean(found)),
                    "images": len(images),
                }
            )
            print(rows[-1], file=sys.stderr, flush=True)
    return rows


def markdown(rows: list[dict], pixels: int, repeats: int) -> str:
    """The section of docs/benchmarks.md."""
    lines = [
        "## Vision tasks: scoring a capture (`evaluate --task`)",
        "",
        f"`python benchmarks/bench_tasks.py --pixels {pixels} --repeats {repeats}`: the {rows[0]['images']} evaluation "
        f"photographs at {pixels}², each with one unit's targets, sharp and blurred; median over images × repeats, "
        "2 CPU cores. Issue 55's targets: ≤ 20 ms a 512² capture for markers and QR codes.",
        "",
        "| task | blur σ (px) | score a capture | place and draw the targets (σ = 0: first rendering) | found |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['task']} | {r['sigma']:g} | {1e3 * r['score_s']:.1f} ms | {1e3 * r['draw_s']:.1f} ms | "
            f"{r['found']:.2f} |"
        )
    per_mp = {
        task: statistics.median(r["score_s"] for r in rows if r["task"] == task) / (pixels**2 / 1e6)
        for task in dict.fromkeys(r["task"] for r in rows)
    }
    lines += [
        "",
        "Per megapixel (median over the blurs; what `evaluate` estimates with): "
        + ", ".join(f"{task} {s:.3f} s" for task, s in per_mp.items())
        + ".",
    ]
    return "\n".join(lines)


def main() -> None:
    """Measure and rewrite the section."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pixels", type=int, default=512)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    rows = measure(args.pixels, args.repeats)
    sys.path.insert(0, str(Path(__file__).parent))
    from report import write_section

    write_section("tasks", markdown(rows, args.pixels, args.repeats))


if __name__ == "__main__":
    main()
