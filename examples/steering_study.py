"""What steers θ on the quick lens: each loss term's gradient signal-to-noise ratio over draws
(``design.validation.steering``) against batch size, crop size and spectral sampling, under the
verdict's camera; writes docs/steering.md.

    python examples/steering_study.py [--draws 8] [--light 2000] [--out runs/steering]

Every configuration starts from the preset's θ_init (and from a finished run's θ with ``--theta
RUN``), on the same fixed validation draws; the camera is ``[optimize] light`` electrons before the
filter with 2.5 e⁻ read noise and the zero order's veil, the image terms on the metric's images
(``loss.space = "metric"``), L_bright over the whole 512² sensor.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import torch

from metalens_cli.design.model import build_model, plan_frequency
from metalens_cli.design.validation import steering
from metalens_cli.io.json_files import write_json
from metalens_cli.io.presets import load_preset

ROOT = Path(__file__).parents[1]
CONFIGS = (  # (batch size, crop pixels, wavelengths per channel, light: None = --light, 0 = noise-free)
    (2, 128, 3, None),
    (2, 128, 3, 0.0),
    (8, 128, 3, None),
    (32, 128, 3, None),
    (2, 256, 3, None),
    (8, 256, 3, None),
    (2, 128, 6, None),
    (2, 128, 12, None),
    (2, 128, 12, 0.0),
    (8, 128, 12, None),
    (2, 128, 24, None),
)


def configured(preset, batch: int, pixels: int, per_channel: int, light: float):
    """The quick preset at ``batch`` × ``pixels``² crops, ``per_channel`` wavelengths, under the camera."""
    return dataclasses.replace(
        preset,
        sensor=dataclasses.replace(preset.sensor, pixels=pixels, full_pixels=512),
        optimize=dataclasses.replace(
            preset.optimize, batch_size=batch, wavelengths_per_channel=per_channel, light=light
        ),
        loss=dataclasses.replace(preset.loss, space="metric"),
    )


def parse_configs(text: str) -> tuple:
    """``--configs`` "BxNxW[xL],…" (batch, crop pixels, wavelengths per channel, light; L 0: noise-free)."""
    configs = []
    for part in text.split(","):
        values = [float(v) for v in part.lower().split("x")]
        batch, pixels, per_channel = (int(v) for v in values[:3])
        configs.append((batch, pixels, per_channel, values[3] if len(values) > 3 else None))
    return tuple(configs)


def measure(preset_path: Path, draws: int, light: float, theta_run: Path | None, configs=CONFIGS) -> list[dict]:
    """One row per configuration at θ_init (``theta_run`` None) or at a run's last checkpoint."""
    base = load_preset(preset_path)
    rows = []
    start_name = "θ_init" if theta_run is None else theta_run.name
    for batch, pixels, per_channel, level in configs:
        level = light if level is None else level
        preset = configured(base, batch, pixels, per_channel, level)
        model = build_model(preset)
        if theta_run is not None:  # the run's last checkpoint: θ as the optimiser holds it
            from metalens_cli.design.rundir import RunDirectory
            from metalens_cli.imaging.restore import load_tensors

            model.load_state_dict(load_tensors(RunDirectory(theta_run).checkpoint_files()[-1])["model"])
        start = time.perf_counter()
        report = steering(model, preset, draws, "cpu", plan_frequency(preset))
        seconds = time.perf_counter() - start
        rows.append(
            {"theta": start_name, "batch": batch, "pixels": pixels, "per_channel": per_channel, "light": level}
            | {"seconds": seconds, **report}
        )
        terms = report["terms"]
        print(
            f"{start_name}: batch {batch:3d} crop {pixels:3d}² λ/ch {per_channel} light {level:g}: "
            f"image SNR {terms['image']['rms_snr']:.3g} "
            f"(l1 {terms['l1']['rms_snr']:.3g}, ssim {terms['ssim']['rms_snr']:.3g}), psf SNR "
            f"{terms['psf']['rms_snr']:.3g}, cos {report['cosine_image_psf']:+.3f}, {seconds:.0f} s",
            flush=True,
        )
    return rows


def _light(level: float) -> str:
    return "noise-free" if not level else f"{level:g}"


