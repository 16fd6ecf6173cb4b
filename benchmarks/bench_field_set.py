"""Benchmark: one off-axis height of a field PSF set (``imaging.field_psfs``) of the paper's
hyperbolic lens (532 nm, f 4 mm, D 2.516 mm, pitch 395 nm) for a 512² sensor of 1.85 µm pixels.

What the set computes per height, at its last one (the corner, 363 px): ``optics.field.field_psf``
of the set's 24 wavelengths (8 strata a channel) at 45 mm and 5 m in a 705-pixel window with the
on-axis angle margin. A set is four such heights and one check PSF. Configurations, each in a
process of its own, in one run: this checkout; with ``--baseline REV`` the code at git revision
REV (a temporary worktree). Reported: seconds (kernels / sources / propagation), the process's
peak RSS (CPU) or ``torch.cuda.max_memory_allocated`` (GPU), and the PSFs' relative L2 from the
first configuration's.

Run alone (it times): python benchmarks/bench_field_set.py [--threads 2] [--device cpu|cuda] [--baseline REV]
(``--baseline DIR --label REV``: a copy of REV in DIR, e.g. ``git archive REV | tar -x -C DIR``, where git is not.)
Rewrites its section of docs/benchmarks.md: ``field-set`` (``field-set-cuda`` on a GPU).
"""

from __future__ import annotations

import argparse
import subprocess
import tempfile
from pathlib import Path

import numpy as np
from report import run_in_checkout, write_section

ROOT = Path(__file__).resolve().parents[1]
HEIGHT_PX, WINDOW_PX, PITCH = 363, 705, 1.85e-6  # the corner of a 512² sensor; the set's window for this lens
# run in the checkout under test, through the API both this checkout and older ones have
WORKER = r"""
import json, math, resource, sys, time
import numpy as np, torch
from metalens_cli.imaging.field_psfs import field_strata
from metalens_cli.io.designs import resolve_design
import metalens_cli.optics.field as field
from metalens_cli.optics.sampling import PsfGrid

options = json.loads(sys.argv[1])
torch.set_num_threads(options["threads"])
device = options["device"]
design = resolve_design("hyperbolic:532nm", None, f_m=4e-3, aperture_m=2.516e-3, pitch_m=395e-9)
lams = [float(x) for x in field_strata(design).wavelengths_m]
angle = math.atan2(options["height"] * options["pitch"], 4e-3)
if device.startswith("cuda"):
    torch.zeros(1, device=device)
    torch.cuda.synchronize()
start = time.perf_counter()
grid = PsfGrid(lams, [45e-3, 5.0], options["window"], options["pitch"], 4e-3)
result = field.field_psf(design.lens, grid, angle, device=device, oversample=field.ON_AXIS_MARGIN)
psf = result.psf.cpu().numpy()
seconds = time.perf_counter() - start
peak = (torch.cuda.max_memory_allocated() if device.startswith("cuda")
        else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024)
np.save(options["out"], psf)
print(json.dumps({"seconds": seconds, "timing": result.timing_s, "grid": result.grid, "peak_gb": peak / 2**30,
                  "wavelengths": len(lams), "module": field.__file__}))
"""


def run(checkout: Path, label: str, options: dict, folder: Path) -> dict:
    out = folder / f"{len(list(folder.glob('*.npy')))}.npy"
    result = run_in_checkout(checkout, WORKER, {**options, "out": str(out)}, label)
    return {**result, "label": label, "psf": np.load(out)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--device", default="cpu", help="cpu or cuda")
    parser.add_argument("--baseline", help="a git revision, or a folder holding one, to time beside this checkout")
    parser.add_argument("--label", help="the baseline's name in the table (default: --baseline)")
    args = parser.parse_args()
    gpu = args.device.startswith("cuda")
    options = {"threads": args.threads, "device": args.device, "height": HEIGHT_PX, "window": WINDOW_PX, "pitch": PITCH}
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        configurations = [("this checkout", ROOT)]
        given = args.baseline and Path(args.baseline).is_dir()  # a copy of that revision (where git is not)
        tree = Path(args.baseline).resolve() if given else folder / "baseline"
        if args.baseline and not given:
            subprocess.run(["git", "worktree", "add", "--detach", str(tree), args.baseline], cwd=ROOT, check=True)
        if args.baseline:
            configurations.append((f"baseline {args.label or args.baseline}", tree))
        try:
            for label, checkout in configurations:
                results.append(run(checkout, label, options, folder))
        finally:
            if args.baseline and not given:
                subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=ROOT, check=True)
    first = results[0]["psf"]
    rows = []
    for r in results:
        t = r["timing"]
        apart = float(np.linalg.norm(r["psf"] - first) / np.linalg.norm(first))
        rows.append(
            f"| {r['label']} | {r['grid']['fft_size']}² | {'yes' if r['grid'].get('mirror_y') else 'no'} | "
            f"**{r['seconds']:.1f}** | {t['kernels']:.1f} / {t['source']:.1f} / {t['propagate']:.1f} | "
            f"{r['peak_gb']:.1f} | {apart:.1e} |"
        )
    ratios = ", ".join(f"{r['label']}: {r['seconds'] / results[0]['seconds']:.2f}×" for r in results[1:])
    import torch

    machine = (
        f"{torch.cuda.get_device_name()} (GPU), torch {torch.__version__}, every timing waiting for the device"
        if gpu
        else f"{args.threads} threads, run alone"
    )
    command = "python benchmarks/bench_field_set.py" + (" --device cuda" if gpu else "")
    command += f" --baseline {args.label or args.baseline}" if args.baseline else ""
    lines = [
        f"## One height of a field PSF set, {'cuda' if gpu else 'cpu'} (`{command}`)",
        "",
        f"The paper's hyperbolic lens, the set's corner height ({HEIGHT_PX} px of {PITCH * 1e6:g} µm behind f = 4 mm), "
        f"its {results[0]['wavelengths']} wavelengths at 45 mm and 5 m in a {WINDOW_PX}-pixel window "
        f"(`optics.field.field_psf`, on-axis angle margin), {machine}, each configuration in a process of its own. "
        "FFT grid: the largest of the wavelengths' (since 2026-11-27 sized by the light that can reach the window, "
        "`sampling.plan_field_asm`; before, the larger of that reach without a guard and every wave of the kept band). "
        "Half pupil: the mirror symmetry about the meridional plane used (`propagate.asm_propagate_even_y`). "
        "Seconds in all, then kernels (site grid, pixel operator, transfer functions) / sources / propagation; "
        f"peak memory ({'GPU' if gpu else 'RSS'}); the PSFs' relative L2 from the first row's. "
        f"Time against the first row's: {ratios or '—'}. A set is four such heights and one check PSF.",
        "",
        "| configuration | FFT grid | half pupil | s | kernels / sources / propagate s | peak GB | apart |",
        "|---|---|---|---|---|---|---|",
        *rows,
    ]
    markdown = "\n".join(lines)
    print(markdown)
    write_section("field-set-cuda" if gpu else "field-set", markdown)


if __name__ == "__main__":
    main()
