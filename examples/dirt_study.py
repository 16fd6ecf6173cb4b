"""Write docs/obstructions.md: which physical effect sets the dirt ordering, and why ours is not the paper's.

    python examples/dirt_study.py [--runs runs] [--pixels 256] [--images 6] [--seeds 2] [--reuse]

1. The three quick designs of docs/results.md (``examples/quick_results.py`` trains them;
   ``--reuse`` keeps finished runs): their channel PSFs at z_near = 45 mm (the paper's
   experiment) and z_far = 5 m, with the zero-order light of the default camera
   (``imaging.camera``). Near PSFs: 5 × 5 core energy, the radius holding half the light and the
   near MTF per channel.
2. Dirt on the photographs (``--images`` of them × ``--seeds`` draws), noise-free: the obstructed
   minus unobstructed PSNR Δ as ``metalens evaluate`` scores it (sRGB, least-squares gain and
   bias), and the error the dirt adds (linear, ``imaging.obstruction_error``) split into its
   shadow, its own light, the zero-order light and the re-match, by channel and by spatial
   frequency band.
3. The same under variations of the dirt (cell size, opacity, its light), of the model (the
   paper's α-blend form, the zero-order leak), of the metric (the paper's luminance mean/std
   match) and in the paper's experimental setting (a printed pattern at 45 mm lit as the scene,
   the scene at 0.6 m, the luminance match).

Every number in the written file comes from this run; the raw results are kept in
``RUNS/dirt_study.json`` (``--reuse`` reads them back) and the figures in docs/figures/.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

from metalens_cli.imaging.images import LUMA_709

sys.path.insert(0, str(Path(__file__).resolve().parent))
from quick_results import DESIGNS, LABELS, PAPER_PSNR, ROOT, train  # noqa: E402

OUT = ROOT / "docs" / "obstructions.md"
FIGURES = ROOT / "docs" / "figures"
Z_NEAR_M = 0.045
# no zero-order light but in its two variations (it changes the error by a few %, below)
BASE = {
    "scale_m": 1.5e-3,
    "opacity": 1.0,
    "light": "soil",
    "formation": "physical",
    "match": "lstsq",
    "leak": 0.0,
    "register": False,
}
BASE_FAR_M = 5.0
# name, what it changes, overrides of BASE (z_far_m: the scene's depth)
VARIATIONS = [
    ("default", "1.5 mm Perlin cells, 15-35 % cover, dry-soil radiance (the preset's dirt)", {}),
    ("cells 0.3 mm", "finer dirt: specks of 0.3 mm and less", {"scale_m": 0.3e-3}),
    ("cells 0.75 mm", "", {"scale_m": 0.75e-3}),
    ("cells 3 mm", "coarser dirt", {"scale_m": 3e-3}),
    ("half opaque", "coverage × 0.5 (a film, not a crust)", {"opacity": 0.5}),
    ("dark", "no light of its own (a silhouette)", {"light": "dark"}),
    ("lit as the scene", "soil reflectance × the scene's mean light / 0.18", {"light": "scene"}),
    ("forward scatter", "each particle glows with half the scene's mean light", {"light": "scatter"}),
    ("glowing 4×", "each particle glows with 4 × the scene's mean light (a print lit by the lamp)", {"light": "glow"}),
    ("paper's α-blend", "α ⊙ (P̂_near ∗ I_obs) for the own light (Suppl. Note 4)", {"formation": "paper"}),
    ("zero order 1 %", "the unconverted light, analyzer leak 0.01 (the default camera)", {"leak": 0.01}),
    ("zero order 5 %", "analyzer leak 0.05", {"leak": 0.05}),
    ("luminance match", "the paper's gain and bias from luminance mean and σ (Suppl. Note 11)", {"match": "luminance"}),
    (
        "registered",
        "each capture registered onto the reference as the paper's were (homography + thin-plate spline)",
        {"register": True},
    ),
    (
        "paper's setting",
        "a printed pattern (0.5 mm cells) at 45 mm lit as the scene, the scene at 0.6 m, registered, luminance match",
        {"scale_m": 0.5e-3, "light": "scene", "match": "luminance", "z_far_m": 0.6, "register": True},
    ),
]
# radial frequency bands, cycles per sensor pixel; a pixel spans 1.85 µm × z/f = 21 µm of glass at 45 mm
EDGES = [0.0, 1 / 128, 1 / 32, 1 / 8, 0.75]
BAND_NAMES = ["> 128 px", "32-128 px", "8-32 px", "< 8 px"]  # period on the sensor
SOIL = np.array([0.20, 0.12, 0.05])  # imaging.obstructions.dirt's linear radiance of dry soil
GREY = 0.18


def near_report(psfs) -> dict:
    """Per channel: the near and far PSFs' 5 × 5 core energy, half-light radius (px) and
    encircled-energy curve, and the radial MTF at the band centres (``analysis.psf_metrics``,
    ``analysis.mtf``; pixel units)."""
    from metalens_cli.analysis.mtf import mtf_at, psf_mtf, radial_grid
    from metalens_cli.analysis.psf_metrics import central_energy, encircled_radius

    centres = [np.sqrt(lo * hi) if lo else hi / 2 for lo, hi in zip(EDGES[:-1], EDGES[1:])]
    fractions = np.linspace(0.02, 0.98, 25)
    out = {}
    for depth in ("near", "far"):
        psf = getattr(psfs, depth).double().cpu().numpy()
        psf = psf / psf.sum(axis=(-2, -1), keepdims=True)
        n = psf.shape[-1]
        radii = [[encircled_radius(psf[k], 1.0, (0.0, 0.0), f) for f in fractions] for k in range(3)]
        mtf = psf_mtf(psf, radial_grid(n, 1.0))  # rings at k/n cycles per pixel
        out[depth] = {
            "window_px": n,
            "core": central_energy(psf).tolist(),
            "r50_px": [encircled_radius(psf[k], 1.0, (0.0, 0.0), 0.5) for k in range(3)],
            "encircled": {"fraction": fractions.tolist(), "r": radii},
            "mtf": mtf_at(np.arange(mtf.shape[-1]) / n, mtf, centres).tolist(),
        }
    return out


def obstruction_canvas(obstruction, image, setting: dict) -> tuple[np.ndarray, np.ndarray]:
    """The dirt's (radiance, coverage) canvases under ``setting``'s opacity and light."""
    mask = obstruction.mask * setting["opacity"]
    present = (obstruction.mask > 0).astype(np.float32)
    scene_mean = image.linear.reshape(3, -1).mean(axis=1)[:, None, None]
    luminance = float(np.dot(LUMA_709, scene_mean.ravel()))
    light = setting["light"]
    if light == "soil":
        rgb = obstruction.rgb
    elif light == "dark":
        rgb = np.zeros_like(obstruction.rgb)
    elif light == "scene":
        rgb = obstruction.rgb * (luminance / GREY)
    elif light == "scatter":
        rgb = 0.5 * scene_mean * present
    elif light == "glow":
        rgb = 4.0 * scene_mean * present
    else:
        raise ValueError(light)
    return rgb.astype(np.float32), mask.astype(np.float32)


def registered(capture: np.ndarray, reference: np.ndarray, record: dict, condition: str) -> np.ndarray:
    """``capture`` (3, H, W) registered onto ``reference`` as `metalens align` does (homography,
    thin-plate spline); where the warp leaves the frame, or the registration fails (counted per
    ``condition`` in ``record["registration_failures"]``), the capture as it is."""
    from metalens_cli.errors import ResultFailed
    from metalens_cli.imaging.registration import register

    target = np.transpose(capture, (1, 2, 0))
    try:
        warp = register(np.transpose(reference, (1, 2, 0)), target, refine="tps")
    except ResultFailed:
        failures = record.setdefault("registration_failures", {})
        failures[condition] = failures.get(condition, 0) + 1
        return capture
    warped = np.where(warp.valid_mask()[..., None], warp.apply(target), target)
    return np.ascontiguousarray(np.transpose(warped, (2, 0, 1)))


def lstsq_error(capture: np.ndarray, reference: np.ndarray) -> float:
    """Linear mean squared error after the least-squares gain and bias."""
    import torch

    from metalens_cli.imaging.metrics import photometric_match

    matched = photometric_match(
        torch.as_tensor(capture, dtype=torch.float64), torch.as_tensor(reference, dtype=torch.float64), "lstsq"
    )[0]
    return float(((matched.numpy() - reference) ** 2).mean())


def run_setting(designs, psf_sets, images, seeds: int, setting: dict, progress: str) -> dict:
    """Per design: Δ (dB) per unit, and the added error's shares per part, channel and band."""
    import torch

    from metalens_cli.imaging.obstruction_error import added_error, added_error_spectrum, capture_parts, error_parts
    from metalens_cli.imaging.obstructions import make_obstruction
    from metalens_cli.imaging.pipeline import score
    from metalens_cli.io.presets import ObstructionConfig

    params = dataclasses.replace(ObstructionConfig(), dirt_scale_m=setting["scale_m"])
    out = {name: {"delta_db": [], "unobstructed_db": [], "shares": [], "bands": []} for name in designs}
    start = time.perf_counter()
    for seed in range(seeds):
        for index, image in enumerate(images):
            design0 = designs[DESIGNS[0]]
            obstruction = make_obstruction(
                "dirt",
                image.sensor.shape[-2:],
                Z_NEAR_M,
                design0.focal_length_m,
                1.85e-6,
                [seed, index],
                params=params,
                margin=image.margin,
            )
            rgb, mask = obstruction_canvas(obstruction, image, setting)
            clean = torch.as_tensor(image.linear)
            reference = torch.as_tensor(image.sensor, dtype=torch.float64)
            for name in designs:
                psfs = psf_sets[name]
                with torch.no_grad():
                    formed = capture_parts(
                        clean,
                        torch.as_tensor(rgb),
                        torch.as_tensor(mask),
                        psfs,
                        image.margin,
                        formation=setting["formation"],
                    )
                u, s, e, z = (x.double() for x in formed)  # float32 formation, float64 differences
                parts, base = error_parts(reference, u, s, e, z, match=setting["match"])
                shares = added_error(parts, base)
                bands = added_error_spectrum(parts, base, EDGES)
                u_scored, o_scored = u.numpy(), (u + s + e + z).numpy()
                record = out[name]
                if setting["register"]:
                    u_scored, o_scored = (
                        registered(x, image.sensor, record, condition)
                        for x, condition in ((u_scored, "unobstructed"), (o_scored, "obstructed"))
                    )
                    record.setdefault("registered_added", []).append(
                        float(sum(lstsq_error(x, image.sensor) * sign for x, sign in ((o_scored, 1), (u_scored, -1))))
                    )
                clear = score(u_scored, image.sensor, match=setting["match"])["psnr_db"]
                obstructed = score(o_scored, image.sensor, match=setting["match"])["psnr_db"]
                record["delta_db"].append(obstructed - clear)
                record["unobstructed_db"].append(clear)
                record.setdefault("base_mse", []).append(float((base**2).mean()))
                record["shares"].append({k: v.tolist() for k, v in shares.items()})
                record["bands"].append({k: v.tolist() for k, v in bands.items()})
            print(f"  {progress}: seed {seed} image {index + 1}/{len(images)}", file=sys.stderr, flush=True)
    out["seconds"] = time.perf_counter() - start
    return out


