"""Benchmark: a training step's scenes and obstructions drawn with torch on a device
(``[optimize] scene_generator = "torch"``, ``design.device_scenes``) against numpy on the host.

For the quick preset (batch 2, 128² crop; canvas margin ``--quick-margin``, a learned lens's far
windows in training) and the paper-size preset (batch 1, 512²; ``--paper-margin``): the median
seconds of a step's batch (``design.step.step_batch``) over ``--draws`` steps, drawn three ways:
numpy at every pixel, numpy at the halo's blocks (``scene_blocks``), and torch on ``--device``
(on CUDA the time until the device has finished). The first draw of each way is not timed.

Run: python benchmarks/bench_device_scenes.py [--device cpu|cuda] [--threads 2] [--draws 6]
Rewrites its section of docs/benchmarks.md (``device-scenes-DEVICE``).
"""

from __future__ import annotations

import argparse
import dataclasses
import platform
import statistics
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
WAYS = {  # [optimize] keys of each way; where the batch is drawn
    "numpy, every pixel": ({"scene_generator": "numpy", "scene_blocks": False}, "host"),
    "numpy, halo blocks": ({"scene_generator": "numpy", "scene_blocks": True}, "host"),
    "torch": ({"scene_generator": "torch"}, "device"),
}


def seconds(preset, margin: int, draws: int, device: str) -> tuple[float, float]:
    """Median seconds of a step's batch of ``preset`` on the canvas of ``margin``: until the host has
    queued it, and until the device has finished it (the same on a CPU)."""
    from metalens_cli.design.step import near_depth, step_batch

    o = preset.optimize
    queued, done = [], []
    for step in range(draws + 1):
        start = time.perf_counter()
        step_batch(
            preset, o.seed, step, list(range(o.batch_size)), near_depth(preset, o.seed, step), None, margin, device
        )
        queued.append(time.perf_counter() - start)
        if device.startswith("cuda"):
            torch.cuda.synchronize()
        done.append(time.perf_counter() - start)
    return statistics.median(queued[1:]), statistics.median(done[1:])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--draws", type=int, default=6)
    parser.add_argument("--quick-margin", type=int, default=580)
    parser.add_argument("--paper-margin", type=int, default=283)
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT))
    from benchmarks.report import write_section
    from metalens_cli.io.presets import load_preset

    torch.set_num_threads(args.threads)
    lines = []
    for name, margin in (("quick-split-spectrum", args.quick_margin), ("split-spectrum", args.paper_margin)):
        preset = load_preset(ROOT / "presets" / f"{name}.toml")
        o = preset.optimize
        row = [f"{name} (batch {o.batch_size}, {preset.sensor.pixels}² + {margin} px margin)"]
        for keys, where in WAYS.values():
            way = dataclasses.replace(preset, optimize=dataclasses.replace(o, **keys))
            queued, done = seconds(way, margin, args.draws, args.device if where == "device" else "cpu")
            row.append(
                f"{done:.3f}"
                + (f" (queued in {queued:.3f})" if where == "device" and args.device.startswith("cuda") else "")
            )
            print(name, keys, row[-1], file=sys.stderr, flush=True)
        lines.append("| " + " | ".join(row) + " |")
    device = torch.cuda.get_device_name() if args.device.startswith("cuda") else f"{platform.machine()} CPU"
    write_section(
        f"device-scenes-{args.device.split(':')[0]}",
        "\n".join(
            [
                f"## A step's scenes and obstructions on the device, {args.device} "
                "(`python benchmarks/bench_device_scenes.py`)",
                "",
                f"{device}, {args.threads} torch threads; the median seconds of a step's batch (clean scenes, "
                f"obstruction colours and masks on the canvas) over {args.draws} steps after the first. numpy: on the "
                f"host (`design.scenes`, `imaging.obstructions`); torch: `design.device_scenes` on {args.device} "
                "(on an accelerator also the seconds until the host had queued the batch: the host's share, which "
                "bounds a step whose device work is shorter).",
                "",
                "| preset | " + " | ".join(f"{way} s" for way in WAYS) + " |",
                "|---|" + "---|" * len(WAYS),
                *lines,
            ]
        ),
    )


if __name__ == "__main__":
    main()
