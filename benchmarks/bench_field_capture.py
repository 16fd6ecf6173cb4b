"""Benchmark: a space-variant capture (``--field auto``) of the paper's hyperbolic lens (532 nm,
f 4 mm, D 2.516 mm, pitch 395 nm) on a 512² sensor of 1.85 µm pixels.

Its field PSF sets at 45 mm and 5 m (``imaging.field_psfs``: cached on disk, so only the first run
computes them, ~10 min on 2 cores), their field transforms at the default 1 % (timed, with the
measured error and the eigen-PSFs per window side), then one capture
(``imaging.field_formation.form_image_field``: the obstructed and unobstructed images of the first
photograph behind dirt) timed ``--captures`` times, the median. Configurations, each in a process
of its own, in one run: this checkout; the same with every eigen-PSF in the largest window
(``WINDOW_SHARE`` = 0); with ``--baseline REV`` the code at git revision REV (a temporary worktree).
The last column: each capture's relative L2 from the first configuration's.

Run alone (it times): python benchmarks/bench_field_capture.py [--threads 2] [--baseline REV]
Rewrites its section of docs/benchmarks.md: ``field-capture``.
"""

from __future__ import annotations

import argparse
import subprocess
import tempfile
from pathlib import Path

import numpy as np
from report import run_in_checkout, write_section

ROOT = Path(__file__).resolve().parents[1]
# run in the checkout under test, through the API both this checkout and older ones have
WORKER = r"""
import json, resource, sys, time
import numpy as np, torch
import metalens_cli.imaging.field_formation as ff
from metalens_cli.imaging.field_psfs import field_channel_psfs
from metalens_cli.imaging.images import load_images
from metalens_cli.imaging.obstructions import make_obstruction
from metalens_cli.imaging.pipeline import DEFAULT_WAVELENGTHS
from metalens_cli.io.designs import resolve_design
from metalens_cli.io.units import parse_length_list

options = json.loads(sys.argv[1])
for name, value in options["constants"].items():
    setattr(ff, name, value)
torch.set_num_threads(options["threads"])
design = resolve_design("hyperbolic:532nm", None, f_m=4e-3, aperture_m=2.516e-3, pitch_m=395e-9)
waves = parse_length_list(DEFAULT_WAVELENGTHS, "--wavelengths")
sets = field_channel_psfs(design, 45e-3, 5.0, waves, 1.85e-6, 512)
start = time.perf_counter()
near, far = (ff.field_transform(s, (512, 512)) for s in (sets.near, sets.far))
prepared = time.perf_counter() - start
image = load_images("photos", (512, 512), 1, sets.margin)[0]
dirt = make_obstruction("dirt", (512, 512), 45e-3, 4e-3, 1.85e-6, [0, 0], clean=image.linear, margin=sets.margin)
inputs = [torch.as_tensor(a, dtype=torch.float32) for a in (image.linear, dirt.rgb, dirt.mask)]
seconds = []
with torch.no_grad():
    for _ in range(options["captures"] + 1):  # the first one warms the FFT plans up
        start = time.perf_counter()
        capture = ff.form_image_field(*inputs, near, far, sets.margin)
        seconds.append(time.perf_counter() - start)
np.save(options["capture"], np.stack([capture.obstructed.numpy(), capture.unobstructed.numpy()]))
windows = [getattr(t, "windows", {t.support: len(t.term_tile)}) for t in (near, far)]
print(json.dumps({
    "prepare_s": prepared, "capture_s": float(np.median(seconds[1:])), "errors": [near.error, far.error],
    "eigen_psfs": [len(near.term_tile), len(far.term_tile)], "windows": windows,
    "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20, "module": ff.__file__,
}))
"""


def run(checkout: Path, label: str, threads: int, captures: int, constants: dict, folder: Path) -> dict:
    options = {"threads": threads, "captures": captures, "constants": constants, "capture": str(folder / label)}
    result = run_in_checkout(checkout, WORKER, options, label)
    return {**result, "label": label, "image": np.load(folder / f"{label}.npy")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--captures", type=int, default=5)
    parser.add_argument("--baseline", help="a git revision to time beside this checkout")
    args = parser.parse_args()
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        configurations = [("this checkout", ROOT, {}), ("one window (WINDOW_SHARE = 0)", ROOT, {"WINDOW_SHARE": 0.0})]
        if args.baseline:
            tree = folder / "baseline"
            subprocess.run(["git", "worktree", "add", "--detach", str(tree), args.baseline], cwd=ROOT, check=True)
            configurations.append((f"baseline {args.baseline}", tree, {}))
        try:
            for label, checkout, constants in configurations:
                results.append(run(checkout, label, args.threads, args.captures, constants, folder))
        finally:
            if args.baseline:
                subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=ROOT, check=True)
    first = results[0]["image"]
    rows = []
    for r in results:
        windows = " / ".join(", ".join(f"{n}×{side}" for side, n in w.items()) for w in r["windows"])
        apart = float(np.linalg.norm(r["image"] - first) / np.linalg.norm(first))
        rows.append(
            f"| {r['label']} | {r['eigen_psfs'][0]} + {r['eigen_psfs'][1]} | {windows} | "
            f"{100 * r['errors'][0]:.2f} / {100 * r['errors'][1]:.2f} % | {r['prepare_s']:.0f} | "
            f"{r['peak_rss_gb']:.1f} | **{r['capture_s']:.2f}** | {apart:.1e} |"
        )
    base = results[0]["capture_s"]
    ratios = ", ".join(f"{r['label']}: {r['capture_s'] / base:.2f}×" for r in results[1:])
    command = "python benchmarks/bench_field_capture.py" + (f" --baseline {args.baseline}" if args.baseline else "")
    lines = [
        f"## A space-variant capture, cpu (`{command}`)",
        "",
        "The paper's hyperbolic lens at 45 mm (near) and 5 m (far) on a 512² sensor, field PSF sets (computed "
        f"once, then read from the disk cache; not timed), {args.threads} threads, run alone, each configuration in "
        "a process of its own, one after another. "
        "Eigen-PSFs near + far, their windows (count × side in px, near / far), the measured PSF-field error "
        "(near / far, tolerance 1 %), the expansion's preparation (s), the process's peak RSS (GB), the median of "
        f"{args.captures} captures (s; the obstructed and unobstructed images of a photograph behind dirt) and the "
        f"capture's relative L2 from the first row's. Capture time against the first row's: {ratios}.",
        "",
        "| configuration | eigen-PSFs | windows | error | prepare s | peak RSS GB | capture s | apart |",
        "|---|---|---|---|---|---|---|---|",
        *rows,
    ]
    markdown = "\n".join(lines)
    print(markdown)
    write_section("field-capture", markdown)


if __name__ == "__main__":
    main()