def registration_check(designs: dict, psf_sets: dict, pixels: int, n_images: int) -> dict:
    """Registration failures per design and condition at ``pixels``² (default dirt, seed 0, no
    zero-order light): whether the study's count holds at the paper's sensor size."""
    import torch

    from metalens_cli.imaging.images import load_images
    from metalens_cli.imaging.obstruction_error import capture_parts
    from metalens_cli.imaging.obstructions import make_obstruction

    margin = max(p.margin for p in psf_sets.values())
    counts = {name: {} for name in designs}
    for index, image in enumerate(load_images("photos", (pixels, pixels), n_images, margin)):
        obstruction = make_obstruction(
            "dirt", (pixels, pixels), Z_NEAR_M, designs[DESIGNS[0]].focal_length_m, 1.85e-6, [0, index], margin=margin
        )
        for name in designs:
            with torch.no_grad():
                u, s, e, z = capture_parts(
                    torch.as_tensor(image.linear),
                    torch.as_tensor(obstruction.rgb),
                    torch.as_tensor(obstruction.mask),
                    psf_sets[name],
                    margin,
                )
            for capture, condition in ((u, "unobstructed"), (u + s + e + z, "obstructed")):
                registered(capture.numpy(), image.sensor, counts[name], condition)
        print(f"  registration at {pixels}²: image {index + 1}/{n_images}", file=sys.stderr, flush=True)
    return {
        "pixels": pixels,
        "images": n_images,
        "failures": {n: c.get("registration_failures", {}) for n, c in counts.items()},
    }


