"""Issue 59's decisive experiment: does learning θ from images beat the PSF-engineered design?

Run by ``python examples/training_study.py --image-learning [--reuse]``, which writes its section of
docs/training.md (between ``<!-- image-learning -->`` markers; the rest of the file is kept).

1. Three runs of ``metalens optimize`` under the verdict's camera (``[optimize] light``, the
   nanofin efficiency and zero-order leak of the evaluation), on the image terms only
   (``[loss] bright = sharp = 0``, L1 and SSIM in the metric's space, ``space = "metric"``):
   - from each learned quick lens (``[optimize] init_from`` = runs/quick-split-spectrum and
     runs/quick-broadband), a fine-tune at a third of the training's learning rate;
   - from the paper's initialisation (the hyperbolic 532 nm θ), ``INIT_STEPS`` steps.
   At the batch and crop of the quick presets (2, 128²) with 12 wavelengths a channel at the
   strata midpoints (a fixed quadrature: docs/steering.md found the random spectral draws to be
   the image gradient's noise; fixed wavelengths also keep the radial kernels cached).
2. ``metalens evaluate`` of the five lenses (two starts, their fine-tunes, the run from θ_init) on
   the photographs at the paper's 512² sensor, 3 seeds, dirt and fence, at the verdict's light
   levels, on axis; the paired differences fine-tune − start.
3. Each run's steering at its start and end (run.json ``validation_loss.steering``: the image
   gradient's SNR over draws) and cost.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CAMERA_LIGHT = 2000  # e⁻ at full scale before the filter: the verdict's indoor level (docs/verdicts.md)
LIGHT = "none,250,2000,20000"  # the verdict's light levels (examples/camera_verdicts.py)
# the camera and the image-only loss every run of this experiment trains under
IMAGE_CAMERA = {
    "optimize": {"light": CAMERA_LIGHT, "wavelengths_per_channel": 12, "spectral_sampling": "midpoint"},
    "loss": {"bright": 0.0, "sharp": 0.0, "space": "metric"},
    "sensor": {"full_pixels": 512},
}
FINE_TUNE_RATE = 1 / 3  # a fine-tune's learning rate, a share of the preset's
# evaluate's estimate sizes the PSF plan by the geometric window (1627-1803 px for the fine-tuned split lens), where
# its light needs 1437-1571 px: 23.8 GiB estimated against 5.4 GB measured at peak (1 seed, 64²); this lets it run
MAX_MEMORY = "40GiB"
INIT_STEPS = 150  # the run from θ_init: half the quick schedule (what 2 cores allowed in one session)
# run → (preset, start run or None for θ_init, what it is)
RUNS = {
    "image-ft-quick-split-spectrum": (
        "quick-split-spectrum",
        "quick-split-spectrum",
        "split lens, fine-tuned on images",
    ),
    "image-ft-quick-broadband": ("quick-broadband", "quick-broadband", "broadband lens, fine-tuned on images"),
    "image-init-split-spectrum": ("quick-split-spectrum", None, "split camera, trained on images from θ_init"),
}
PAIRS = [  # (design, versus): paired differences reported
    ("image-ft-quick-split-spectrum", "quick-split-spectrum"),
    ("image-ft-quick-broadband", "quick-broadband"),
    ("image-init-split-spectrum", "quick-split-spectrum"),
]
DESIGNS = ["quick-split-spectrum", "image-ft-quick-split-spectrum", "image-init-split-spectrum",
           "quick-broadband", "image-ft-quick-broadband"]  # fmt: skip


def run_preset(runs: Path, run: str) -> Path:
    """The preset of one run (written to RUNS/run.toml): the quick preset with ``IMAGE_CAMERA``,
    and a fine-tune's ``init_from`` and learning rate."""
    from metalens_cli.io.presets import load_preset, to_toml

    name, start, _ = RUNS[run]
    preset = load_preset(ROOT / "presets" / f"{name}.toml")
    overrides = {section: dict(values) for section, values in IMAGE_CAMERA.items()}
    if start is not None:
        overrides["optimize"]["init_from"] = str(runs / start)
        overrides["optimize"]["learning_rate"] = preset.optimize.learning_rate * FINE_TUNE_RATE
    else:
        overrides["optimize"].update(steps=INIT_STEPS, t_max=INIT_STEPS)
    for section, values in overrides.items():
        preset = dataclasses.replace(preset, **{section: dataclasses.replace(getattr(preset, section), **values)})
    path = runs / f"{run}.toml"
    path.write_text(to_toml(preset))
    return path


