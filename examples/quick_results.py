"""Reproduce docs/results.md: the quick presets against both baselines, through the CLI alone.

    python examples/quick_results.py [--runs runs] [--seeds 3] [--reuse]

1. ``metalens optimize`` trains presets/quick-split-spectrum.toml and presets/quick-broadband.toml
   (same code, same schedule; the broadband baseline has no filter) and writes the hyperbolic
   532 nm baseline as a run directory (presets/hyperbolic-532.toml, no steps).
2. ``metalens evaluate`` scores raw captures of the built-in held-out images (never used in
   training) through all three designs, at the sensor crop the quick presets train on and at the
   paper's full 512 × 512 sensor, for ``--seeds`` draws of depths and obstructions.
3. ``metalens psf-scan`` measures, per pass band of the tri-band filter, the fraction of power in
   the central 5 × 5 pixels of the far (∞) and near (45 mm) PSFs of both learned designs.
4. The cost of a training step at the paper's resolution, radial and 2-D, is copied from the
   ``optimize-cpu`` section of docs/benchmarks.md (``python benchmarks/bench_optimize.py`` writes
   it; this script does not re-run it).

Every other number and every verdict in the written file comes from the commands' JSON output.
``--reuse`` keeps run directories that already hold a finished run.
"""

from __future__ import annotations

import argparse
import json
import re
import shlex
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DESIGNS = ("quick-split-spectrum", "quick-broadband", "hyperbolic-532")
LABELS = {"quick-split-spectrum": "learned split-spectrum", "quick-broadband": "learned broadband",
          "hyperbolic-532": "hyperbolic 532 nm"}
OBSTRUCTIONS = "dirt,fence,drops"
NEAR_DEPTH = "45mm"
BENCHMARKS = ROOT / "docs" / "benchmarks.md"


def metalens(*args: str) -> dict:
    """Run ``metalens ARGS --json`` from the repository root; return its JSON."""
    command = [sys.executable, "-m", "metalens_cli", *args, "--json"]
    print("$ metalens " + shlex.join(args) + " --json", file=sys.stderr, flush=True)
    done = subprocess.run(command, cwd=ROOT, check=True, capture_output=True, text=True)
    return json.loads(done.stdout)


def train(runs: Path, reuse: bool) -> dict[str, dict]:
    reports = {}
    for name in DESIGNS:
        run = runs / name
        if reuse and (run / "run.json").is_file():
            reports[name] = json.loads((run / "run.json").read_text())
            continue
        if run.exists():
            raise SystemExit(f"{run} exists: remove it or pass --reuse")
        start = time.perf_counter()
        reports[name] = metalens("optimize", f"presets/{name}.toml", "-o", str(run), "--quiet")
        reports[name]["wall_s"] = time.perf_counter() - start
    return reports


def evaluate(runs: Path, seeds: int, pixels: int) -> dict:
    """Mean over seeds of PSNR/SSIM per (design, obstruction, condition)."""
    scores: dict[tuple[str, str, str], list[tuple[float, float]]] = {}
    for seed in range(seeds):
        report = metalens("evaluate", *(str(runs / n) for n in DESIGNS), "--obstruction", OBSTRUCTIONS,
                          "--pixels", str(pixels), "--seed", str(seed))
        for row in report["rows"]:
            key = (Path(row["design"]).name, row["obstruction"], row["condition"])
            scores.setdefault(key, []).append((row["psnr_db"], row["ssim"]))
    return {key: (statistics.mean(p for p, _ in v), statistics.mean(s for _, s in v)) for key, v in scores.items()}


def pass_bands(preset_path: Path) -> list[tuple[str, float, float]]:
    """(name, lo, hi) in m of each pass band: centre ± FWHM/2 of the preset's filter."""
    sys.path.insert(0, str(ROOT))
    from metalens_cli.io.presets import load_preset

    f = load_preset(preset_path).filter
    return [(name, c - w / 2, c + w / 2) for name, c, w in zip("BGR", f.centers_m, f.widths_m)]


def core_energy(runs: Path, bands) -> dict:
    """Mean central 5 × 5 energy over each pass band (2 nm steps), far and near, per learned design."""
    waves = ",".join(f"{lo * 1e9:.0f}:{hi * 1e9:.0f}:2nm" for _, lo, hi in bands)
    out = {}
    for name in DESIGNS[:2]:
        report = metalens("psf-scan", "--design", str(runs / name), "--wavelengths", waves, "--depths", f"{NEAR_DEPTH},inf",
                          "--pixels", "64", "-o", str(runs / name / "passbands.exr"), "--quiet")
        for band, lo, hi in bands:
            for depth in ("far", "near"):
                values = [p["energy_center_5x5"] for p in report["psfs"] if lo - 1e-12 <= p["wavelength_m"] <= hi + 1e-12
                          and (p["depth_m"] is None or p["depth_m"] == float("inf")) == (depth == "far")]
                out[(name, band, depth)] = statistics.mean(values)
    return out


