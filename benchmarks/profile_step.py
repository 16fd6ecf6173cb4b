"""Profile: where a training step of a preset spends its time, by stage and by operator.

Run: python benchmarks/profile_step.py [PRESET] [--device cpu|cuda] [--threads 2] [--warmup 40] [--steps 8]
[--pool auto|on|off]
Runs ``--warmup`` steps (the windows grow with the lens, and the kernels' plan with them), then
profiles ``--steps`` more with ``torch.profiler``: seconds per step by stage (on CUDA each stage
waits for the device) and the operators that took the most self time (device time on CUDA),
grouped by input shape; then the time a step spends outside torch's operators (Python, numpy, the
host's share of the scenes and obstructions: what a GPU would wait for) and, on CUDA, the share of
the step the device is busy. Each step's scenes are drawn ahead on the scene pool's thread where a
run would (``design.scene_pool.draws_ahead``; the stage ``scenes`` is then the wait), or with
``--pool off`` in the step. Prints; writes nothing.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch
from torch.profiler import ProfilerActivity, profile

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("preset", nargs="?", default=str(ROOT / "presets" / "quick-split-spectrum.toml"))
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--warmup", type=int, default=40)
    parser.add_argument("--steps", type=int, default=8)
    parser.add_argument("--rows", type=int, default=25)
    parser.add_argument(
        "--pool", choices=("auto", "on", "off"), default="auto", help="scenes drawn ahead (auto: as a run would)"
    )
    args = parser.parse_args()

    from metalens_cli.design import distributed
    from metalens_cli.design.scene_pool import draws_ahead
    from metalens_cli.design.step import one_step
    from metalens_cli.design.training import _session
    from metalens_cli.io.presets import load_preset
    from metalens_cli.runtime import Stopwatch

    torch.set_num_threads(args.threads)
    preset = load_preset(args.preset)
    device = torch.device(args.device)
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device.type == "cuda" else [])
    with distributed.session(device) as ctx:
        ahead = draws_ahead(device) if args.pool == "auto" else args.pool == "on"
        session = _session(preset, ctx, ahead, args.warmup + args.steps)
        with session.scenes:
            for step in range(args.warmup):
                one_step(session, preset, step, ctx, Stopwatch(device))
            watch = Stopwatch(device)
            start = time.perf_counter()
            with profile(activities=activities, record_shapes=True) as prof:
                for step in range(args.warmup, args.warmup + args.steps):
                    one_step(session, preset, step, ctx, watch)
            seconds = (time.perf_counter() - start) / args.steps
    stages = ", ".join(f"{k} {v / args.steps:.3f}" for k, v in watch.times.items() if not k.startswith("psf_"))
    pool = "drawn ahead" if ahead else "in the step"
    print(
        f"{args.preset} on {device}: {seconds:.3f} s/step under the profiler (scenes {pool}); windows {session.windows}"
    )
    print(f"stages (s/step): {stages}")
    key = "self_cuda_time_total" if device.type == "cuda" else "self_cpu_time_total"
    events = prof.key_averages()
    operators = sum(e.self_cpu_time_total for e in events if e.key.startswith("aten::")) / 1e6 / args.steps
    print(
        f"host: {operators:.3f} s/step inside torch operators (aten self time), "
        f"{seconds - operators:.3f} s/step outside them ({100 * (1 - operators / seconds):.0f} % of the step)"
    )
    if device.type == "cuda":
        busy = sum(getattr(e, "self_device_time_total", 0.0) for e in events) / 1e6 / args.steps
        print(f"device busy {busy:.3f} s/step ({100 * busy / seconds:.0f} % of the step)")
    print(
        prof.key_averages(group_by_input_shape=True).table(
            sort_by=key, row_limit=args.rows, max_name_column_width=40, max_shapes_column_width=60
        )
    )


if __name__ == "__main__":
    main()
