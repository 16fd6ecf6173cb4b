"""Regenerate docs/field_training.md: does a lens trained over the field beat one trained on axis?

One off-axis training step of the paper's lens is 18 PSFs through the whole 2.5-mm aperture (3.4 s
each forward on 2 CPU cores, about as much again backward): minutes a step. So this study trains the
paper's camera scaled down 4× (examples/scaled-split-spectrum.toml: f = 1 mm, D = 0.629 mm, the same
NA and field of view on a 128² sensor, depths and obstructions / 16), where an off-axis step costs
15-32 s (34-46 min a run over the field).

1. ``metalens optimize`` of that preset on axis (runs/scaled-axis) and with ``[optimize]
   field_angles`` 0°, 4.75°, 9.5° (runs/scaled-field: the axis, half-way and the corner) and 3.1°,
   5.4°, 7.0° (runs/scaled-field-area: the middles of the three thirds of the sensor's pixels by
   field angle, so every pixel weighs the same), the same seed and a schedule of ``STEPS`` steps
   (presets written to runs/<run>.toml; ``--reuse`` keeps finished runs).
2. ``metalens psf-scan --field-angles`` of the three runs and of the same camera's hyperbolic lens at the
   filter's centre wavelengths, source at infinity, to the sensor's corner; ``metalens mtf``:
   tangential and sagittal MTF50 per field.
3. ``metalens evaluate`` of the four on the photographs at 128², once with the on-axis model and
   once with ``--field auto`` (fixed depths 2.8 mm and 31.25 cm, the 45 mm and 5 m of docs/field.md
   over 16): each design's scores, the paired differences field-trained − axis-trained, and
   field − on-axis per design.

    python examples/field_training.py [--reuse]
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from field_results import WAVELENGTHS, _lpmm, field_differences, metalens

ROOT = Path(__file__).resolve().parents[1]
PRESET = "examples/scaled-split-spectrum.toml"
STEPS = 100  # a third of the quick schedule: an off-axis step of the learned lens costs 23-32 s on 2 cores
FIELD_RUNS = {  # trained over the field: run → field angles (deg)
    "runs/scaled-field": (0.0, 4.75, 9.5),  # the axis, half-way and the 128² sensor's corner (atan(90.5 px · p / f))
    "runs/scaled-field-area": (3.1, 5.4, 7.0),  # the 1/6, 1/2 and 5/6 quantiles of the pixels' field angles
}
FIELDS_DEG = (0.0, 2.25, 4.75, 6.75, 9.5)  # scanned: the axis to the corner, the sensor's edge (6.75°) among them
DESIGNS = {
    "runs/scaled-axis": "trained on axis",
    "runs/scaled-field": "trained over the field",
    "runs/scaled-field-area": "trained over the field by area",
    "hyperbolic:532nm": "hyperbolic 532 nm",
}
EVALUATE = ["--preset", PRESET, "--images", "photos", "--obstruction", "dirt,fence", "--seed", "0:2",
            "--z-near", "2.8mm", "--z-far", "312.5mm"]  # fmt: skip
PIXELS = 127  # psf-scan window: holds the corner's coma (rays land up to ~45 µm from the chief ray)
OUT = ROOT / "docs" / "field_training.md"


def train(reuse: bool) -> None:
    """The runs, from presets written to runs/ (``STEPS`` steps, the cosine schedule over them)."""
    from metalens_cli.io.presets import load_preset, to_toml

    preset = load_preset(ROOT / PRESET)
    schedule = {"steps": STEPS, "t_max": STEPS}
    runs = {"runs/scaled-axis": schedule}
    for run, angles in FIELD_RUNS.items():
        runs[run] = {**schedule, "field_angles_rad": tuple(math.radians(a) for a in angles)}
    for run, settings in runs.items():
        if reuse and (ROOT / run / "run.json").is_file():
            continue
        if (ROOT / run).exists():
            raise SystemExit(f"{run} exists: remove it or pass --reuse")
        written = ROOT / f"{run}.toml"
        written.parent.mkdir(exist_ok=True)
        written.write_text(to_toml(preset, optimize=settings))
        metalens("optimize", f"{run}.toml", "-o", run, "--quiet")


def scan(spec: str, reuse: bool) -> dict:
    """mtf's report of the design's field cube (runs/scaled-cube-<slug>.exr)."""
    slug = spec.split("/")[-1].replace(":", "-")
    cube = f"runs/scaled-cube-{slug}.exr"
    if not (reuse and (ROOT / cube).is_file()):
        design = ["--design", spec] + (["--preset", PRESET] if spec.startswith("hyperbolic") else [])
        metalens("psf-scan", *design, "--wavelengths", WAVELENGTHS, "--depths", "inf", "--pixels", str(PIXELS),
                 "--field-angles", ",".join(f"{a:g}deg" for a in FIELDS_DEG), "-o", cube, "--quiet")  # fmt: skip
    return metalens("mtf", cube)


def evaluate(model: str, reuse: bool) -> dict:
    saved = ROOT / "runs" / f"scaled-evaluate-{model}.json"
    if reuse and saved.is_file():
        return json.loads(saved.read_text())
    report = metalens("evaluate", *DESIGNS, *EVALUATE, "--field", model, "--max-time", "inf", "--quiet")
    saved.write_text(json.dumps(report))
    return report


def _ci(d: dict, digits: int) -> str:
    return f"{d['mean']:+.{digits}f} [{d['ci'][0]:+.{digits}f}, {d['ci'][1]:+.{digits}f}]"


def _between(report: dict, metric: str, run: str) -> dict[str, dict]:
    """condition → evaluate's paired difference, ``run`` (trained over the field) − trained on axis."""
    out = {}
    for c in report["comparisons"]:
        if c["capture"] != "raw" or c["metric"] != metric or c["condition"] not in ("unobstructed", "obstructed"):
            continue
        pair = (c["design"], c["versus"])
        sign = {(run, "runs/scaled-axis"): 1, ("runs/scaled-axis", run): -1}.get(pair)
        if sign:
            condition = c["condition"] if c["condition"] == "unobstructed" else c["obstruction"]
            lo, hi = sorted(sign * x for x in c["ci"])
            out[condition] = {"mean": sign * c["difference"], "ci": [lo, hi]}
    return out


