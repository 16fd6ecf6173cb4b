"""The lab loop on a synthetic bench: measured PSFs and captured photographs, through the CLI.

    python examples/bench_workflow.py [--out runs/bench-example] [--seed 0]

It fabricates what a bench would give, with known answers, in the layout the commands expect:

- ``OUT/bench/``: PSF frames of the hyperbolic 532 nm lens at 457, 530 and 628 nm and at 45 mm
  and infinity, as a 16-bit camera behind a 2× relay would record them (3.7 µm camera pixels,
  so 1.85 µm in the lens' sensor plane): the simulated PSFs at a random whole-pixel position
  (the in-focus PSF is undersampled at 1.85 µm, and a sub-pixel shift of an undersampled PSF
  cannot be made from its samples; sub-pixel centring is tested on well-sampled spots in
  tests/analysis/test_measured_psf.py), exposed to fill 60 % of the 16-bit range, Poisson photons, a background, a dark
  offset with read noise, five hot pixels; a stack of dark frames; one over-exposed frame (``psf_530nm_inf_long.png``);
  the manifest ``psf.csv``.
- ``OUT/pairs/``: photographs of printed dead-leaves charts through two lenses (``metalens simulate --images charts``),
  as a second camera that is not quite where the reference was would record them: warped by
  a homography and a smooth distortion of a few pixels (``gt/``, ``DESIGN/unobstructed/``,
  ``DESIGN/obstructed/``).

Then it runs the commands a user would: ``psf import`` (first with the over-exposed frame,
which is refused, then without it), ``mtf``, ``psf compare`` against the simulation, ``align``
of one photograph, and ``evaluate --pairs``. Each command is printed as it runs.
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PRESET = ROOT / "presets" / "split-spectrum.toml"
WAVELENGTHS_NM = (457, 530, 628)
DEPTHS = ("45mm", "inf")
DESIGNS = ("hyperbolic:532nm", "hyperbolic:457nm")
CAMERA_PITCH, MAGNIFICATION = "3.7um", 2
FRAME = 384  # camera frame side, pixels
WINDOW = 161  # PSF window: holds the 45 mm blur disc (~121 pixels across) of the f = 4 mm lens
FILL = 0.6  # each frame's exposure puts its brightest pixel at this fraction of full scale
HOT = [(40, 51), (200, 330), (300, 77), (191, 203), (350, 350)]


def metalens(*args, expect: int = 0) -> dict | None:
    """Run ``metalens ARGS --json``; return its JSON (None for an expected failure, whose one
    error line is printed)."""
    print("$ metalens " + shlex.join(map(str, args)), file=sys.stderr, flush=True)
    done = subprocess.run(
        [sys.executable, "-m", "metalens_cli", *map(str, args), "--json"], cwd=ROOT, capture_output=True, text=True
    )
    if done.returncode != expect:
        sys.exit(f"exit {done.returncode} (expected {expect}): {done.stderr.strip()}")
    if expect:
        print("  → " + done.stderr.strip(), file=sys.stderr)
        return None
    return json.loads(done.stdout)


def bench_frames(simulated: Path, folder: Path, rng: np.random.Generator) -> None:
    """Camera frames of the simulated PSFs (see the module docstring) and their manifest."""
    sys.path.insert(0, str(ROOT))
    from metalens_cli.io.exr import read_exr_cube

    cube = read_exr_cube(simulated)
    folder.mkdir(parents=True, exist_ok=True)
    rows = ["file,wavelength,depth,exposure"]
    dark_offset = 800.0
    for i, depth in enumerate(DEPTHS):
        for j, wavelength in enumerate(WAVELENGTHS_NM):
            psf = cube.psf[i, j]
            photons = FILL * 65535 / (psf.max() / psf.sum())  # a 10 ms exposure's photo-electrons
            takes = [("", 1.0)] + ([("_long", 4.0)] if (wavelength, depth) == (530, "inf") else [])
            for suffix, factor in takes:
                exposure = 0.010 * factor
                name = f"psf_{wavelength}nm_{depth}{suffix}.png"
                frame = _frame(psf, factor * photons, dark_offset, rng)
                cv2.imwrite(str(folder / name), frame)
                rows.append(f"{name},{wavelength}nm,{depth},{exposure * 1e3:g}ms")
    darks = np.stack([_frame(None, 0.0, dark_offset, rng) for _ in range(5)])
    np.save(folder / "dark.npy", darks)
    (folder / "psf.csv").write_text("\n".join(rows) + "\n")
    (folder / "psf_no_long.csv").write_text("\n".join(r for r in rows if "_long" not in r) + "\n")


def _frame(psf: np.ndarray | None, photons: float, dark_offset: float, rng: np.random.Generator) -> np.ndarray:
    """One 16-bit frame: the PSF at a random place near the centre, Poisson photons on a
    background, the dark offset, read noise, the hot pixels."""
    light = np.zeros((FRAME, FRAME))
    if psf is not None:
        n = psf.shape[-1]
        top = FRAME // 2 - n // 2 + int(rng.integers(-30, 31))
        left = FRAME // 2 - n // 2 + int(rng.integers(-30, 31))
        light[top : top + n, left : left + n] = np.clip(psf, 0, None) / psf.sum()
    signal = rng.poisson(np.clip(light, 0, None) * photons + 40.0) + dark_offset + rng.normal(0, 5, light.shape)
    for y, x in HOT:
        signal[y, x] += 9000
    return np.clip(np.rint(signal), 0, 65535).astype(np.uint16)


def photographs(simulated: dict[str, Path], folder: Path) -> None:
    """The pairs layout from ``metalens simulate`` folders, each capture seen by a camera that is
    slightly off the reference's pose."""
    homography = np.array([[1.015, 0.02, -5.0], [-0.015, 1.01, 3.5], [1.5e-5, -1e-5, 1.0]])
    for design, source in simulated.items():
        name = design.replace(":", "-")
        for clean in sorted(source.glob("*_clean.png")):
            scene = clean.name.removesuffix("_clean.png")
            (folder / "gt").mkdir(parents=True, exist_ok=True)
            shutil.copyfile(clean, folder / "gt" / f"{scene}.png")
            for condition in ("unobstructed", "obstructed"):
                image = cv2.imread(str(source / f"{scene}_{condition}.png"), cv2.IMREAD_UNCHANGED)
                (folder / name / condition).mkdir(parents=True, exist_ok=True)
                cv2.imwrite(str(folder / name / condition / f"{scene}.png"), _camera(image, homography))