def train(runs: Path, reuse: bool) -> dict[str, dict]:
    """The three runs (``reuse``: finished ones are read back); their run.json and wall time."""
    import quick_results

    return quick_results.train(runs, reuse, list(RUNS), lambda run: str(run_preset(runs, run)))


def evaluate(runs: Path, reuse: bool) -> tuple[dict, list[str], float]:
    """The five lenses on the photographs at 512², 3 seeds, dirt and fence, at ``LIGHT``, on axis;
    kept with its command in RUNS/verdicts/image-learning.json (``reuse``: read back for the same command)."""
    from quick_results import kept

    args = ["evaluate", *(str(runs / name) for name in DESIGNS), "--images", "photos",
            "--obstruction", "dirt,fence", "--pixels", "512", "--seed", "0:2", "--light", LIGHT, "--quiet",
            "--max-memory", MAX_MEMORY]  # fmt: skip
    report, seconds = kept(runs / "verdicts" / "image-learning.json", args, reuse)
    return report, args, seconds


def _steering(report: dict, when: str) -> str:
    image = report["validation_loss"]["steering"][when]["terms"]["image"]
    return f"{image['rms_snr']:.2f} ({image['share_above_1']:.0%})"


def _move(runs: Path, run: str) -> str:
    """How far the run moved θ from its start: rms and largest |Δθ| over the rings (rad)."""
    import numpy as np

    folder = runs / run
    start_file = folder / "start_theta.npy"
    theta = np.load(folder / "theta.npy")
    if start_file.is_file():
        start = np.load(start_file)
    else:
        from metalens_cli.design.model import build_model
        from metalens_cli.io.presets import load_preset

        start = build_model(load_preset(folder / "preset.toml")).full_theta().detach().numpy()
    delta = theta - start
    return f"{np.sqrt(np.mean(delta**2)):.2f} / {np.abs(delta).max():.2f}"