def write(mtfs: dict[str, dict], on_axis: dict, field: dict) -> None:
    trained = [name for name in DESIGNS if name.startswith("runs/")]
    runs = {name: json.loads((ROOT / name / "run.json").read_text()) for name in trained}
    lines = [
        "# Training over the field of view",
        "",
        "Generated by `python examples/field_training.py` (do not edit by hand). The paper trains on axis. "
        "`[optimize] field_angles` draws a field angle per step and trains with that field point's PSFs "
        "(docs/training.md). At the paper's lens an off-axis step costs minutes on 2 CPU cores, so this "
        f"compares lenses of the paper's camera scaled down 4× (`{PRESET}`: f = 1 mm, D = 0.629 mm, "
        "the same NA 0.3 and ±6.75° to the 128² sensor's edge, 9.5° to its corner; depths and obstructions "
        "/ 16, the same defocus in waves; 4× fewer waves of coma than the paper's lens): the same preset, "
        "schedule and seed, one trained on axis and two over the field (each step one of its angles, equally "
        "likely): "
        + "; ".join(
            f"{DESIGNS[run]}, `field_angles = " + ", ".join(f"{a:g}°" for a in angles) + "`"
            for run, angles in FIELD_RUNS.items()
        )
        + ". The first weighs the sensor's corner like its axis; the second puts each angle at the middle of a "
        "third of the sensor's pixels, so every pixel weighs the same.",
        "",
        "| run | steps | s/step (median) | training (min) |",
        "| --- | --- | --- | --- |",
    ]
    for name, report in runs.items():
        cost = report["cost"]
        lines.append(
            f"| {DESIGNS[name]} | {report['settings']['steps']} | {cost['seconds_per_step_median']:.2f} | "
            f"{cost['seconds_training'] / 60:.0f} |"
        )
    lines += [
        "",
        "## MTF50 over the field (lp/mm, tangential / sagittal)",
        "",
        "`metalens psf-scan --field-angles` (source at infinity, azimuth 0, a "
        f"{PIXELS}-pixel window on the chief ray) and `metalens mtf` (pixel aperture included; Nyquist 270 lp/mm; "
        "—: the MTF stays above 0.5 up to Nyquist).",
        "",
        "| design | λ | " + " | ".join(f"{a:g}°" for a in FIELDS_DEG) + " |",
        "| --- | --- | " + " | ".join("---" for _ in FIELDS_DEG) + " |",
    ]
    for spec, mtf in mtfs.items():
        by_lambda: dict[float, list[str]] = {}
        for entry in (e for f in mtf["fields"] for e in f["mtf50_lpmm"] if "wavelength_m" in e):
            by_lambda.setdefault(entry["wavelength_m"], []).append(
                f"{_lpmm(entry['tangential'])} / {_lpmm(entry['sagittal'])}"
            )
        for wavelength, cells in by_lambda.items():
            lines.append(f"| {DESIGNS[spec]} | {wavelength * 1e9:.0f} nm | " + " | ".join(cells) + " |")
    lines += [
        "",
        "## Photographs over the whole field",
        "",
        "`metalens evaluate " + " ".join([*DESIGNS, *EVALUATE]) + " --field on-axis|auto`: 9 photographs × 3 "
        "seeds, PSNR after the photometric match. Scores with the on-axis model (one PSF per depth, what "
        "training on axis optimises) and with the field-dependent one (`--field auto`: each output pixel "
        "its own PSF), mean and 95 % bootstrap CI; then the paired differences on the same units.",
        "",
        "| design | condition | PSNR on-axis model (dB) | PSNR field model (dB) | field − on-axis (dB) |",
        "| --- | --- | --- | --- | --- |",
    ]
    rows = {
        (model, r["design"], "unobstructed" if r["condition"] == "unobstructed" else r["obstruction"]): r
        for model, report in (("on-axis", on_axis), ("auto", field))
        for r in report["rows"]
        if r["capture"] == "raw"
    }
    differences = field_differences(on_axis, {**field, "designs": list(DESIGNS)})
    for spec in DESIGNS:
        for condition in ("unobstructed", "dirt", "fence"):
            cells = [
                f"{r['psnr_db']:.2f} [{r['psnr_db_ci'][0]:.2f}, {r['psnr_db_ci'][1]:.2f}]"
                for r in (rows["on-axis", spec, condition], rows["auto", spec, condition])
            ]
            lines.append(
                f"| {DESIGNS[spec]} | {condition} | "
                + " | ".join(cells)
                + f" | {_ci(differences[spec, condition, 'psnr_db'], 2)} |"
            )
    lines += [
        "",
        "Trained over the field − trained on axis, paired over the same units (PSNR dB / SSIM):",
        "",
        "| run | condition | on-axis model | field model |",
        "| --- | --- | --- | --- |",
    ]
    over_field = {}
    for run in FIELD_RUNS:
        between = {m: (_between(on_axis, m, run), _between(field, m, run)) for m in ("psnr_db", "ssim")}
        for condition in ("unobstructed", "dirt", "fence"):
            cells = [
                f"{_ci(between['psnr_db'][i][condition], 2)} / {_ci(between['ssim'][i][condition], 3)}" for i in (0, 1)
            ]
            lines.append(f"| {DESIGNS[run]} | {condition} | " + " | ".join(cells) + " |")
        over_field[run] = between["psnr_db"][1]["unobstructed"]
    lines += ["", _verdict(over_field, differences)]
    OUT.write_text("\n".join(lines) + "\n")


