"""Write docs/filter.md: the filter learned with the lens against the paper's fixed filter.

    python examples/filter_study.py [--out runs/filter] [--reuse] [--train-only]

Seven runs of ``metalens optimize`` from presets/quick-joint-filter.toml (300 steps, seed 0, the
same θ budget, the same band-following spectral quadrature and shot noise for all):

- ``joint-40-50``: the preset as it is: θ and the filter learned together, obstructions at
  40-50 mm, the split-spectrum conditions for rays up to 25.7° on the filter;
- ``light-40-50`` and ``light0.3-40-50``: the same with the light term, ``filter.light_weight``
  1 and 0.3;
- ``fixed-40-50``: the paper's filter fixed (``filter.learn = false``);
- ``*-30-40``: the same three with obstructions at 30-40 mm, where the paper's filter fails
  ``bands check`` even at normal incidence (``filter.max_incidence = "0deg"``).

Each pair is then scored by ``metalens evaluate JOINT FIXED --pixels 512 --seed 0:2 --obstruction
dirt,fence`` without noise and with ``--photons N --photons-before-filter`` for N = 2000 (the
training light) and 250 (the held-out photographs, raw captures, each design's channels with its
own filter's share of the light) and ``metalens bands check --preset RUN/preset.toml``; the filters' throughput comes
from each run's run.json. ``--reuse`` keeps finished run directories. Every number in the written file comes from those
outputs.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT_DOC = ROOT / "docs" / "filter.md"
PRESET = ROOT / "presets" / "quick-joint-filter.toml"
PHOTONS = 2000  # the joint preset's training light
LIGHTS = (None, PHOTONS, 250)  # evaluated: no noise, the training light, 8× less
# (name, z_near, learn, max_incidence, light_weight)
RUNS = [
    ("light-40-50", (0.04, 0.05), True, "25.7deg", 1.0),
    ("light0.3-40-50", (0.04, 0.05), True, "25.7deg", 0.3),
    ("joint-40-50", (0.04, 0.05), True, "25.7deg", 0.0),
    ("fixed-40-50", (0.04, 0.05), False, "25.7deg", 1.0),
    ("light-30-40", (0.03, 0.04), True, "0deg", 1.0),
    ("joint-30-40", (0.03, 0.04), True, "0deg", 0.0),
    ("fixed-30-40", (0.03, 0.04), False, "0deg", 1.0),
]
SCENARIOS = [
    (("light-40-50", "light0.3-40-50", "joint-40-50"), "fixed-40-50", "40mm:50mm", "40-50 mm, rays up to 25.7°"),
    (("light-30-40", "joint-30-40"), "fixed-30-40", "30mm:40mm", "30-40 mm, normal incidence"),
]


def metalens(*args: str, check: bool = True) -> dict:
    """``metalens ARGS --json`` from the repository root; its JSON (exit 1 allowed with ``check=False``)."""
    command = [sys.executable, "-m", "metalens_cli", *args, "--json"]
    print("$ metalens " + shlex.join(args), file=sys.stderr, flush=True)
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
    if done.returncode not in ((0,) if check else (0, 1)):
        raise SystemExit(f"metalens {shlex.join(args)} failed ({done.returncode}): {done.stderr.strip()}")
    return json.loads(done.stdout)


def run_preset(name: str, z_near: tuple[float, float], learn: bool, incidence: str, light: float, out: Path) -> Path:
    """The variant of the joint preset, written beside its run."""
    from metalens_cli.io.presets import load_preset, to_toml

    text = to_toml(
        load_preset(PRESET),
        filter={"learn": learn, "max_incidence": incidence, "light_weight": light},
        scene={"z_near_m": z_near},
    )
    path = out / f"{name}.toml"
    path.write_text(text.replace('name = "quick-joint-filter"', f'name = "{name}"'))
    return path


def train(out: Path, reuse: bool) -> None:
    out.mkdir(parents=True, exist_ok=True)
    for name, z_near, learn, incidence, light in RUNS:
        run = out / name
        if reuse and (run / "run.json").is_file():
            continue
        subprocess.run(["rm", "-rf", str(run)], check=True)
        preset = run_preset(name, z_near, learn, incidence, light, out)
        metalens("optimize", str(preset.relative_to(ROOT)), "-o", str(run.relative_to(ROOT)), "--quiet")


def cell(value: float, ci) -> str:
    return f"{value:.2f} [{ci[0]:.2f}, {ci[1]:.2f}]"


def nm(value_m: float) -> str:
    return f"{value_m * 1e9:.1f}"


def filter_lines(out: Path) -> list[str]:
    lines = [
        "| run | z_near | bands (nm, FWHM) | edge (nm) | throughput R / G / B | bands check | smallest margin (nm) |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, z_near, *_ in RUNS:
        run = out / name
        report = json.loads((run / "run.json").read_text())
        f = report["preset"]["filter"]
        share = report["filter"]["learned"]["throughput"] if "filter" in report else throughput(run)
        checked = metalens("bands", "check", "--preset", str((run / "preset.toml").relative_to(ROOT)), check=False)
        margin = min(c["margin_m"] for c in checked["conditions"])
        bands = ", ".join(f"{nm(c - w / 2)}-{nm(c + w / 2)}" for c, w in zip(f["centers_m"], f["widths_m"]))
        lines.append(
            f"| {name} | {z_near[0] * 1e3:g}-{z_near[1] * 1e3:g} mm | {bands} | {f['edge_width_m'] * 1e9:.2f} | "
            f"{share['R']:.3f} / {share['G']:.3f} / {share['B']:.3f} | {'passes' if checked['ok'] else 'fails'} | "
            f"{margin * 1e9:+.2f} |"
        )
    return lines


def cost_line(out: Path) -> str:
    """Seconds per step of the joint and the fixed-filter preset, and of the quick split preset
    (importance samples, no noise), each over 30 steps from θ_init in this process (run alone)."""
    import torch

    from metalens_cli.design.training import time_steps
    from metalens_cli.io.presets import load_preset

    torch.set_num_threads(2)
    cases = [
        ("light-40-50", load_preset(out / "light-40-50.toml")),
        ("fixed-40-50", load_preset(out / "fixed-40-50.toml")),
        ("quick-split-spectrum", load_preset(ROOT / "presets" / "quick-split-spectrum.toml")),
    ]
    seconds = {name: time_steps(preset, steps=30)["seconds_per_step"] for name, preset in cases}
    return (
        "Cost, 2 CPU threads, median over steps 2-30 from θ_init (`design.training.time_steps`, one process, nothing "
        "else running): "
        + ", ".join(f"{name} {value:.2f} s/step" for name, value in seconds.items())
        + " (3 importance samples per channel, no noise)."
    )


def throughput(run: Path) -> dict:
    from metalens_cli.io.preset_spectra import channel_throughput
    from metalens_cli.io.presets import load_preset

    return dict(zip("RGB", channel_throughput(load_preset(run / "preset.toml")).tolist()))


def evaluation_lines(out: Path, learned: tuple[str, ...], fixed: str, z_near: str, title: str) -> list[str]:
    names = [*learned, fixed]
    base = [
        *(str((out / n).relative_to(ROOT)) for n in names),
        "--pixels",
        "512",
        "--seed",
        "0:2",
        "--obstruction",
        "dirt,fence",
        "--z-near",
        z_near,
    ]
    lines = [
        f"### Obstructions at {title}",
        "",
        f"`metalens evaluate {' '.join(base)} [LIGHT]`, LIGHT one of: none (no noise), "
        + ", ".join(f"`--photons {n} --photons-before-filter`" for n in LIGHTS if n)
        + ". 9 photographs × 3 seeds = 27 "
        f"units per cell, PSNR (dB) after the least-squares match, mean [95 % CI]; paired: learned − {fixed} on the "
        "same units.",
        "",
        "| light (e⁻ before the filter) | design | unobstructed | dirt | fence |",
        "|---|---|---|---|---|",
    ]
    paired_lines = []
    for photons in LIGHTS:
        light = ["--photons", str(photons), "--photons-before-filter"] if photons else []
        report = metalens("evaluate", *base, *light, "--quiet")
        rows = {
            (Path(r["design"]).name, r["obstruction"], r["condition"]): r
            for r in report["rows"]
            if r.get("capture", "raw") == "raw"
        }
        for name in names:
            cells = [
                cell(rows[name, "dirt", "unobstructed"]["psnr_db"], rows[name, "dirt", "unobstructed"]["psnr_db_ci"])
            ]
            cells += [
                cell(rows[name, k, "obstructed"]["psnr_db"], rows[name, k, "obstructed"]["psnr_db_ci"])
                for k in ("dirt", "fence")
            ]
            lines.append(f"| {photons or 'no noise'} | {name} | " + " | ".join(cells) + " |")
        paired: dict = {}
        for c in report["comparisons"]:
            if (
                c["metric"] == "psnr_db"
                and Path(c["versus"]).name == fixed
                and c.get("capture", "raw") == "raw"
                and c.get("versus_capture", "raw") == "raw"
            ):
                paired.setdefault(Path(c["design"]).name, {}).setdefault(c["condition"], {})[c["obstruction"]] = cell(
                    c["difference"], c["ci"]
                )
        paired_lines += [
            f"| {photons or 'no noise'} | {name} | {paired[name]['unobstructed']['dirt']} | "
            f"{paired[name]['obstructed']['dirt']} | {paired[name]['obstructed']['fence']} |"
            for name in learned
        ]
    lines += [
        "",
        f"| light | learned − {fixed} | unobstructed | dirt | fence |",
        "|---|---|---|---|---|",
        *paired_lines,
        "",
    ]
    return lines


def write_doc(out: Path) -> None:
    lines = [
        "# Learning the filter with the lens",
        "",
        "Written by `python examples/filter_study.py` (text below the findings marker is kept). Seven runs of "
        "`metalens optimize` from `presets/quick-joint-filter.toml`, 300 steps each on 2 CPU cores, seed 0: the same θ "
        f"budget, the same band-following spectral quadrature (4 wavelengths per band) and shot noise ({PHOTONS} e⁻ at "
        "full scale before the filter, so each channel gets its filter's share) for all. `light-*` learn the filter "
        "with θ and the light term (`filter.light_weight` 1, or 0.3 where named), `joint-*` without it, `fixed-*` keep "
        "the paper's tri-band filter (457/530/628 nm, FWHM 22/20/28 nm, 2 nm edges).",
        "",
        "## The filters",
        "",
    ]
    lines += filter_lines(out)
    lines += ["", cost_line(out)]
    lines += [
        "",
        "Throughput: ∫T·CRF^c·η dλ / ∫CRF^c·η dλ per channel (the share of the unfiltered signal). Bands check: "
        "`metalens bands check --preset RUN/preset.toml` at the run's f, z_near and oblique incidence.",
        "",
        "## Photographs at the paper's 512 × 512 sensor",
        "",
    ]
    for scenario in SCENARIOS:
        lines += evaluation_lines(out, *scenario)
    text = OUT_DOC.read_text() if OUT_DOC.is_file() else ""  # read now: the findings may have been edited meanwhile
    findings = text[text.index("<!-- findings -->") :] if "<!-- findings -->" in text else "<!-- findings -->\n"
    OUT_DOC.write_text("\n".join(lines) + "\n" + findings)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "filter")
    parser.add_argument("--reuse", action="store_true", help="keep finished run directories")
    parser.add_argument("--train-only", action="store_true", help="train, write nothing else")
    args = parser.parse_args()
    out = args.out.resolve()
    train(out, args.reuse)
    if not args.train_only:
        write_doc(out)


if __name__ == "__main__":
    main()