def compute(runs: Path, pixels: int, n_images: int, seeds: int, kept: dict | None = None) -> dict:
    """The study's raw results; with ``kept`` (an earlier run's, same sizes) only the variations it lacks."""
    from metalens_cli.imaging.channel_psfs import channel_psfs
    from metalens_cli.imaging.images import load_images
    from metalens_cli.imaging.pipeline import DEFAULT_WAVELENGTHS, attach_zero_order
    from metalens_cli.io.designs import resolve_design
    from metalens_cli.io.units import parse_length_list

    waves = parse_length_list(DEFAULT_WAVELENGTHS, "wavelengths")
    designs = {name: resolve_design(str(runs / name)) for name in DESIGNS}
    raw_psfs, psf_seconds = {}, {}
    for z_far in sorted({BASE_FAR_M} | {o.get("z_far_m", BASE_FAR_M) for _, _, o in VARIATIONS}):
        for name, design in designs.items():
            start = time.perf_counter()
            raw_psfs[name, z_far] = channel_psfs(design, Z_NEAR_M, z_far, waves, 1.85e-6)
            psf_seconds[f"{name} @ {z_far:g} m"] = time.perf_counter() - start
    # one canvas for every variation (the dirt generator fills the canvas: another margin draws other dirt); the
    # zero-order discs (radius a(1 + d/z): 740 px at 45 mm) set it
    margin = max(
        attach_zero_order(dataclasses.replace(p, zero_order=None), designs[name], 1.85e-6, 0.01).margin
        for (name, _), p in raw_psfs.items()
    )
    images = load_images("photos", (pixels, pixels), n_images, margin)
    results = kept or {
        "pixels": pixels,
        "images": [i.name for i in images],
        "seeds": seeds,
        "psf_seconds": psf_seconds,
        "settings": {},
    }
    if "psfs" not in results:
        results["psfs"] = {name: near_report(raw_psfs[name, BASE_FAR_M]) for name in DESIGNS}
    if "registration_512" not in results:
        results["registration_512"] = registration_check(
            designs, {name: raw_psfs[name, BASE_FAR_M] for name in DESIGNS}, 512, len(images)
        )
    for label, _, overrides in VARIATIONS:
        if label in results["settings"]:
            continue
        setting = {**BASE, **overrides}
        z_far = overrides.get("z_far_m", BASE_FAR_M)
        psf_sets = {}
        for name, design in designs.items():
            psfs = dataclasses.replace(raw_psfs[name, z_far], zero_order=None, transforms={})
            psf_sets[name] = attach_zero_order(psfs, design, 1.85e-6, setting["leak"])
        print(f"{label}:", file=sys.stderr, flush=True)
        results["settings"][label] = run_setting(designs, psf_sets, images, seeds, setting, label)
    return results