def section(runs: Path, reports: dict[str, dict], evaluation: tuple[dict, list[str], float]) -> str:
    """The markdown section of docs/training.md, from the runs' run.json and the evaluation's JSON."""
    report, args, seconds = evaluation
    label = {str(runs / name): name for name in DESIGNS}
    lines = [
        "## Learning from images under the verdict's camera (issue 59)",
        "",
        "Written by `python examples/training_study.py --image-learning` (examples/image_learning.py). Every run "
        f"trains under the verdict's camera ([optimize] light = {CAMERA_LIGHT} e⁻ at full scale before the filter, "
        "read noise 2.5 e⁻, the nanofin efficiency and the zero-order leak of `evaluate`) on the image terms "
        'alone (bright = sharp = 0; L1 and 1 − SSIM on the metric\'s images, `space = "metric"`), batch 2, '
        "128² crops, 12 wavelengths a channel at the strata midpoints, on axis, seed 0, the cosine schedule. "
        f"The fine-tunes start from the learned quick lenses (`init_from`) at {FINE_TUNE_RATE:.2g} × the preset's "
        f"learning rate for the preset's 300 steps; the third run starts from the paper's θ_init at the preset's "
        f"rate for {INIT_STEPS} steps.",
        "",
        "| run | what | s/step | wall | image-gradient RMS SNR (share > 1), start → end "
        "| Δθ from its start, rms / max (rad) |",
        "|---|---|---|---|---|---|",
    ]
    for run, (_, _, what) in RUNS.items():
        r = reports[run]
        wall = r.get("wall_s", r["cost"]["seconds_training"])
        lines.append(
            f"| {run} | {what} | {r['cost']['seconds_per_step_median']:.1f} | {wall / 60:.0f} min | "
            f"{_steering(r, 'initial')} → {_steering(r, 'final')} | {_move(runs, run)} |"
        )
    lines += [
        "",
        f"`metalens {' '.join(args[:1])} …` ({' '.join(args[len(DESIGNS) + 1 :])}): {seconds / 60:.0f} min. "
        "PSNR (dB) of raw captures after the least-squares match, mean over 9 photographs × 3 seeds = 27 units:",
        "",
        "| design | light | dirt unobstructed | dirt obstructed | fence obstructed |",
        "|---|---|---|---|---|",
    ]
    cell = {}
    for row in report["rows"]:
        if row["capture"] == "raw":
            cell[(label.get(row["design"], row["design"]), row["light"], row["obstruction"], row["condition"])] = row
    lights = list(dict.fromkeys(row["light"] for row in report["rows"]))
    for name in DESIGNS:
        for light in lights:
            values = [cell.get((name, light, o, c)) for o, c in
                      (("dirt", "unobstructed"), ("dirt", "obstructed"), ("fence", "obstructed"))]  # fmt: skip
            shown = ("—" if v is None else f"{v['psnr_db']:.2f}" for v in values)
            lines.append(f"| {name} | {light} | " + " | ".join(shown) + " |")
    lines += paired_table(report, label, lights, "psnr_db", "PSNR (dB)", 2)
    lines += paired_table(report, label, lights, "ssim", "SSIM (the loss's 1 − SSIM term)", 3)
    return "\n".join(lines) + "\n"


def paired_table(report: dict, label: dict, lights: list[str], metric: str, name: str, digits: int) -> list[str]:
    """Markdown rows of the paired differences design − its start in ``metric`` for ``PAIRS``."""
    lines = [
        "",
        f"Paired differences in {name}, mean [95 % CI] over the 27 units, design − its start:",
        "",
        "| design − start | light | dirt unobstructed | dirt obstructed | fence obstructed |",
        "|---|---|---|---|---|",
    ]
    comparisons = {}
    for c in report["comparisons"]:
        if c["metric"] == metric and c["capture"] == "raw" and c["versus_capture"] == "raw":
            key = (label.get(c["design"]), label.get(c["versus"]), c["light"], c["obstruction"], c["condition"])
            comparisons[key] = c
    for design, versus in PAIRS:
        for light in lights:
            cells = []
            for o, cond in (("dirt", "unobstructed"), ("dirt", "obstructed"), ("fence", "obstructed")):
                c, sign = comparisons.get((design, versus, light, o, cond)), 1
                if c is None:
                    c, sign = comparisons.get((versus, design, light, o, cond)), -1
                if c is None:
                    cells.append("—")
                    continue
                lo, hi = sorted(sign * x for x in c["ci"])
                cells.append(f"{sign * c['difference']:+.{digits}f} [{lo:+.{digits}f}, {hi:+.{digits}f}]")
            lines.append(f"| {design} − {versus} | {light} | " + " | ".join(cells) + " |")
    return lines


def write_section(doc: Path, text: str) -> None:
    """Put ``text`` between the ``<!-- image-learning -->`` markers of ``doc`` (appended if absent)."""
    start, end = "<!-- image-learning -->", "<!-- /image-learning -->"
    current = doc.read_text(encoding="utf-8")
    block = f"{start}\n{text}{end}"
    if start in current:
        head, rest = current.split(start, 1)
        current = head + block + rest.split(end, 1)[1]
    else:
        current = current.rstrip("\n") + "\n\n" + block + "\n"
    doc.write_text(current, encoding="utf-8")


def run(runs: Path, reuse: bool, doc: Path) -> None:
    """Train, evaluate and write the section."""
    reports = train(runs, reuse)
    write_section(doc, section(runs, reports, evaluate(runs, reuse)))
