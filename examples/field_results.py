"""Regenerate docs/field.md: how sharp the three designs are over the paper's field of view.

1. ``metalens optimize`` trains presets/quick-split-spectrum.toml and presets/quick-broadband.toml
   into runs/ (skipped with --reuse when their run.json exists; the same runs as
   examples/quick_results.py).
2. ``metalens psf-scan --field-angles`` of each design and the hyperbolic baseline at the filter's
   centre wavelengths, source at infinity, from the axis to the 512² sensor's corner: field cubes
   in runs/field-*.exr.
3. ``metalens mtf`` of each cube: tangential and sagittal MTF50 per field and wavelength, and
   ``psf-scan``'s centroid (coma) and encircled energy per field.
4. ``metalens evaluate`` of the three designs on the photographs at 512², once with the on-axis
   model and once with ``--field auto`` (fixed depths, so one field PSF set per design; one design
   per run, 20-40 min each on 2 cores): the paired per-unit differences, field − on-axis, with 95 %
   bootstrap CIs: how much the on-axis model overstates each design. Reports kept in
   runs/evaluate_field_on-axis.json and runs/evaluate_field_auto-<design>.json (``--reuse``).
5. ``spectral_check`` per design: on-axis captures with the off-axis PSFs' spectral reduction, the
   on-axis quadrature and one twice as fine, to tell the field's effect from the spectrum's.
6. ``height_check`` per design: far PSFs in the middle of the first and the last interval of the
   set's heights against the model's interpolation there (runs/field-heights-<design>.json).

    python examples/field_results.py [--reuse] [--over-field split-spectrum,broadband,hyperbolic]
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DESIGNS = {
    "learned split-spectrum": ["--design", "runs/quick-split-spectrum"],
    "learned broadband": ["--design", "runs/quick-broadband"],
    "hyperbolic 532 nm": ["--design", "hyperbolic:532nm", "--preset", "presets/hyperbolic-532.toml"],
}
BLOCK = ("<!-- field_results -->", "<!-- /field_results -->")  # its section of docs/results.md
WAVELENGTHS = "457nm,530nm,628nm"  # the tri-band filter's centres
FIELDS_DEG = (0.0, 2.25, 4.5, 6.75, 9.5)  # to the 512² sensor's edge (6.75°) and corner (9.5°) at f = 4 mm
PIXELS = 255  # holds the corner's coma (rays land up to ~170 µm from the chief ray)
EVALUATED = {
    "runs/quick-split-spectrum": "split-spectrum",
    "runs/quick-broadband": "broadband",
    "presets/hyperbolic-532.toml": "hyperbolic",
}  # evaluate's design argument → the slug of its files in runs/
# evaluate --field-tolerance per design: the learned lenses' near sets at 0.01 need ~10⁴ eigen-PSFs
# (~18-20 GB with their spectra), past a 23-GB machine; 0.03 needs ~1800 (3.4 GiB with maps and spectra)
FIELD_TOLERANCE = {"split-spectrum": "0.03", "broadband": "0.03", "hyperbolic": "0.01"}
EVALUATE = ["--images", "photos", "--obstruction", "dirt,fence", "--pixels", "512", "--seed", "0:2",
            "--z-near", "45mm", "--z-far", "5m"]  # fmt: skip


def metalens(*args: str) -> dict:
    """Run ``metalens ARGS --json`` from the repository root; return its JSON."""
    command = [sys.executable, "-m", "metalens_cli", *args, "--json"]
    print("$ metalens " + shlex.join(args) + " --json", file=sys.stderr, flush=True)
    done = subprocess.run(command, cwd=ROOT, check=True, capture_output=True, text=True)
    return json.loads(done.stdout)


def train(reuse: bool) -> None:
    for name in ("quick-split-spectrum", "quick-broadband"):
        run = ROOT / "runs" / name
        if reuse and (run / "run.json").is_file():
            continue
        if run.exists():
            raise SystemExit(f"{run} exists: remove it or pass --reuse")
        metalens("optimize", f"presets/{name}.toml", "-o", str(run.relative_to(ROOT)), "--quiet")


def scan(label: str, spec: list[str], reuse: bool) -> tuple[dict, dict]:
    """The field cube of one design (psf-scan's report) and its MTF (mtf's report)."""
    slug = label.split()[1] if label.startswith("learned") else "hyperbolic"
    cube = f"runs/field-{slug}.exr"
    report_path = ROOT / "runs" / f"field-{slug}.json"
    if reuse and report_path.is_file() and (ROOT / cube).is_file():
        report = json.loads(report_path.read_text())
    else:
        angles = ",".join(f"{a:g}deg" for a in FIELDS_DEG)
        report = metalens(
            "psf-scan", *spec, "--wavelengths", WAVELENGTHS, "--depths", "inf", "--pixels", str(PIXELS),
            "--field-angles", angles, "-o", cube, "--quiet",
        )  # fmt: skip
        report_path.write_text(json.dumps(report))
    return report, metalens("mtf", cube)


def evaluate(model: str, reuse: bool, designs=tuple(EVALUATED)) -> dict:
    """``metalens evaluate`` with ``--field MODEL`` (kept in runs/): the three designs in one run
    on axis, one design a run over the field (``designs``; their units, PSF reports and rows put
    together, and the designs under ``designs``)."""
    runs = {"on-axis": list(EVALUATED)} if model == "on-axis" else {EVALUATED[d]: [d] for d in designs}
    reports = []
    for name, designs in runs.items():
        saved = ROOT / "runs" / f"evaluate_field_{name if model == 'on-axis' else model + '-' + name}.json"
        if reuse and saved.is_file():
            reports.append(json.loads(saved.read_text()))
            continue
        # the evaluate estimate counts a cached field PSF set as uncomputed: the measured peak is ~15 GB
        tolerance = [] if model == "on-axis" else ["--field-tolerance", FIELD_TOLERANCE[name]]
        report = metalens("evaluate", *designs, *EVALUATE, "--field", model, *tolerance, "--max-time", "inf",
                          "--max-memory", "22GiB", "--quiet")  # fmt: skip
        saved.write_text(json.dumps(report))
        reports.append(report)
    merged = {key: [x for r in reports for x in r[key]] for key in ("units", "psfs", "rows")}
    return {**merged, "designs": [d for names in runs.values() for d in names]}


def field_differences(on_axis: dict, field: dict) -> dict[tuple[str, str, str], dict]:
    """(design, condition, metric) → paired field − on-axis mean and CI over the same units."""
    from metalens_cli.analysis.statistics import paired_difference_ci

    def scores(report):
        out = {}
        for unit in report["units"]:
            if unit["capture"] != "raw":
                continue
            key = (unit["design"], unit["seed"], unit["image"])
            out.setdefault(("unobstructed", *key), unit["unobstructed"])
            out[(unit["obstruction"], *key)] = unit["obstructed"]
        return out

    a, b = scores(on_axis), scores(field)
    result = {}
    for design in field["designs"]:
        for condition in ("unobstructed", "dirt", "fence"):
            keys = sorted(k for k in a if k[0] == condition and k[1] == design)
            for metric in ("psnr_db", "ssim"):
                result[design, condition, metric] = paired_difference_ci(
                    [b[k][metric] for k in keys], [a[k][metric] for k in keys], metric=metric
                )
    return result


def spectral_check(spec: str) -> dict[str, list[dict]]:
    """Unobstructed on-axis captures of the photographs at 512² through ``spec`` at the far depth,
    with the on-axis quadrature (every 5 nm, ``full``), one twice as fine (every 2.5 nm, ``fine``)
    and the off-axis PSFs' spectral reduction (8 strata per channel, ``reduced``): the scores per
    photograph, in order. They say how much of the field − on-axis difference the reduction alone
    could make, and how converged the on-axis quadrature itself is."""
    import torch

    from metalens_cli.imaging.channel_psfs import channel_psfs
    from metalens_cli.imaging.field_psfs import field_strata, strata_channel_psfs
    from metalens_cli.imaging.formation import convolve
    from metalens_cli.imaging.images import load_images
    from metalens_cli.imaging.pipeline import DEFAULT_WAVELENGTHS, score
    from metalens_cli.io.designs import resolve_design
    from metalens_cli.io.units import parse_length_list

    design = resolve_design(str(ROOT / spec))
    pitch, every_5nm = 1.85e-6, parse_length_list(DEFAULT_WAVELENGTHS, "--wavelengths")
    full = channel_psfs(design, 0.045, 5.0, every_5nm, pitch).far
    n = full.shape[-1]
    every_2_5nm = np.linspace(every_5nm[0], every_5nm[-1], 2 * len(every_5nm) - 1)
    psfs = {
        "full": full.float(),
        "fine": channel_psfs(design, 0.045, 5.0, every_2_5nm, pitch, window=n).far.float(),
        "reduced": strata_channel_psfs(design, field_strata(design), [5.0], n, pitch)[0].float(),
    }
    scores = {name: [] for name in psfs}
    for image in load_images("photos", (512, 512), None, n // 2):
        canvas = torch.as_tensor(image.linear)
        for name, psf in psfs.items():
            capture = convolve(canvas, psf, n // 2).numpy()
            scores[name].append(score(capture, image.linear[:, n // 2 : -(n // 2), n // 2 : -(n // 2)]))
    return scores


def height_check(spec: str, reuse: bool) -> dict:
    """What the field model's interpolation between heights misses, at the far depth (5 m): the
    channel PSFs (8 strata a channel, as off axis) at the heights of the first and the last
    interval of a 512² set and at its middle pixel, against the model there, which on the +x axis
    is the linear interpolation of its two ends (``field_formation.field_psf``, ψ = 0). Per
    interval: the PSF's relative L2 per channel (a white-noise scene's, the metric of
    ``--field-tolerance``) and that of each photograph captured through the one PSF, true against
    modelled (shift-invariant, 512²). Kept in runs/field-heights-<slug>.json (``--reuse``)."""
    slug = EVALUATED[spec]
    path = ROOT / "runs" / f"field-heights-{slug}.json"
    if reuse and path.is_file():
        return json.loads(path.read_text())
    import torch

    from metalens_cli.imaging.field_psfs import field_heights, field_strata
    from metalens_cli.imaging.formation import convolve
    from metalens_cli.imaging.images import load_images
    from metalens_cli.io.designs import resolve_design
    from metalens_cli.optics.blur import psf_window
    from metalens_cli.optics.field import ON_AXIS_MARGIN, field_psf, field_window
    from metalens_cli.optics.sampling import PsfGrid

    print(f"# height check: {spec}", file=sys.stderr, flush=True)
    design = resolve_design(str(ROOT / spec))
    pitch, far, d = 1.85e-6, 5.0, design.focal_length_m
    strata = field_strata(design)
    lams = [float(x) for x in strata.wavelengths_m]
    weights = torch.as_tensor(strata.weights, dtype=torch.float64)
    heights = field_heights(512)
    corner = math.atan2(heights[-1] * pitch, d)
    n = field_window(design.lens, lams, far, corner, d, pitch, psf_window(design.lens, lams, [far], d, pitch))

    def channel_psfs(height: int) -> torch.Tensor:
        angle = math.atan2(height * pitch, d)
        mono = field_psf(design.lens, PsfGrid(lams, [far], n, pitch, d), angle, oversample=ON_AXIS_MARGIN).psf[0]
        rgb = torch.einsum("wij,cw->cij", mono.double(), weights)
        return rgb / rgb.sum((-2, -1), keepdim=True)

    images = load_images("photos", (512, 512), None, n // 2)
    intervals = []
    for lo, hi in ((heights[0], heights[1]), (heights[-2], heights[-1])):
        mid = (lo + hi) // 2
        low, true, high = (channel_psfs(h) for h in (lo, mid, hi))
        w = (mid - lo) / (hi - lo)
        model = (1 - w) * low + w * high
        psf_error = ((model - true).norm(dim=(-2, -1)) / true.norm(dim=(-2, -1))).tolist()
        capture_error = []
        for image in images:
            canvas = torch.as_tensor(image.linear)
            exact, approx = (convolve(canvas, psf.float(), n // 2) for psf in (true, model))
            capture_error.append(float((approx - exact).norm() / exact.norm()))
        intervals.append({"heights_px": [lo, mid, hi], "psf_error": psf_error, "capture_error": capture_error})
    result = {"design": spec, "depth_m": far, "window_px": n, "intervals": intervals}
    path.write_text(json.dumps(result, indent=1))
    return result


def unobstructed(report: dict, design: str, seed: int = 0) -> list[dict]:
    """``design``'s unobstructed raw scores in ``report`` per photograph, in order (one seed: with
    fixed depths and no noise they are the same for every seed)."""
    units = [u for u in report["units"] if u["design"] == design and u["capture"] == "raw" and u["seed"] == seed]
    first = units[0]["obstruction"]
    return [u["unobstructed"] for u in units if u["obstruction"] == first]


def write(
    path: Path, results: dict[str, tuple[dict, dict]], on_axis: dict, over_field: dict, heights: dict[str, dict]
) -> None:
    lines = [
        "# Over the field of view",
        "",
        "Generated by `python examples/field_results.py` (do not edit by hand). The paper's sensor, "
        "512 × 512 pixels of 1.85 µm behind f = 4 mm, spans ±6.75° to its edges and 9.5° to its corners; "
        "the paper simulates and reports the optical axis only. Here each design's PSF at infinity is "
        f"computed at field angles {', '.join(f'{a:g}°' for a in FIELDS_DEG)} (azimuth 0) at the tri-band "
        "filter's centre wavelengths, each in a 255-pixel window centred on its chief ray "
        "(`metalens psf-scan --field-angles`: the 2-D shifted angular spectrum over the whole aperture).",
        "",
        "## MTF50 over the field (lp/mm, tangential / sagittal)",
        "",
        "From `metalens mtf` of each field cube (pixel aperture included; Nyquist 270 lp/mm). The "
        "lens-design convention: tangential along the radius through the chief ray, sagittal across it.",
        "",
    ]
    mtf_table = len(lines)
    lines += [
        "| design | λ | " + " | ".join(f"{a:g}°" for a in FIELDS_DEG) + " |",
        "| --- | --- | " + " | ".join("---" for _ in FIELDS_DEG) + " |",
    ]
    for label, (_, mtf) in results.items():
        by_lambda: dict[float, list[str]] = {}
        for field in mtf["fields"]:
            for entry in field["mtf50_lpmm"]:
                if "wavelength_m" not in entry:
                    continue
                t, s = entry["tangential"], entry["sagittal"]
                by_lambda.setdefault(entry["wavelength_m"], []).append(f"{_lpmm(t)} / {_lpmm(s)}")
        for wavelength, cells in by_lambda.items():
            lines.append(f"| {label} | {wavelength * 1e9:.0f} nm | " + " | ".join(cells) + " |")
    mtf_table = lines[mtf_table:]
    lines += [
        "",
        "## Coma and spread over the field (µm)",
        "",
        "From `psf-scan`'s report: the centroid's offset from the chief ray along the radius (coma: "
        "Seidel theory gives sin α·a²/(2f) = 23 µm at 6.75° for the hyperbolic lens at its design "
        "wavelength) and the radius holding 80 % of the window's light, at 530 nm. Last column: the "
        "fraction of the light through the aperture that the 255-pixel window holds, over the fields and "
        "wavelengths (the rest is the halo of wavelengths far from focus; the MTFs describe what it holds). "
        "The learned lenses spread most of each wavelength's light into a wide halo (their extended depth "
        "of field), so their MTF50 sits at a few lp/mm wherever the core is sharp: compare their rows with "
        "each other across the field, not with the hyperbolic lens's.",
        "",
        "| design | " + " | ".join(f"{a:g}°: centroid, EE80 r" for a in FIELDS_DEG) + " | window keeps |",
        "| --- | " + " | ".join("---" for _ in FIELDS_DEG) + " | --- |",
    ]
    for label, (report, _) in results.items():
        cells = []
        for field in report["fields"]:
            (psf,) = [p for p in field["psfs"] if abs(p["wavelength_m"] - 530e-9) < 1e-12]
            cells.append(f"{psf['centroid_from_chief_ray_m'][0] * 1e6:+.1f}, {psf['ee80_radius_m'] * 1e6:.1f}")
        kept = [p["energy_in_window"] for field in report["fields"] for p in field["psfs"]]
        lines.append(f"| {label} | " + " | ".join(cells) + f" | {100 * min(kept):.0f}-{100 * max(kept):.1f} % |")
    labels = dict(zip(EVALUATED, DESIGNS))
    differences = field_differences(on_axis, over_field)
    lines += [
        "",
        "## Captures over the whole field against the on-axis model",
        "",
        "`metalens evaluate " + " ".join(EVALUATED) + " " + " ".join(EVALUATE) + " --field on-axis`, and "
        "`metalens evaluate DESIGN "
        + " ".join(EVALUATE)
        + " --field auto --field-tolerance T` per design ("
        + ", ".join(f"{d}: T = {FIELD_TOLERANCE[EVALUATED[d]]}" for d in over_field["designs"])
        + "; the learned lenses' near PSF sets at T = 0.01 need ~10⁴ eigen-PSFs, ~20 GB; the "
        "field-dependent PSF sets and the space-variant formation of `imaging.field_psfs` and "
        "`imaging.field_formation`; the depths fixed so that a design needs one set). The same units (9 "
        "photographs × 3 seeds) in both: per-unit differences field − on-axis, mean and 95 % bootstrap CI. "
        "Negative: the on-axis model overstates the design by that much. Obstructed rows: the field model's "
        "larger PSF windows widen the canvas, on which the obstruction of a unit is drawn anew, so those pairs "
        "share image and seed but not the obstruction's pattern (wider CIs).",
        "",
    ]
    missing = [labels[d] for d in EVALUATED if d not in over_field["designs"]]
    if missing:
        lines += [f"Not yet evaluated over the field: {', '.join(missing)}.", ""]
    capture_table = len(lines)
    lines += [
        "| design | condition | PSNR on axis (dB) | Δ PSNR, field − on-axis (dB) | SSIM on axis | Δ SSIM |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    rows = {
        (r["design"], "unobstructed" if r["condition"] == "unobstructed" else r["obstruction"]): r
        for r in on_axis["rows"]
        if r["capture"] == "raw"
    }

    def ci(d, digits):
        return f"{d['mean']:+.{digits}f} [{d['ci'][0]:+.{digits}f}, {d['ci'][1]:+.{digits}f}]"

    for design in over_field["designs"]:
        for condition in ("unobstructed", "dirt", "fence"):
            row = rows[design, condition]
            cells = []
            for metric, digits in (("psnr_db", 2), ("ssim", 3)):
                cells += [f"{row[metric]:.{digits}f}", ci(differences[design, condition, metric], digits)]
            lines.append(f"| {labels[design]} | {condition} | " + " | ".join(cells) + " |")
    capture_table = lines[capture_table:]
    from metalens_cli.analysis.statistics import paired_difference_ci

    lines += [
        "",
        "The off-axis PSFs are mixed from 8 wavelengths per channel (strata of equal weight), the on-axis ones "
        "from every 5 nm, so part of each unobstructed difference is the spectrum's, not the field's. "
        "`spectral_check` (examples/field_results.py) tells them apart on axis, where every quadrature is "
        "cheap: unobstructed captures of the photographs (seed 0; the far PSF) with the 8-strata reduction, "
        "with every 5 nm (evaluate's own captures: checked equal) and with every 2.5 nm. Paired differences, "
        "mean and 95 % bootstrap CI over the photographs, PSNR (dB) / SSIM:",
        "",
    ]
    spectral_table = len(lines)
    lines += [
        "| design | reduction − every 5 nm | every 2.5 nm − every 5 nm | field − reduction on axis |",
        "| --- | --- | --- | --- |",
    ]
    resolved = []
    for design in over_field["designs"]:
        spectral = spectral_check(design)
        field_scores = unobstructed(over_field, design)
        # the 5 nm captures are evaluate's own on-axis ones (the same scores)
        np.testing.assert_allclose(
            [u["psnr_db"] for u in spectral["full"]],
            [u["psnr_db"] for u in unobstructed(on_axis, design)],
            rtol=1e-3,
        )
        cells = []
        for a, b in ((spectral["reduced"], spectral["full"]), (spectral["fine"], spectral["full"]),
                     (field_scores, spectral["reduced"])):  # fmt: skip
            d = [paired_difference_ci([u[m] for u in a], [u[m] for u in b], metric=m) for m in ("psnr_db", "ssim")]
            cells.append(f"{ci(d[0], 2)} / {ci(d[1], 3)}")
        lines.append(f"| {labels[design]} | " + " | ".join(cells) + " |")
        if d[0]["ci"][1] < 0 or d[0]["ci"][0] > 0:
            resolved.append(labels[design])
    spectral_table = lines[spectral_table:]
    lines += [
        "",
        "The last column is the field's own effect on the unobstructed photographs, the spectrum held the same: "
        + (f"resolved (CI excludes 0) for {', '.join(resolved)}." if resolved else "resolved for no design.")
        + " The middle column is how converged the on-axis model's own quadrature is.",
    ]
    lines += ["", "What the field model cost and how accurate it is, per design (from `evaluate`'s JSON):", ""]
    lines += [
        "| design | model | heights (px) | windows near / far (px) | set (s) | sampling error "
        "| spectral error near / far | expansion error near / far (tolerance) "
        "| eigen-PSFs near / far (largest window, px) | expansion (s) | a capture (s, median) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for entry in [e for e in over_field["psfs"] if e["seed"] == 0]:
        test = entry.get("field", {})
        if test.get("model") != "field":
            lines.append(f"| {labels[entry['design']]} | {test.get('model', 'on-axis')} | | | | | | | | | |")
            continue
        windows = entry["field_psf_window_px"]
        spectral, expansion = entry["spectral_error"], test.get("expansion", {})
        lines.append(
            f"| {labels[entry['design']]} | field | {', '.join(map(str, entry['field_heights_px']))} | "
            f"{windows['near']} / {windows['far']} | {entry['field_psf_seconds']:.0f}"
            f"{' (cache)' if entry['field_psf_cached'] else ''} | "
            f"{entry['sampling_error']:.1e} | "
            f"{spectral['near']:.3f} / {spectral['far']:.3f} | "
            + (
                f"{expansion['near']['error']:.4f} / {expansion['far']['error']:.4f} "
                f"({expansion['near'].get('tolerance', 0.01):g}) | "
                f"{expansion['near']['eigen_psfs']} ({expansion['near']['support_px']}) / "
                f"{expansion['far']['eigen_psfs']} ({expansion['far']['support_px']}) | {expansion['seconds']:.0f} |"
                if expansion
                else "— | — | — |"
            )
            + (f" {test['formation']['median_seconds']:.1f} |" if "formation" in test else " — |")
        )
    lines += [
        "",
        "## Between the heights",
        "",
        "The set holds PSFs at heights 91 px apart, and the model interpolates linearly in ρ between them; "
        "the expansion's error above is measured against that model, not against the lens. `height_check` "
        "(examples/field_results.py) computes the far PSFs (5 m; 8 strata a channel, as off axis) at the middle "
        "pixel of the first and of the last interval and compares them with the model there: the PSFs' "
        "relative L2 per channel (a white-noise scene's, the metric of `--field-tolerance`), and that of each "
        "photograph (512²) captured through the true PSF against through the model's, median and largest of "
        "the 9.",
        "",
        "| design | heights (px) | PSF error R / G / B | a photograph's error (median / max) |",
        "| --- | --- | --- | --- |",
    ]
    for design, check in heights.items():
        for interval in check["intervals"]:
            psf_error = " / ".join(f"{100 * e:.1f} %" for e in interval["psf_error"])
            capture = interval["capture_error"]
            lines.append(
                f"| {labels[design]} | {', '.join(map(str, interval['heights_px']))} | {psf_error} | "
                f"{100 * float(np.median(capture)):.2f} / {100 * max(capture):.2f} % |"
            )
    worst_psf = max(max(i["psf_error"]) for c in heights.values() for i in c["intervals"])
    worst_capture = max(max(i["capture_error"]) for c in heights.values() for i in c["intervals"])
    lines += [
        "",
        f"Between its nodes the model's PSFs miss by up to {100 * worst_psf:.0f} % of their norm, far past the "
        "expansion's tolerance: a linear mix of two PSFs is not the PSF in between when its fine structure (a "
        "sharp core, a coma flare) moves or grows with the height. Photographs, whose power lies at low "
        f"frequencies, hardly see it: a capture through the model's PSF is within {100 * worst_capture:.2f} % "
        "of one through the true PSF. The set's own report (`height_error` in the JSON) leaves each interior "
        "height out instead, at no cost in PSFs (`imaging.field_formation.height_check`).",
    ]
    lines += [
        "",
        "Lenses trained over the field (`[optimize] field_angles`): docs/field_training.md "
        "(`examples/field_training.py`, on the paper's camera scaled down 4×).",
        "",
    ]
    path.write_text("\n".join(lines))
    results_block(
        [
            "## Over the field of view",
            "",
            "Written by `python examples/field_results.py` (this section only; the rest of this file by "
            "examples/quick_results.py, which keeps it). The paper reports the optical axis only; its 512² sensor "
            "spans 9.5° to the corners. How, and what it cost: docs/field.md.",
            "",
            "MTF50 (lp/mm, tangential / sagittal) at infinity over the field, from `metalens psf-scan "
            "--field-angles` and `metalens mtf`:",
            "",
            *mtf_table,
            "",
            "Captures of the photographs at 512², over the whole field (`evaluate --field auto`) against the "
            "on-axis model, the same units (9 photographs × 3 seeds), paired differences with 95 % CIs:",
            "",
            *capture_table,
            "",
            "Part of each difference is the off-axis PSFs' spectral reduction (8 wavelengths per channel). "
            "On axis, unobstructed, PSNR (dB) / SSIM:",
            "",
            *spectral_table,
        ]
    )


def results_block(lines: list[str], markers=BLOCK, path: Path = ROOT / "docs" / "results.md") -> None:
    """Put ``lines`` between a script's ``markers`` in docs/results.md (at its end if they are not
    there yet); examples/quick_results.py carries the block over when it rewrites the file."""
    text = path.read_text(encoding="utf-8")
    block = f"{markers[0]}\n" + "\n".join(lines) + f"\n{markers[1]}\n"
    if markers[0] in text:
        head, rest = text.split(markers[0], 1)
        text = head + block + rest.split(markers[1], 1)[1].lstrip("\n")
    else:
        text = text.rstrip("\n") + "\n\n" + block
    path.write_text(text, encoding="utf-8")


def _lpmm(value) -> str:
    return "—" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.0f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reuse", action="store_true", help="reuse runs/ and the field cubes found there")
    parser.add_argument(
        "--over-field",
        default=",".join(EVALUATED.values()),
        help="designs to evaluate over the field, of " + ", ".join(EVALUATED.values()) + " (default: all)",
    )
    args = parser.parse_args()
    slugs = {slug: design for design, slug in EVALUATED.items()}
    chosen = args.over_field.split(",")
    if unknown := [name for name in chosen if name not in slugs]:
        parser.error(f"--over-field: unknown design(s) {', '.join(unknown)}")
    train(args.reuse)
    results = {label: scan(label, spec, args.reuse) for label, spec in DESIGNS.items()}
    on_axis = evaluate("on-axis", args.reuse)
    over_field = evaluate("auto", args.reuse, [slugs[name] for name in chosen])
    heights = {design: height_check(design, args.reuse) for design in over_field["designs"]}
    write(ROOT / "docs" / "field.md", results, on_axis, over_field, heights)
    print("wrote docs/field.md", file=sys.stderr)


if __name__ == "__main__":
    main()