def _units(record: dict, key: str, part: str | None = None, channel: int | None = None, band: int | None = None):
    """One value per unit: the added error (linear; all parts unless ``part``; mean over channels
    unless ``channel``)."""
    values = []
    for unit in record[key]:
        parts = [part] if part else list(unit)
        v = np.array([unit[p] for p in parts]).sum(axis=0)  # (3,) or (3, bands)
        v = v[..., band] if band is not None else v
        values.append(float(v[channel] if channel is not None else v.mean()))
    return np.array(values)


def summarise(results: dict) -> dict:
    from metalens_cli.analysis.statistics import mean_ci, paired_difference_ci

    summary = {}
    for label, setting in results["settings"].items():
        rows = {}
        for name in DESIGNS:
            r = setting[name]
            rows[name] = {
                "delta": mean_ci(r["delta_db"]),
                "unobstructed_db": float(np.mean(r["unobstructed_db"])),
                "added": float(_units(r, "shares").mean()),
                **(
                    {
                        "registered_added": float(np.mean(r["registered_added"])),
                        "failures": r.get("registration_failures", {}),
                    }
                    if "registered_added" in r
                    else {}
                ),
                "base_mse": float(np.mean(r["base_mse"])),
                "parts": {p: float(_units(r, "shares", part=p).mean()) for p in r["shares"][0]},
                "channels": [float(_units(r, "shares", channel=c).mean()) for c in range(3)],
                "bands": [float(_units(r, "bands", band=b).mean()) for b in range(len(EDGES) - 1)],
                "part_bands": {
                    p: [float(_units(r, "bands", part=p, band=b).mean()) for b in range(len(EDGES) - 1)]
                    for p in r["bands"][0]
                },
            }
        split = setting[DESIGNS[0]]["delta_db"]
        rows["paired"] = {
            name: paired_difference_ci(split, setting[name]["delta_db"], metric="dirt Δ") for name in DESIGNS[1:]
        }
        order = sorted(DESIGNS, key=lambda n: rows[n]["delta"]["mean"])  # most harmed first
        rows["order"] = order
        rows["paper_order"] = order == ["hyperbolic-532", "quick-broadband", "quick-split-spectrum"]
        rows["seconds"] = setting["seconds"]
        summary[label] = rows
    return summary


def paper_added(name: str) -> float:
    """The paper's raw dirt added error: MSE obstructed − MSE unobstructed from its PSNRs."""
    clear, obstructed = PAPER_PSNR[name, "dirt"][:2]
    return 10 ** (-obstructed / 10) - 10 ** (-clear / 10)


SHORT = {"quick-split-spectrum": "split", "quick-broadband": "broadband", "hyperbolic-532": "hyperbolic"}
PART_NAMES = {"shadow": "shadow", "own_light": "own light", "zero_order": "zero order", "rematch": "re-match"}