def _verdict(over_field: dict[str, dict], differences: dict) -> str:
    """Two sentences on the question, from each run's paired difference against the lens trained
    on axis (``over_field``: run → the field model's unobstructed PSNR difference)."""
    outcomes = []
    for run, between in over_field.items():
        lo, hi = between["ci"]
        outcome = "beats it" if lo > 0 else "loses to it" if hi < 0 else "does not resolvably differ from it"
        outcomes.append(f"the lens {DESIGNS[run]} {outcome}, {_ci(between, 2)} dB")
    cost = {spec: -differences[spec, "unobstructed", "psnr_db"]["mean"] for spec in ("runs/scaled-axis", *over_field)}
    return (
        "Over the whole field (the field model, unobstructed photographs), against the lens trained on axis: "
        + "; ".join(outcomes)
        + f". The on-axis model overstates the lens trained on axis by {cost['runs/scaled-axis']:.2f} dB, "
        + " and ".join(f"the one {DESIGNS[run]} by {cost[run]:.2f} dB" for run in over_field)
        + "."
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reuse", action="store_true", help="keep finished runs, cubes and evaluate reports")
    args = parser.parse_args()
    train(args.reuse)
    mtfs = {spec: scan(spec, args.reuse) for spec in DESIGNS}
    write(mtfs, evaluate("on-axis", args.reuse), evaluate("auto", args.reuse))


if __name__ == "__main__":
    main()
