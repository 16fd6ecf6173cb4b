"""Write docs/training.md: what makes the lens learn, measured with short A/B runs.

    python examples/training_study.py [--steps 200] [--out runs/study] [--reuse] [--only NAME ...]

Each variant is a quick preset (presets/quick-*.toml) with a few keys changed; every variant runs
``metalens optimize`` for ``--steps`` steps (seed 0) as a user would, then is scored on what a
user of the lens sees:

- ``metalens evaluate RUN --pixels 128 --seed 0 --obstruction dirt,fence``: PSNR of raw captures of
  the held-out photographs (never trained on), unobstructed and obstructed (seed 0: 9 units);
- the far (∞) PSF's energy in the central 5 × 5 pixels per wavelength over 430-650 nm (5 nm),
  its mean and the fraction of wavelengths at ≥ half its maximum ("sharp across the majority of
  the spectrum"), and the near (45 mm) one's mean, from ``optics.psf.compute_psf``;
- run.json: the per-term gradient norms at θ_init and at the end, the validation loss, the PSF
  windows the light needed, seconds per step.

The hyperbolic 532 nm lens is scored the same way, once per camera (the broadband preset's, without a
filter, and the split-spectrum preset's tri-band filter), as the reference rows. Then the quick presets
as they are (with ``--longer``, also the split one trained 3× longer) are trained in full and scored together with
the hyperbolic lens at the paper's 512 × 512 sensor over 3 seeds, with paired CIs
(``--no-final`` skips that part). Every number in the written file comes from those outputs;
``--reuse`` keeps finished run directories.

    python examples/training_study.py --image-learning [--reuse]

runs only issue 59's experiment (examples/image_learning.py: learning θ from images under the
verdict's camera) and rewrites only its section of this file.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT_DOC = ROOT / "docs" / "training.md"

# The quick presets' keys before this study; every variant states its changes from them.
BEFORE = {"optimize": {"theta_basis": "samples", "design_grid": 400}, "loss": {"sharp_mode": "per_channel"}}


def changed(optimize: dict | None = None, loss: dict | None = None) -> dict:
    return {"optimize": {**BEFORE["optimize"], **(optimize or {})}, "loss": {**BEFORE["loss"], **(loss or {})}}


SPLINE = {"theta_basis": "spline", "design_grid": 64}
SPLINE_256 = {"theta_basis": "spline", "design_grid": 256}
# (name, preset, overrides {section: {key: value}}, what it tests)
VARIANTS = [
    (
        "broadband: before",
        "quick-broadband",
        changed(),
        "400 linear samples, mean 1/E_c (the quick preset before this study)",
    ),
    (
        "broadband: spline",
        "quick-broadband",
        changed(SPLINE),
        "64 cubic B-spline coefficients in (r/a)² instead of 400 samples",
    ),
    (
        "broadband: spline, log",
        "quick-broadband",
        changed(SPLINE, {"sharp_mode": "log"}),
        "L_sharp = −mean log E_c (gradient −1/E instead of −1/E²)",
    ),
    (
        "broadband: spline, log, w 0.01",
        "quick-broadband",
        changed(SPLINE, {"sharp_mode": "log", "sharp": 0.01, "bright": 0.01}),
        "PSF terms weighted down to the image terms' gradient scale",
    ),
    (
        "broadband: spline, log, lr 0.3",
        "quick-broadband",
        changed({**SPLINE, "learning_rate": 0.3}, {"sharp_mode": "log"}),
        "θ moves 3× further per step",
    ),
    (
        "broadband: spline, log, midpoint λ",
        "quick-broadband",
        changed({**SPLINE, "spectral_sampling": "midpoint"}, {"sharp_mode": "log"}),
        "fixed spectral quadrature (strata midpoints) instead of random draws",
    ),
    (
        "broadband: spline, paper's L_sharp",
        "quick-broadband",
        changed(SPLINE, {"sharp_mode": "total"}),
        "the paper's 1/ΣE − 1",
    ),
    (
        "broadband: spline 256, log",
        "quick-broadband",
        changed(SPLINE_256, {"sharp_mode": "log"}),
        "the quick preset's θ basis and loss before the harmonic rows below",
    ),
    (
        "broadband: spline 256, log per λ",
        "quick-broadband",
        changed(SPLINE_256, {"sharp_mode": "log_wavelength"}),
        "L_sharp = −mean log E_λ over the wavelength samples, each its own core: asks every wavelength to be sharp",
    ),
    (
        "broadband: spline 256, harmonic per λ",
        "quick-broadband",
        changed(SPLINE_256, {"sharp_mode": "harmonic_wavelength"}),
        "L_sharp = log mean 1/E_λ (−log of the harmonic mean): the weakest wavelengths steer most",
    ),
    (
        "broadband: spline 256, harmonic per λ, 6 per channel",
        "quick-broadband",
        changed({**SPLINE_256, "wavelengths_per_channel": 6}, {"sharp_mode": "harmonic_wavelength"}),
        "as above with 6 wavelength draws per channel a step: the quick preset",
    ),
    ("split: before", "quick-split-spectrum", changed(), "as broadband: before"),
    ("split: spline, log", "quick-split-spectrum", changed(SPLINE, {"sharp_mode": "log"}), "as broadband"),
    ("split: spline 256, log", "quick-split-spectrum", changed(SPLINE_256, {"sharp_mode": "log"}), "4× finer spline"),
    ("split: spline, 1/E per channel", "quick-split-spectrum", changed(SPLINE), "the old L_sharp on the spline"),
    (
        "split: spline 256, harmonic per λ",
        "quick-split-spectrum",
        changed(SPLINE_256, {"sharp_mode": "harmonic_wavelength"}),
        "the broadband baseline's L_sharp on the split lens (its draws lie in the pass bands)",
    ),
    (
        "split: spline 256, log, fence",
        "quick-split-spectrum",
        changed({**SPLINE_256, "obstructions": ("fence",)}, {"sharp_mode": "log"}),
        "trained with fences instead of dirt",
    ),
    (
        "split: spline 256, log, dirt + fence",
        "quick-split-spectrum",
        changed({**SPLINE_256, "obstructions": ("dirt", "fence")}, {"sharp_mode": "log"}),
        "each batch entry dirt or fence at random",
    ),
    (
        "split: spline 256, log, w 0.01",
        "quick-split-spectrum",
        changed(SPLINE_256, {"sharp_mode": "log", "sharp": 0.01, "bright": 0.01}),
        "PSF terms weighted down to the image terms' gradient scale, trained with dirt",
    ),
    (
        "split: spline 256, log, w 0.01, fence",
        "quick-split-spectrum",
        changed({**SPLINE_256, "obstructions": ("fence",)}, {"sharp_mode": "log", "sharp": 0.01, "bright": 0.01}),
        "the same trained with fences: does the obstruction steer the lens once the image terms can?",
    ),
    (
        "split: spline 256, log, cosine over 200",
        "quick-split-spectrum",
        changed({**SPLINE_256, "t_max": 200}, {"sharp_mode": "log"}),
        "the learning rate annealed to 0 within the run (the others: t_max 1500, still near 0.1 at step 200)",
    ),
]
REFERENCE = "hyperbolic:532nm"
VARIANT_T_MAX = 1500  # every variant's cosine schedule (its runs stop at --steps, early in it)
CORE_WAVES_NM = np.arange(430, 651, 5)
NEAR_M = 0.045


def metalens(*args: str) -> dict:
    """Run ``metalens ARGS --json`` from the repository root; return its JSON."""
    command = [sys.executable, "-m", "metalens_cli", *args, "--json", "--quiet"]
    print("$ metalens " + shlex.join(args), file=sys.stderr, flush=True)
    done = subprocess.run(command, cwd=ROOT, check=True, capture_output=True, text=True)
    return json.loads(done.stdout)


def slug(name: str) -> str:
    return "".join(c if c.isalnum() else "-" for c in name).strip("-").replace("--", "-")


def variant_preset(preset_name: str, overrides: dict, path: Path) -> Path:
    from metalens_cli.io.presets import load_preset, to_toml

    preset = load_preset(ROOT / "presets" / f"{preset_name}.toml")
    overrides = {**overrides, "optimize": {"t_max": VARIANT_T_MAX, **overrides.get("optimize", {})}}
    for section, values in overrides.items():
        preset = dataclasses.replace(preset, **{section: dataclasses.replace(getattr(preset, section), **values)})
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(to_toml(preset))
    return path


def core_energy(spec: str, preset_path: Path) -> dict:
    """Far and near energy in the central 5 × 5 pixels per wavelength (fractions of the aperture power)."""
    import torch

    from metalens_cli.io.designs import resolve_design
    from metalens_cli.io.presets import load_preset
    from metalens_cli.optics.psf import compute_psf
    from metalens_cli.optics.sampling import PsfGrid

    preset = load_preset(preset_path)
    design = resolve_design(spec, preset if spec.startswith("hyperbolic:") else None)
    waves = list(CORE_WAVES_NM * 1e-9)
    psf = compute_psf(
        design.lens,
        PsfGrid(waves, [math.inf, NEAR_M], 5, preset.sensor.pixel_pitch_m, design.focal_length_m),
        dtype=torch.float64,
    ).psf
    far, near = psf[0].sum(dim=(-2, -1)).numpy(), psf[1].sum(dim=(-2, -1)).numpy()
    centre = psf[0, :, 2, 2].numpy()  # the axis pixel: ∝ on-axis intensity, whose integral over defocus is fixed
    return {
        "far_mean": float(far.mean()),
        "far_half_max_fraction": float((far >= far.max() / 2).mean()),
        "near_mean": float(near.mean()),
        "far": far.tolist(),
        "centre_mean": float(centre.mean()),
    }


def scores(spec: str, preset_path: Path) -> dict:
    report = metalens(
        "evaluate", spec, "--preset", str(preset_path), "--pixels", "128", "--seed", "0", "--obstruction", "dirt,fence"
    )
    out = {}
    for row in report["rows"]:
        out[(row["obstruction"], row["condition"])] = row["psnr_db"]
    return {
        "unobstructed": out[("dirt", "unobstructed")],
        "dirt": out[("dirt", "obstructed")],
        "fence": out[("fence", "obstructed")],
    }


def run_variant(name: str, preset_name: str, overrides: dict, out: Path, steps: int, reuse: bool) -> dict:
    run = out / slug(name)
    preset_path = variant_preset(preset_name, overrides, out / "presets" / f"{slug(name)}.toml")
    if not (reuse and (run / "run.json").is_file()):
        if run.exists():
            subprocess.run(["rm", "-rf", str(run)], check=True)
        metalens("optimize", str(preset_path), "-o", str(run), "--steps", str(steps))
    report = json.loads((run / "run.json").read_text())
    return {
        "name": name,
        "run": str(run),
        "scores": scores(str(run), preset_path),
        "core": core_energy(str(run), preset_path),
        "gradients": report["validation_loss"].get("gradient_norms", {}),
        "validation": report["validation_loss"],
        "windows": report["psf_windows"].get("window_px", {}),
        "kept": report["psf_windows"].get("kept", {}),
        "seconds_per_step": report["cost"]["seconds_per_step_median"],
    }


def ratio_text(gradients: dict) -> str:
    if not gradients:
        return "—"
    image = math.hypot(gradients.get("l1", 0.0), gradients.get("ssim", 0.0))
    psf = math.hypot(gradients.get("sharp", 0.0), gradients.get("bright", 0.0))
    return f"{psf / image:.3g}" if image > 0 else "∞"


def write(results: list[dict], reference: dict, steps: int, final: list[str]) -> None:
    lines = [
        "# Training: what makes the lens learn",
        "",
        f"Written by `python examples/training_study.py --steps {steps}` (re-running it rewrites this file). Each row "
        f"is a quick preset with the keys named changed, trained {steps} steps (seed 0, 2 CPU cores) by `metalens "
        "optimize`, then scored on the held-out photographs (`metalens evaluate RUN --pixels 128 --seed 0 "
        "--obstruction dirt,fence`, raw captures, seed 0, 9 units; PSNR in dB after the least-squares match) and on "
        "its far PSF: the energy in the central 5 × 5 pixels (fraction of the power through the aperture) per "
        "wavelength over 430-650 nm at 5 nm, its mean and the fraction of those wavelengths at ≥ half its maximum; the "
        "near (45 mm) mean beside it. Gradient norms: ‖∂(w·L)/∂c‖ of each weighted term over the optimiser's "
        "parameters c, mean of 2 fixed draws, at θ_init and after training (run.json "
        "`validation_loss.gradient_norms`); PSF/image is ‖(sharp, bright)‖ / ‖(L1, SSIM)‖.",
        "",
        "| variant | what it tests | unobs. PSNR | dirt obs. | fence obs. | far 5×5 mean | ≥ ½ max | near 5×5 mean | "
        "PSF/image gradient, start → end | far window px (mean / max) | least kept | s/step |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for camera, r in reference.items():
        lines.append(
            f"| {REFERENCE}, {camera} camera (reference) | not trained | {r['scores']['unobstructed']:.2f} | "
            f"{r['scores']['dirt']:.2f} | {r['scores']['fence']:.2f} | {r['core']['far_mean']:.4f} | "
            f"{r['core']['far_half_max_fraction']:.2f} | {r['core']['near_mean']:.4f} | — | — | — | — |"
        )
    for res in results:
        g, w = res["gradients"], res["windows"].get("far", {})
        kept = min((v["min"] for v in res["kept"].values()), default=float("nan"))
        lines.append(
            f"| {res['name']} | {res['what']} | {res['scores']['unobstructed']:.2f} | {res['scores']['dirt']:.2f} | "
            f"{res['scores']['fence']:.2f} | {res['core']['far_mean']:.4f} | "
            f"{res['core']['far_half_max_fraction']:.2f} | {res['core']['near_mean']:.4f} | "
            f"{ratio_text(g.get('initial', {}))} → {ratio_text(g.get('final', {}))} | "
            f"{w.get('mean', float('nan')):.0f} / {w.get('max', float('nan')):.0f} | {kept:.4f} | "
            f"{res['seconds_per_step']:.2f} |"
        )
    lines += [
        "",
        "Gradient norms per term (start → end):",
        "",
        "| variant | L1 | SSIM | L_bright | L_sharp |",
        "|---|---|---|---|---|",
    ]
    for res in results:
        g = res["gradients"]
        cells = [
            f"{g.get('initial', {}).get(t, float('nan')):.3g} → {g.get('final', {}).get(t, float('nan')):.3g}"
            for t in ("l1", "ssim", "bright", "sharp")
        ]
        lines.append(f"| {res['name']} | " + " | ".join(cells) + " |")
    lines += ["", "Far 5 × 5 energy per wavelength (430-650 nm, 5 nm):", ""]
    lines.append("| variant | " + " ".join(f"{int(x)}" for x in CORE_WAVES_NM[::4]) + " (every 20 nm) |")
    lines.append("|---|---|")
    for res in [dict(reference["broadband"], name=REFERENCE)] + results:
        lines.append(f"| {res['name']} | " + " ".join(f"{v:.3f}" for v in res["core"]["far"][::4]) + " |")
    lines += final
    text = "\n".join(lines) + "\n"
    marker = "<!-- findings -->"
    if OUT_DOC.is_file() and marker in OUT_DOC.read_text():  # the written findings below the tables are kept
        text += "\n" + marker + OUT_DOC.read_text().split(marker, 1)[1]
    OUT_DOC.write_text(text)  # (the findings part holds --image-learning's section)


FINAL = [("quick-split-spectrum", 1), ("quick-broadband", 1), ("hyperbolic-532", 1)]
LONGER = ("quick-split-spectrum", 3)  # --longer: the split preset trained 3× as many steps, for convergence


def final_runs(out: Path, reuse: bool, longer: bool) -> list[str]:
    """The quick presets as they are (``longer``: and the split one 3× longer), trained by ``metalens optimize``."""
    from metalens_cli.io.presets import load_preset

    runs = []
    for name, factor in FINAL + ([LONGER] if longer else []):
        preset_path = ROOT / "presets" / f"{name}.toml"
        steps = load_preset(preset_path).optimize.steps * factor
        run = out / (f"final-{name}" + (f"-{factor}x" if factor > 1 else ""))
        if not (reuse and (run / "run.json").is_file()):
            if run.exists():
                subprocess.run(["rm", "-rf", str(run)], check=True)
            metalens("optimize", str(preset_path), "-o", str(run), "--steps", str(steps))
        runs.append(str(run))
    return runs


PASS_BANDS = {"B": (446e-9, 468e-9), "G": (520e-9, 540e-9), "R": (614e-9, 642e-9)}  # 457/22, 530/20, 628/28 nm


def band_energy(run: str) -> dict:
    """{depth: {channel: mean 5 × 5 energy over the pass band}} for a run directory."""
    import torch

    from metalens_cli.io.designs import resolve_design
    from metalens_cli.optics.psf import compute_psf
    from metalens_cli.optics.sampling import PsfGrid

    design = resolve_design(run)
    out = {"far": {}, "near": {}}
    for channel, (lo, hi) in PASS_BANDS.items():
        waves = list(np.arange(lo, hi + 0.5e-9, 1e-9))
        psf = (
            compute_psf(
                design.lens,
                PsfGrid(waves, [math.inf, NEAR_M], 5, design.preset.sensor.pixel_pitch_m, design.focal_length_m),
                dtype=torch.float64,
            )
            .psf.sum(dim=(-2, -1))
            .numpy()
        )
        out["far"][channel], out["near"][channel] = float(psf[0].mean()), float(psf[1].mean())
    return out


def final_section(runs: list[str]) -> list[str]:
    """The quick runs against each other and the hyperbolic lens at 512², 3 seeds, paired CIs."""
    report = metalens("evaluate", *runs, "--pixels", "512", "--seed", "0:2", "--obstruction", "dirt,fence")
    label = {run: Path(run).name.removeprefix("final-") for run in runs}
    steps = {run: json.loads((Path(run) / "run.json").read_text())["settings"]["steps"] for run in runs}
    minutes = {run: json.loads((Path(run) / "run.json").read_text())["cost"]["seconds_training"] / 60 for run in runs}
    lines = [
        "",
        "## The quick presets as they are, at the full 512 × 512 sensor",
        "",
        "`metalens evaluate " + " ".join(f"runs/study/{Path(r).name}" for r in runs) + " --pixels 512 --seed 0:2 "
        "--obstruction dirt,fence` (9 held-out photographs × 3 seeds = 27 units per cell; raw captures; "
        "PSNR in dB after the least-squares match, mean [95 % bootstrap CI]). `-3x`: the same preset trained 3× as "
        "many steps.",
        "",
        "| design | steps | training min | unobstructed | dirt obstructed | fence obstructed | dirt Δ | fence Δ |",
        "|---|---|---|---|---|---|---|---|",
    ]
    rows = {
        (r["design"], r["obstruction"], r["condition"]): r for r in report["rows"] if r.get("capture", "raw") == "raw"
    }
    deltas = {(d["design"], d["obstruction"]): d for d in report["deltas"] if d.get("capture", "raw") == "raw"}

    def cell(value, ci):
        return f"{value:.2f} [{ci[0]:.2f}, {ci[1]:.2f}]"

    for run in runs:
        u = rows[run, "dirt", "unobstructed"]
        cells = [cell(u["psnr_db"], u["psnr_db_ci"])]
        cells += [
            cell(rows[run, k, "obstructed"]["psnr_db"], rows[run, k, "obstructed"]["psnr_db_ci"])
            for k in ("dirt", "fence")
        ]
        cells += [cell(deltas[run, k]["delta_psnr_db"], deltas[run, k]["delta_psnr_db_ci"]) for k in ("dirt", "fence")]
        lines.append(f"| {label[run]} | {steps[run]} | {minutes[run]:.1f} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "Energy in the central 5 × 5 pixels (fraction of the power through the aperture), mean over each pass "
        "band of the tri-band filter at 1 nm (the split lens's; the broadband and hyperbolic lenses measured in the "
        "same bands), far (∞) and near (45 mm):",
        "",
        "| design | "
        + " | ".join(f"far {c}" for c in PASS_BANDS)
        + " | "
        + " | ".join(f"near {c}" for c in PASS_BANDS)
        + " |",
        "|---|" + "---|" * (2 * len(PASS_BANDS)),
    ]
    bands = {run: band_energy(run) for run in runs}
    for run in runs:
        lines.append(
            f"| {label[run]} | "
            + " | ".join(f"{bands[run][d][c]:.4f}" for d in ("far", "near") for c in PASS_BANDS)
            + " |"
        )
    lines += [
        "",
        "Paired PSNR differences on the same units (dB, 95 % CI):",
        "",
        "| design − versus | condition | dirt | fence |",
        "|---|---|---|---|",
    ]
    pairs = {}
    for c in report["comparisons"]:
        if c["metric"] == "psnr_db" and c.get("capture", "raw") == "raw" and c.get("versus_capture", "raw") == "raw":
            pairs.setdefault((c["design"], c["versus"], c["condition"]), {})[c["obstruction"]] = cell(
                c["difference"], c["ci"]
            )
    for (design, versus, condition), by_kind in pairs.items():
        lines.append(
            f"| {label.get(design, design)} − {label.get(versus, versus)} | {condition} | "
            f"{by_kind.get('dirt', '—')} | {by_kind.get('fence', '—')} |"
        )
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "study")
    parser.add_argument("--reuse", action="store_true")
    parser.add_argument("--only", nargs="*", help="variant names to run (others are skipped)")
    parser.add_argument("--no-final", action="store_true", help="skip the quick presets' full runs at 512²")
    parser.add_argument("--longer", action="store_true", help="also train the split preset 3× longer (convergence)")
    parser.add_argument(
        "--image-learning",
        action="store_true",
        help="only issue 59's experiment (examples/image_learning.py): image-only training under the camera; "
        "rewrites its own section of docs/training.md",
    )
    args = parser.parse_args()
    if args.image_learning:
        import image_learning

        image_learning.run(ROOT / "runs", args.reuse, OUT_DOC)
        return
    results = []
    for name, preset_name, overrides, what in VARIANTS:
        if args.only and name not in args.only:
            continue
        result = run_variant(name, preset_name, overrides, args.out, args.steps, args.reuse)
        result["what"] = what
        results.append(result)
        (args.out / "results.json").write_text(json.dumps(results, indent=1))
    reference = {}
    for camera, preset_name in (("broadband", "quick-broadband"), ("split-spectrum", "quick-split-spectrum")):
        ref_preset = variant_preset(preset_name, {}, args.out / "presets" / f"reference-{camera}.toml")
        reference[camera] = {"scores": scores(REFERENCE, ref_preset), "core": core_energy(REFERENCE, ref_preset)}
    final = [] if args.no_final else final_section(final_runs(args.out, args.reuse, args.longer))
    write(results, reference, args.steps, final)


if __name__ == "__main__":
    main()