def figures(results: dict, summary: dict) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    FIGURES.mkdir(parents=True, exist_ok=True)
    colours = {DESIGNS[0]: "tab:green", DESIGNS[1]: "tab:orange", DESIGNS[2]: "tab:blue"}
    names = []

    fig, axes = plt.subplots(1, 3, figsize=(11, 3.2), sharey=True)
    for k, ax in enumerate(axes):
        for name in DESIGNS:
            enc = results["psfs"][name]["near"]["encircled"]
            ax.plot(np.maximum(enc["r"][k], 0.5), enc["fraction"], color=colours[name], label=SHORT[name])
        ax.axvline(2.5, color="grey", lw=0.8, ls=":")
        ax.set_xscale("log")
        ax.set_title(f"{'RGB'[k]} channel, dirt at 45 mm")
        ax.set_xlabel("radius (sensor pixels)")
    axes[0].set_ylabel("encircled energy of the near PSF")
    axes[0].legend()
    fig.tight_layout()
    names.append("obstructions-near-psfs.png")
    fig.savefig(FIGURES / names[-1], dpi=110)
    plt.close(fig)

    fig, axes = plt.subplots(1, 2, figsize=(11, 3.4), sharey=False)
    panels = (("all parts", None), ("its shadow alone", "shadow"))
    for ax, (title, part) in zip(axes, panels):
        width = 0.27
        for j, name in enumerate(DESIGNS):
            row = summary["default"][name]
            bands = np.array(row["part_bands"][part] if part else row["bands"]) * 1e4
            ax.bar(np.arange(len(bands)) + (j - 1) * width, bands, width, color=colours[name], label=SHORT[name])
        ax.set_xticks(range(len(BAND_NAMES)), BAND_NAMES)
        ax.set_xlabel("period on the sensor")
        ax.set_title(f"default dirt: {title}")
        ax.set_ylabel("added error per band (linear MSE × 10⁴)")
        ax.axhline(0, color="black", lw=0.6)
    axes[0].legend()
    fig.tight_layout()
    names.append("obstructions-bands.png")
    fig.savefig(FIGURES / names[-1], dpi=110)
    plt.close(fig)

    labels = ["paper's captures", *summary]
    fig, ax = plt.subplots(figsize=(8, 0.42 * len(labels) + 1.2))
    for j, name in enumerate(DESIGNS):
        clear, obstructed = PAPER_PSNR[name, "dirt"][:2]
        means = [obstructed - clear] + [summary[lbl][name]["delta"]["mean"] for lbl in labels[1:]]
        lo = means[:1] + [summary[lbl][name]["delta"]["ci"][0] for lbl in labels[1:]]
        hi = means[:1] + [summary[lbl][name]["delta"]["ci"][1] for lbl in labels[1:]]
        y = np.arange(len(labels)) + (j - 1) * 0.27
        ax.barh(y, means, 0.27, color=colours[name], label=SHORT[name])
        ax.errorbar(means, y, xerr=[np.subtract(means, lo), np.subtract(hi, means)], fmt="none", ecolor="black", lw=0.7)
    ax.set_yticks(range(len(labels)), labels)
    ax.invert_yaxis()
    ax.set_xlabel("dirt Δ = obstructed − unobstructed PSNR (dB), 95 % CI")
    ax.legend(loc="upper left")
    fig.tight_layout()
    names.append("obstructions-variations.png")
    fig.savefig(FIGURES / names[-1], dpi=110)
    plt.close(fig)
    return names


def _ci(entry: dict, digits: int = 2) -> str:
    lo, hi = entry["ci"]
    return f"{entry['mean']:+.{digits}f} [{lo:+.{digits}f}, {hi:+.{digits}f}]"


