"""Plug your own detector into `metalens evaluate`: does it still see through each lens?

    python examples/own_model.py [--model your_detector.onnx] [--kind detect|segment] [DESIGN ...]

Without ``--model`` it writes a small stand-in detector to runs/stand_in_detector.onnx first (a
few torch layers scoring bright and dark 32-pixel cells, with a raw YOLO-style head (N, 4 + 2,
cells); your YOLO export, (N, 300, 6) boxes or a raw head, goes in the same way). Then, for the
designs given (default: the quick split-spectrum and hyperbolic runs if examples/quick_results.py
has written them, else the hyperbolic 532 nm lens of presets/hyperbolic-532.toml), it runs

    metalens evaluate DESIGN... --images photos --obstruction dirt,fence --pixels 256 --seed 0
        --task-model MODEL --task-kind KIND --task-labels clean --json

(``--task-labels clean``: the model's own output on each clean photograph is the truth, so no
annotation is needed) and prints mAP50-95 (or mIoU) per design, capture and condition with its
95 % interval. Needs onnxruntime (``pip install 'metalens-cli[tasks]'``) and, to write the
stand-in, onnx.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PIXELS = 256


def stand_in_detector(path: Path) -> Path:
    """Write a small torch detector with a raw YOLO-style head as ONNX (fixed 1 × 3 × 256 × 256 input)."""
    import torch
    import torch.nn.functional as F

    class Cells(torch.nn.Module):
        def forward(self, x):
            g = F.avg_pool2d(x.mean(1, keepdim=True), 32)
            local = F.avg_pool2d(F.pad(g, (1, 1, 1, 1), mode="replicate"), 3, stride=1)
            scores = torch.cat([torch.sigmoid(30 * (g - local - 0.03)), torch.sigmoid(30 * (local - g - 0.03))], 1)
            n, _, h, w = g.shape
            cy = ((torch.arange(h, dtype=x.dtype) + 0.5) * 32)[:, None].expand(h, w)
            cx = ((torch.arange(w, dtype=x.dtype) + 0.5) * 32)[None, :].expand(h, w)
            size = torch.full((h, w), 32.0, dtype=x.dtype)
            boxes = torch.stack([cx, cy, size, size]).reshape(1, 4, h * w).expand(n, 4, h * w)
            return torch.cat([boxes, scores.reshape(n, 2, h * w)], 1)

    path.parent.mkdir(parents=True, exist_ok=True)
    torch.onnx.export(Cells(), (torch.rand(1, 3, PIXELS, PIXELS),), str(path), dynamo=False, input_names=["images"])
    return path


def main() -> None:
    """Write the stand-in if needed, evaluate, print the model's rows."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("designs", nargs="*")
    parser.add_argument("--model", type=Path, help="your .onnx, .pt2 or TorchScript model, or module:callable")
    parser.add_argument("--kind", default="detect", choices=("detect", "segment"))
    args = parser.parse_args()
    model = args.model or stand_in_detector(ROOT / "runs" / "stand_in_detector.onnx")
    runs = [ROOT / "runs" / "quick-split-spectrum", ROOT / "runs" / "hyperbolic-532"]
    if args.designs:
        designs = args.designs
    elif all((run / "run.json").is_file() for run in runs):
        designs = [str(run) for run in runs]
    else:
        designs = ["hyperbolic:532nm", "--preset", "presets/hyperbolic-532.toml"]
    command = [
        sys.executable, "-m", "metalens_cli", "evaluate", *designs, "--images", "photos",
        "--obstruction", "dirt,fence", "--pixels", str(PIXELS), "--seed", "0", "--task-model", str(model),
        "--task-kind", args.kind, "--task-labels", "clean", "--quiet", "--json",
    ]  # fmt: skip
    report = json.loads(subprocess.run(command, cwd=ROOT, check=True, capture_output=True, text=True).stdout)
    metric = "map50_95" if args.kind == "detect" else "miou"
    for row in report["model"]:
        value, ci = row[metric], row[f"{metric}_ci"]
        shown = "—" if value is None else f"{value:.3f} [{ci[0]:.3f}, {ci[1]:.3f}]"
        print(f"{row['design']:>28} {row['capture']:>6} {row['obstruction'] or '':>6} {row['condition']:>13}  {shown}")


if __name__ == "__main__":
    main()