def table(rows: list[dict]) -> str:
    head = (
        "| θ | light (e⁻) | batch | crop | λ per channel | image SNR (rms / median / share > 1) | L1 SNR | "
        "1 − SSIM SNR | PSF SNR | ‖image‖ / ‖PSF‖ | cos(image, PSF) | seconds |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|\n"
    )
    lines = []
    order = list(dict.fromkeys(r["theta"] for r in rows))
    for r in sorted(rows, key=lambda r: order.index(r["theta"])):  # stable: each θ's rows together
        t = r["terms"]
        img, psf = t["image"], t["psf"]
        lines.append(
            f"| {r['theta']} | {_light(r['light'])} | {r['batch']} | {r['pixels']}² | {r['per_channel']} | "
            f"{img['rms_snr']:.3g} / {img['median_snr']:.3g} / "
            f"{100 * img['share_above_1']:.0f} % | {t['l1']['rms_snr']:.3g} | {t['ssim']['rms_snr']:.3g} | "
            f"{psf['rms_snr']:.3g} | {img['mean_norm'] / psf['mean_norm']:.3g} | {r['cosine_image_psf']:+.3f} | "
            f"{r['seconds']:.0f} |"
        )
    return head + "\n".join(lines) + "\n"


def findings(rows: list[dict]) -> str:
    """What the table says, from its numbers: per θ, the largest image SNR and where, and whether any
    configuration lifts it past 1."""
    out = []
    for theta in dict.fromkeys(r["theta"] for r in rows):
        mine = [r for r in rows if r["theta"] == theta]
        best = max(mine, key=lambda r: r["terms"]["image"]["rms_snr"] or 0.0)
        snr = best["terms"]["image"]["rms_snr"] or 0.0
        where = f"batch {best['batch']}, {best['pixels']}² crops, {best['per_channel']} wavelengths per channel"
        verdict = "exceeds 1" if snr > 1 else "stays below 1 in every configuration measured"
        out.append(
            f"- At {theta} the image terms' RMS SNR {verdict}; its largest is {snr:.2f} "
            f"({where}, {_light(best['light'])} e⁻)."
        )
    return "\n".join(out) + "\n"


def write_doc(rows: list[dict], doc: Path, preset: Path, draws: int, light: float, thetas: list[str]) -> None:
    """docs/steering.md from the measured ``rows``."""
    where = "θ_init" + "".join(f" and at the last checkpoint of `{t}`" for t in thetas)
    text = (
        "# What steers θ: gradient signal-to-noise ratio against batch, crop and spectral sampling\n\n"
        f"Written by `python examples/steering_study.py --draws {draws} --light {light:g}"
        + "".join(f" --theta {t}" for t in thetas)
        + f"` (re-running it rewrites this file). `{preset}` at {where}, under the verdict's "
        f"camera: {light:g} e⁻ at full scale before the filter (each channel collects that × t_c), 2.5 e⁻ read "
        "noise, the zero order's veil; image terms on the metric's images (`loss.space = \"metric\"`: least-squares "
        "match, sRGB), L_bright over the whole 512² sensor. Each row: the same "
        f"{draws} fixed validation draws (depths, wavelengths, scenes, obstructions, noise; "
        "`design.validation.steering`). SNR is each gradient's mean over its standard deviation across draws, per "
        "parameter (256 spline coefficients), summarised as the root of the mean unbiased SNR² (rms; 0 where the "
        "estimate is at or below 0), the median, and the share of parameters above 1; image = L1 + (1 − SSIM), "
        "PSF = L_bright + L_sharp, each weighted as the preset weighs it. Under Adam a term steers a parameter when "
        "its SNR is of order 1 or more: below, its updates are mostly noise.\n\n" + findings(rows) + "\n" + table(rows)
    )
    doc.write_text(text, encoding="utf-8")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--preset", type=Path, default=ROOT / "presets" / "quick-split-spectrum.toml")
    parser.add_argument("--draws", type=int, default=8)
    parser.add_argument("--light", type=float, default=2000.0)
    parser.add_argument(
        "--theta", type=Path, action="append", default=[], help="a finished run whose θ to measure at too"
    )
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "steering")
    parser.add_argument("--doc", type=Path, default=ROOT / "docs" / "steering.md")
    parser.add_argument("--from-json", type=Path, default=None, help="rewrite the doc from a saved steering.json")
    parser.add_argument("--configs", type=parse_configs, default=CONFIGS, help='"BxNxW[xL],…" instead of the built-in')
    parser.add_argument("--merge", type=Path, default=None, help="a steering.json whose rows come first")
    args = parser.parse_args()
    torch.set_num_threads(2)
    if args.from_json is not None:
        rows = json.loads(args.from_json.read_text())
    else:
        rows = json.loads(args.merge.read_text()) if args.merge else []
        for theta in (None, *args.theta):
            rows += measure(args.preset, args.draws, args.light, theta, args.configs)
        args.out.mkdir(parents=True, exist_ok=True)
        write_json(args.out / "steering.json", rows)
    thetas = [f"runs/{t.name}" for t in args.theta]
    write_doc(rows, args.doc, args.preset.resolve().relative_to(ROOT), args.draws, args.light, thetas)
    print(json.dumps({"doc": str(args.doc), "rows": len(rows)}))


if __name__ == "__main__":
    main()