def render(results: dict, summary: dict, figure_names: list[str], command: str) -> str:
    units = len(results["images"]) * results["seeds"]
    default = summary["default"]
    lines = [
        "# Why dirt does not follow the paper",
        "",
        f"Written by `{command}` (examples/dirt_study.py); do not edit by hand. The three quick designs of",
        "docs/results.md, dirt at z_near = 45 mm (the paper's experiment), the scene at 5 m, a",
        f"{results['pixels']}² sensor, {len(results['images'])} photographs × {results['seeds']} dirt draws = {units}",
        "paired units, noise-free, without the zero-order light but in its two variations. Δ is the",
        "obstructed minus unobstructed PSNR as",
        "`metalens evaluate` scores it (sRGB after the least-squares gain and bias); the *added error* A is",
        "the same difference in mean squared error, taken on linear values so that it splits exactly",
        "(`metalens_cli/imaging/obstruction_error.py`; tests/imaging/test_obstruction_error.py checks it",
        "against a brute-force per-pixel sum): A = Σ_i ⟨t_i (D + 2 (U′ − R))⟩ over the parts t_i of the",
        "difference D between the matched captures — the dirt's **shadow** (the far light its cone",
        "fraction α blocks), its **own light**, the change of the **zero-order** light, and the **re-match**",
        "(the changed gain and bias applied to the whole image). Per part, channel and radial",
        "spatial-frequency band (period on the sensor; one pixel spans 21 µm of glass at 45 mm).",
        "",
        "The paper's captured photographs (Suppl. table) give raw dirt Δ −1.08 dB hyperbolic, −0.86",
        "broadband, −0.43 split-spectrum; as added error on its unobstructed error (10^(−PSNR/10), sRGB,",
        "luminance match): " + ", ".join(f"{SHORT[n]} {paper_added(n) * 1e4:.1f}" for n in DESIGNS) + " × 10⁻⁴.",
        "",
        "## The near PSFs: core and halo",
        "",
        f"![near PSFs](figures/{figure_names[0]})",
        "",
        "| design | channel | near 5 × 5 core | near half-light radius (px) | near MTF by period "
        + " / ".join(BAND_NAMES)
        + " | far 5 × 5 core |",
        "|---|---|---|---|---|---|",
    ]
    for name in DESIGNS:
        p = results["psfs"][name]
        for k in range(3):
            mtf = " / ".join(f"{v:.3f}" for v in p["near"]["mtf"][k])
            lines.append(
                f"| {LABELS[name]} | {'RGB'[k]} | {p['near']['core'][k]:.4f} | {p['near']['r50_px'][k]:.0f} | {mtf} | "
                f"{p['far']['core'][k]:.4f} |"
            )
    lines += [
        "",
        "## The default dirt, taken apart",
        "",
        "| design | Δ (dB) | unobstructed PSNR (dB) | A × 10⁴ | "
        + " | ".join(f"{PART_NAMES[p]} × 10⁴" for p in PART_NAMES)
        + " | R / G / B × 10⁴ | base MSE × 10⁴ |",
        "|---|---|---|---|" + "---|" * len(PART_NAMES) + "---|---|",
    ]
    for name in DESIGNS:
        row = default[name]
        lines.append(
            f"| {LABELS[name]} | {_ci(row['delta'])} | {row['unobstructed_db']:.2f} | {row['added'] * 1e4:.2f} | "
            + " | ".join(f"{row['parts'][p] * 1e4:+.2f}" for p in PART_NAMES)
            + " | "
            + " / ".join(f"{v * 1e4:.2f}" for v in row["channels"])
            + f" | {row['base_mse'] * 1e4:.1f} |"
        )
    lines += [
        "",
        "The default dirt's added error by part and band (× 10⁴, mean over units and channels):",
        "",
        "| design | part | " + " | ".join(f"period {b}" for b in BAND_NAMES) + " |",
        "|---|---|" + "---|" * len(BAND_NAMES),
    ]
    for name in DESIGNS:
        for part in PART_NAMES:
            if part == "zero_order":
                continue
            lines.append(
                f"| {LABELS[name]} | {PART_NAMES[part]} | "
                + " | ".join(f"{v * 1e4:+.2f}" for v in default[name]["part_bands"][part])
                + " |"
            )
    lines += [
        "",
        f"![added error by band](figures/{figure_names[1]})",
        "",
        "| design | " + " | ".join(f"period {b}" for b in BAND_NAMES) + " |",
        "|---|" + "---|" * len(BAND_NAMES),
    ]
    for label in ("default", "cells 0.3 mm"):
        for name in DESIGNS:
            bands = summary[label][name]["bands"]
            total = sum(bands)
            lines.append(
                f"| {LABELS[name]}, {label} | " + " | ".join(f"{v * 1e4:+.2f} ({v / total:.0%})" for v in bands) + " |"
            )
    lines += [
        "",
        "## Variations",
        "",
        f"![variations](figures/{figure_names[2]})",
        "",
        "| variation | what | Δ split | Δ broadband | Δ hyperbolic | split − hyperbolic | split − broadband | "
        "A × 10⁴ split / broadband / hyperbolic | paper's order |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for label, what, _ in VARIATIONS:
        row = summary[label]
        lines.append(
            f"| {label} | {what} | "
            + " | ".join(_ci(row[name]["delta"]) for name in DESIGNS)
            + " | "
            + " | ".join(_ci(row["paired"][name]) for name in DESIGNS[1:])
            + " | "
            + " / ".join(
                f"{row[name]['registered_added'] * 1e4:.2f}†"
                if "registered_added" in row[name]
                else f"{row[name]['added'] * 1e4:.2f}"
                for name in DESIGNS
            )
            + f" | {'yes' if row['paper_order'] else 'no'} |"
        )
    registered_rows = [label for label in summary if "registered_added" in summary[label][DESIGNS[0]]]
    lines += [
        "",
        "† after registration, linear, least-squares match. Registrations that failed and were kept unregistered, "
        f"of {units} unobstructed and {units} obstructed captures per design: "
        + "; ".join(
            f"{label}: "
            + ", ".join(
                f"{SHORT[n]} {summary[label][n]['failures'].get('unobstructed', 0)} unobstructed and "
                f"{summary[label][n]['failures'].get('obstructed', 0)} obstructed"
                for n in DESIGNS
            )
            for label in registered_rows
        )
        + ".",
    ]
    lines += ["", "## What this says", "", *findings(results, summary), ""]
    seconds = sum(row["seconds"] for row in summary.values()) + sum(results["psf_seconds"].values())
    lines += [
        f"The study took {seconds / 60:.0f} min on this machine (PSFs {sum(results['psf_seconds'].values()):.0f} s).",
        "",
    ]
    return "\n".join(lines)


def findings(results: dict, summary: dict) -> list[str]:
    """What the tables say, in numbers taken from them."""
    default, psfs = summary["default"], results["psfs"]
    split, broadband, hyperbolic = DESIGNS

    def near(name, key, k):
        return psfs[name]["near"][key][k]

    def part_band(label, name, part, bands):
        return sum(summary[label][name]["part_bands"][part][b] for b in bands) * 1e4

    followed = [label for label, row in summary.items() if row["paper_order"]]
    ratio = {n: default[n]["added"] / default[n]["base_mse"] for n in DESIGNS}
    zero = summary["zero order 1 %"]
    glow = summary["glowing 4×"]
    luminance = summary["luminance match"]
    paper = {n: paper_added(n) for n in DESIGNS}
    failed = {label: {n: row[n].get("failures", {}) for n in DESIGNS} for label, row in summary.items()}
    units = len(results["images"]) * results["seeds"]

    def added(row, name):
        return row[name].get("registered_added", row[name]["added"])

    widest = max(added(row, hyperbolic) / added(row, split) for row in summary.values())
    return [
        "- **The near PSFs differ as the paper says.** The hyperbolic lens focuses dirt at 45 mm near "
        "532·(1 + f/z) ≈ 580 nm: its near 5 × 5 core holds "
        f"{near(hyperbolic, 'core', 0):.3f} (R) and {near(hyperbolic, 'core', 1):.3f} (G) of the light, against "
        f"{near(split, 'core', 0):.4f} and {near(split, 'core', 1):.4f} through the split lens's filter, and it passes "
        f"dirt structure of 32-128 px periods with an MTF of {near(hyperbolic, 'mtf', 0)[1]:.2f} (R) against "
        f"{near(split, 'mtf', 0)[1]:.2f}. Ray dwell caps that core (docs/training.md): no geometric-phase lens images "
        "more than a few % of the near light sharply.",
        "- **But the dirt's error is its shadow on the far image, and that grows with the far image's sharpness.** "
        "α (the blurred coverage) varies slowly, and the shadow −α ⊙ (P̂_far ∗ I_clean) takes away the far image's "
        "own detail where the dirt sits. At periods under 32 px, where no near PSF passes the dirt's structure "
        f"(split MTF ≤ {max(near(split, 'mtf', k)[2] for k in range(3)):.3f}), the shadow adds "
        + ", ".join(f"{part_band('default', n, 'shadow', (2, 3)):.1f}" for n in DESIGNS)
        + " × 10⁻⁴ (split, broadband, hyperbolic): the sharper the far image, the more detail the dirt can dim. At "
        "32-128 px, the dirt's own scale, the shadow adds about the same to each ("
        + ", ".join(f"{part_band('default', n, 'shadow', (1,)):.1f}" for n in DESIGNS)
        + "). The own light of the dim soil is small beside it.",
        "- **And Δ is relative.** The added error A is "
        + " / ".join(f"{default[n]['added'] * 1e4:.1f}" for n in DESIGNS)
        + " × 10⁻⁴ (split / broadband / hyperbolic): nearly the same, the split lens's the largest. On unobstructed "
        "errors of "
        + " / ".join(f"{default[n]['base_mse'] * 1e4:.0f}" for n in DESIGNS)
        + " × 10⁻⁴ that is "
        + " / ".join(f"{ratio[n]:.2f}" for n in DESIGNS)
        + " of each, so the sharpest lens shows the largest drop in dB.",
        "- **No variation gives the paper's order"
        + (f" but {', '.join(followed)}" if followed else "")
        + ".** Finer or coarser dirt, half opacity, no own light, light like the scene's or 4 × brighter, the "
        "paper's α-blend, the zero-order light, the luminance match and the paper's setting all leave the split "
        "lens losing as much as or more than the hyperbolic lens. The zero-order light changes A by "
        + ", ".join(f"{(zero[n]['added'] / default[n]['added'] - 1):+.0%}" for n in DESIGNS)
        + "; the luminance match inflates every Δ ("
        + " / ".join(f"{luminance[n]['delta']['mean']:+.2f}" for n in DESIGNS)
        + " dB) without ordering them. Glowing dirt is where the hyperbolic lens's near core shows: its own light "
        "at 32-128 px adds "
        + ", ".join(f"{part_band('glowing 4×', n, 'own_light', (1,)):.1f}" for n in DESIGNS)
        + " × 10⁻⁴, but the glow's mean lowers every design's gain and the re-match then dims the far detail, "
        "again most for the sharpest lens (Δ " + " / ".join(f"{glow[n]['delta']['mean']:+.2f}" for n in DESIGNS) + ").",
        "- **The paper's captures need an effect this model does not have.** Its raw dirt added error, from its "
        "PSNRs, is "
        + " / ".join(f"{paper[n] * 1e4:.0f}" for n in DESIGNS)
        + " × 10⁻⁴ (split / broadband / hyperbolic): "
        f"{paper[hyperbolic] / paper[split]:.1f} × more for the hyperbolic lens than for the split lens, where no "
        f"variation here gives more than {widest:.2f} ×. The lens's near focus cannot supply it (the core above is "
        "bounded by ray dwell), and the model already holds the obstruction's own light and scattered light (a "
        "particle's scattered light leaves it as its own light does: I_obs, imaged by the near PSF), its "
        "zero-order light and its shadow. What it does not hold is the capture chain, and the registration rows "
        "point at it: registered as the paper's captures were (homography from SIFT features, then a thin-plate "
        "spline; `metalens align`), the obstructed captures fail the registration's checks far more often than "
        "the unobstructed ones for the blurred designs ("
        + ", ".join(
            f"{SHORT[n]} {failed['registered'][n].get('obstructed', 0)} against "
            f"{failed['registered'][n].get('unobstructed', 0)}"
            for n in DESIGNS
        )
        + f" of {units}; at 512², {results['registration_512']['images']} photographs: "
        + ", ".join(
            f"{SHORT[n]} {results['registration_512']['failures'][n].get('obstructed', 0)} against "
            f"{results['registration_512']['failures'][n].get('unobstructed', 0)}"
            for n in DESIGNS
        )
        + "): on a blurred, low-contrast capture the dirt's blobs are the strongest features. A failed "
        "registration here keeps the simulated capture, which is aligned already, so Δ does not show the cost; in "
        "the paper's captures every pair was aligned and scored, and a warp pulled by dirt adds error where the "
        "capture is blurred, which is the hyperbolic lens's (10.8 dB unobstructed). The other candidate is light "
        "the model leaves out: the hyperbolic and broadband captures were taken without the tri-band filter, so "
        "with every wavelength the relay, the analyzer and the sensor pass. This study cannot tell them apart "
        "without the "
        "paper's captures.",
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, default=ROOT / "runs")
    parser.add_argument("--pixels", type=int, default=256)
    parser.add_argument("--images", type=int, default=6)
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--reuse", action="store_true", help="keep finished runs and RUNS/dirt_study.json")
    args = parser.parse_args()
    train(args.runs, args.reuse)
    kept = args.runs / "dirt_study.json"
    results = json.loads(kept.read_text()) if args.reuse and kept.is_file() else None
    if results and (results["pixels"], len(results["images"]), results["seeds"]) != (
        args.pixels,
        args.images,
        args.seeds,
    ):
        results = None
    if (
        results is None
        or set(results["settings"]) != {lbl for lbl, _, _ in VARIATIONS}
        or not {"psfs", "registration_512"} <= set(results)
    ):
        results = compute(args.runs, args.pixels, args.images, args.seeds, results)
        kept.write_text(json.dumps(results))
    summary = summarise(results)
    names = figures(results, summary)
    command = f"python examples/dirt_study.py --pixels {args.pixels} --images {args.images} --seeds {args.seeds}"
    OUT.write_text(render(results, summary, names, command), encoding="utf-8")
    print(f"wrote {OUT.relative_to(ROOT)}", file=sys.stderr)


if __name__ == "__main__":
    main()