def _camera(image: np.ndarray, homography: np.ndarray) -> np.ndarray:
    """``image`` sampled at H·(x, y, 1) plus a smooth distortion of up to 2 pixels."""
    h, w = image.shape[:2]
    y, x = np.mgrid[:h, :w].astype(np.float64)
    s = homography[2, 0] * x + homography[2, 1] * y + homography[2, 2]
    u = (homography[0, 0] * x + homography[0, 1] * y + homography[0, 2]) / s + 2.0 * np.sin(2 * math.pi * y / h)
    v = (homography[1, 0] * x + homography[1, 1] * y + homography[1, 2]) / s + 1.5 * np.cos(2 * math.pi * x / w)
    return cv2.remap(image, u.astype(np.float32), v.astype(np.float32), cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "bench-example")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    out = args.out.resolve()
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    rng = np.random.default_rng(args.seed)

    simulated = out / "simulated.exr"
    metalens(
        "psf-scan",
        "--design",
        DESIGNS[0],
        "--preset",
        PRESET,
        "--wavelengths",
        ",".join(f"{w}nm" for w in WAVELENGTHS_NM),
        "--depths",
        ",".join(DEPTHS),
        "--pixels",
        WINDOW,
        "-o",
        simulated,
        "--quiet",
    )
    bench_frames(simulated, out / "bench", rng)
    measured = out / "measured.exr"
    import_args = [
        "--dark",
        out / "bench" / "dark.npy",
        "--pixel-pitch",
        CAMERA_PITCH,
        "--magnification",
        MAGNIFICATION,
        "--pixels",
        WINDOW,
        "-o",
        measured,
        "--quiet",
    ]
    metalens("psf", "import", out / "bench" / "psf.csv", *import_args, expect=2)  # the over-exposed frame is refused
    imported = metalens(
        "psf", "import", out / "bench" / "psf_no_long.csv", *import_args, "--plot", out / "measured.png"
    )
    curves = metalens("mtf", measured)["curves"]
    comparison = metalens("psf", "compare", measured, simulated, "--plot", out / "compare.png")

    scenes = {}
    for design in DESIGNS:
        scenes[design] = out / "simulate" / design.replace(":", "-")
        metalens(
            "simulate",
            design,
            "--preset",
            PRESET,
            "--obstruction",
            "dirt",
            "--images",
            "charts",
            "--pixels",
            256,
            "--limit",
            3,
            "-o",
            scenes[design],
            "--overwrite",
        )  # the script's own folder: a rerun replaces it
    photographs(scenes, out / "pairs")
    first = sorted((out / "pairs" / "gt").iterdir())[0].name
    aligned = metalens(
        "align",
        out / "pairs" / "gt" / first,
        out / "pairs" / DESIGNS[0].replace(":", "-") / "unobstructed" / first,
        "-o",
        out / "aligned.png",
    )
    table = metalens("evaluate", "--pairs", out / "pairs", "--plot", out / "pairs.png", "--csv", out / "pairs.csv")

    print(
        f"\npsf import: {imported['pixels']}² pixels at {imported['pixel_pitch_m'] * 1e6:.3g} µm, "
        f"{imported['hot_pixels']} hot pixels replaced (5 planted)"
    )
    for c in curves:
        depth = "inf" if c["depth_m"] is None or math.isinf(c["depth_m"]) else f"{c['depth_m'] * 1e3:g} mm"
        print(f"  MTF50 at {c['wavelength_m'] * 1e9:.0f} nm, {depth}: {c['mtf50_lpmm'] or float('nan'):.1f} lp/mm")
    for p in comparison["pairs"]:
        print(
            f"psf compare {p['wavelength_m'] * 1e9:.0f} nm: peak ratio {p['peak_ratio']:.3f}, relative L2 "
            f"{p['relative_l2']:.3f}"
        )
    report = aligned["pairs"][0]["registration"]
    print(f"align {first}: {report.get('inliers')} inliers, residual {report.get('residual_px', float('nan')):.2f} px")
    for row in table["rows"]:
        print(
            f"evaluate --pairs {row['design']} {row['condition']}: PSNR {row['psnr_db']:.2f} dB, SSIM {row['ssim']:.3f}"
        )
    print(f"\nfiles in {out}")


if __name__ == "__main__":
    main()