def write(path: Path, reports, tables, energies, bands, seeds) -> None:
    lines = ["# Results: the quick presets against both baselines", "",
             "Written by `python examples/quick_results.py` (all numbers below come from the commands it runs; "
             "re-running it rewrites this file). Machine: 2 CPU cores.", "",
             "## Commands", "", "```bash"]
    lines += [f"metalens optimize presets/{n}.toml -o runs/{n}" for n in DESIGNS]
    lines += [f"metalens evaluate runs/quick-split-spectrum runs/quick-broadband runs/hyperbolic-532 --obstruction {OBSTRUCTIONS} "
              f"--pixels {{128,512}} --seed {{0..{seeds - 1}}} --json",
              f"metalens psf-scan --design runs/{{quick-split-spectrum,quick-broadband}} --wavelengths "
              + ",".join(f"{lo * 1e9:.0f}:{hi * 1e9:.0f}:2nm" for _, lo, hi in bands) + f" --depths {NEAR_DEPTH},inf --pixels 64 "
              "-o runs/…/passbands.exr --json", "```", "", "## Training", "",
             "| design | steps | torch threads | s/step (median) | training time | validation loss before → after (4 fixed draws) |",
             "|---|---|---|---|---|---|"]
    for name in DESIGNS:
        r = reports[name]
        v = r.get("validation_loss") or {}
        before_after = f"{v['initial']:.3f} → {v['final']:.3f}" if v else "—"
        per_step = r["cost"].get("seconds_per_step_median")
        threads = r["settings"].get("threads", "—")
        lines.append(f"| {LABELS[name]} | {r['settings']['steps']} | {threads} | {per_step:.3f} |" if per_step
                     else f"| {LABELS[name]} | 0 | {threads} | — |")
        lines[-1] += f" {r['cost'].get('seconds_training', 0) / 60:.1f} min | {before_after} |"
    lines += ["", "Threads and s/step are as each run's `run.json` recorded them; the two learned runs here were made side by side on the one 2-core machine, one torch thread each, so they took longer than a run alone (see (c) for a step with 2 threads)."]
    verdict_a = []
    for pixels, table in tables.items():
        lines += ["", f"## (a) Raw captures of the held-out images, {pixels} × {pixels} sensor", "",
                  f"`metalens evaluate`, built-in images, obstructions {OBSTRUCTIONS.replace(',', ', ')}, mean over seeds "
                  f"0-{seeds - 1} (each seed draws z_near in 40-50 mm, z_far in 1-20 m and the obstructions). PSNR after the "
                  "global gain/bias match.", "",
                  "| design | obstruction | PSNR unobstructed | PSNR obstructed | Δ PSNR | SSIM obstructed |", "|---|---|---|---|---|---|"]
        for kind in OBSTRUCTIONS.split(","):
            for name in DESIGNS:
                u, o = table[(name, kind, "unobstructed")], table[(name, kind, "obstructed")]
                lines.append(f"| {LABELS[name]} | {kind} | {u[0]:.2f} | {o[0]:.2f} | {o[0] - u[0]:+.2f} | {o[1]:.3f} |")
            best = table[(DESIGNS[0], kind, "obstructed")][0]
            others = [table[(n, kind, "obstructed")][0] for n in DESIGNS[1:]]
            verdict_a.append((pixels, kind, best > max(others), best - max(others)))
    lines += ["", "## (b) PSF energy in the central 5 × 5 pixels, per pass band", "",
              "`metalens psf-scan`, mean over each pass band (centre ± FWHM/2, 2 nm steps); far = ∞, near = 45 mm. "
              "Fractions of the power through the aperture.", "",
              "| pass band | split-spectrum far | broadband far | split-spectrum near | broadband near |", "|---|---|---|---|---|"]
    verdict_b = []
    for band, lo, hi in bands:
        e = {(n, d): energies[(n, band, d)] for n in DESIGNS[:2] for d in ("far", "near")}
        lines.append(f"| {band} ({lo * 1e9:.0f}-{hi * 1e9:.0f} nm) | {e[DESIGNS[0], 'far']:.4f} | {e[DESIGNS[1], 'far']:.4f} | "
                     f"{e[DESIGNS[0], 'near']:.4f} | {e[DESIGNS[1], 'near']:.4f} |")
        verdict_b.append((band, e[DESIGNS[0], "far"] > e[DESIGNS[1], "far"], e[DESIGNS[0], "near"] < e[DESIGNS[1], "near"]))
    lines += ["", "## (c) Seconds per training step", "", step_benchmark()]
    lines += ["", "## Verdicts", ""]
    for pixels, kind, ok, margin in verdict_a:
        lines.append(f"- (a) {pixels}², {kind}: split-spectrum obstructed PSNR {'beats' if ok else 'does NOT beat'} both baselines "
                     f"({margin:+.2f} dB over the better one).")
    for band, far_ok, near_ok in verdict_b:
        lines.append(f"- (b) {band}: far core energy {'higher' if far_ok else 'NOT higher'} and near core energy "
                     f"{'lower' if near_ok else 'NOT lower'} than the broadband baseline's.")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def step_benchmark() -> str:
    """The ``optimize-cpu`` section of docs/benchmarks.md without its heading, or how to make it."""
    text = BENCHMARKS.read_text(encoding="utf-8") if BENCHMARKS.is_file() else ""
    found = re.search(r"<!-- bench:optimize-cpu -->\n## [^\n]*\n(.*?)\n<!-- /bench:optimize-cpu -->", text, re.S)
    if found is None:
        return "Not measured yet: run `python benchmarks/bench_optimize.py`, then this script again."
    return ("Copied from docs/benchmarks.md (written by `python benchmarks/bench_optimize.py`).\n" + found.group(1).rstrip())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, default=ROOT / "runs")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--pixels", type=int, nargs="+", default=[128, 512])
    parser.add_argument("--reuse", action="store_true")
    parser.add_argument("--output", type=Path, default=ROOT / "docs" / "results.md")
    args = parser.parse_args()
    reports = train(args.runs, args.reuse)
    tables = {p: evaluate(args.runs, args.seeds, p) for p in args.pixels}
    bands = pass_bands(ROOT / "presets" / "quick-split-spectrum.toml")
    write(args.output, reports, tables, core_energy(args.runs, bands), bands, args.seeds)
    print(args.output)


if __name__ == "__main__":
    main()
