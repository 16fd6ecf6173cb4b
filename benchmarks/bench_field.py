"""Benchmark: the field of view on the paper's lens (hyperbolic 532 nm, f 4 mm, D 2.516 mm, pitch
395 nm; sensor 512² of 1.85 µm, corner at 9.5°).

1. One off-axis PSF (``optics.field.field_psf``, 255-pixel window, 530 nm, ∞) at the sensor's edge
   and corner: with ``field_psf``'s default angle margin (doubled, for small lenses) and with the
   single one the field PSF sets use (``imaging.field_psfs.SET_OVERSAMPLE``), their relative L2
   apart; the on-axis radial PSF for scale.
2. The field PSF set a 512² capture needs (``imaging.field_psfs.field_channel_psfs``: 5 heights,
   8 wavelengths per channel, near 45 mm and far 5 m), computed without the cache: its time
   against the ≤ 2 min target, and read back from the cache.
3. One 512² RGB obstructed capture with that set (``imaging.field_formation``): the transforms
   once, then the median of ``--repeats`` captures; the on-axis capture (``imaging.formation``)
   with the same lens's on-axis PSFs for scale.

Run alone (it times): python benchmarks/bench_field.py [--threads 2] [--repeats 5]
Rewrites its section (``field``) of docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import tempfile
import time

import torch
from report import write_section

PIXELS, PITCH = 512, 1.85e-6
Z_NEAR, Z_FAR = 0.045, 5.0
SPEC = "hyperbolic:532nm"


def _design():
    from metalens_cli.io.designs import resolve_design

    return resolve_design(SPEC, None, f_m=4e-3, aperture_m=2.516e-3, pitch_m=395e-9)


def one_psf(design) -> list[str]:
    from metalens_cli.imaging.field_psfs import SET_OVERSAMPLE, corner_pixels
    from metalens_cli.optics.field import field_psf
    from metalens_cli.optics.psf import compute_psf

    lens, rows = design.lens, []
    t = time.perf_counter()
    compute_psf(lens, [530e-9], [math.inf], 255, PITCH)
    rows.append(f"| on axis (radial path) | 0° | — | {time.perf_counter() - t:.2f} | — | — |")
    for label, height in (("sensor edge", PIXELS // 2), ("sensor corner", corner_pixels(PIXELS))):
        angle = math.atan2(height * PITCH, 4e-3)
        results = {}
        for oversample in (1.0, SET_OVERSAMPLE):
            t = time.perf_counter()
            r = field_psf(lens, [530e-9], [math.inf], 255, PITCH, angle, oversample=oversample)
            results[oversample] = (r, time.perf_counter() - t)
        ref, fast = results[1.0][0].psf, results[SET_OVERSAMPLE][0].psf
        error = float((fast - ref).norm() / ref.norm())
        for oversample, (r, seconds) in results.items():
            margin = "doubled (default)" if oversample == 1.0 else "single (field sets)"
            rows.append(
                f"| {label}, {margin} | {math.degrees(angle):.2f}° | {r.grid['fft_size']}² | {seconds:.2f} "
                f"| {r.timing_s['kernels']:.2f} / {r.timing_s['propagate']:.2f} "
                f"| {'—' if oversample == 1.0 else f'{error:.1e}'} |"
            )
            print(rows[-1], flush=True)
    return rows


def field_set(design):
    from metalens_cli.imaging.field_psfs import field_channel_psfs
    from metalens_cli.optics.spectra import wavelength_grid

    lams = wavelength_grid(400e-9, 700e-9, 5e-9)
    t = time.perf_counter()
    first = field_channel_psfs(design, Z_NEAR, Z_FAR, lams, PITCH, PIXELS)
    cold = time.perf_counter() - t
    t = time.perf_counter()
    again = field_channel_psfs(design, Z_NEAR, Z_FAR, lams, PITCH, PIXELS)
    warm = time.perf_counter() - t
    assert again.cached
    return first, cold, warm, lams


def formation(design, psf_set, lams, repeats: int) -> dict:
    from metalens_cli.imaging.field_formation import field_transform, form_image_field
    from metalens_cli.imaging.formation import canvas_margin, form_image, psf_transform
    from metalens_cli.imaging.pipeline import channel_psfs

    gen = torch.Generator().manual_seed(0)
    axis = channel_psfs(design, Z_NEAR, Z_FAR, lams, PITCH)
    out = {}
    for name in ("on-axis", "field"):
        t = time.perf_counter()
        if name == "field":
            transforms = tuple(field_transform(s, (PIXELS, PIXELS)) for s in (psf_set.near, psf_set.far))
            margin, form = psf_set.margin, form_image_field
        else:
            transforms = (
                psf_transform(axis.near.float(), (PIXELS, PIXELS)),
                psf_transform(axis.far.float(), (PIXELS, PIXELS)),
            )
            margin, form = canvas_margin(axis.near.shape[-1], axis.far.shape[-1]), form_image
        prepare = time.perf_counter() - t
        canvas = PIXELS + 2 * margin
        clean, obs = torch.rand(3, canvas, canvas, generator=gen), torch.rand(3, canvas, canvas, generator=gen)
        mask = (torch.rand(1, canvas, canvas, generator=gen) > 0.7).float()
        with torch.no_grad():
            form(clean, obs, mask, *transforms, margin)
            times = []
            for _ in range(repeats):
                t = time.perf_counter()
                form(clean, obs, mask, *transforms, margin)
                times.append(time.perf_counter() - t)
        out[name] = {"prepare": prepare, "median": statistics.median(times), "min": min(times), "canvas": canvas}
        if name == "field":
            out[name]["error"] = (transforms[0].error, transforms[1].error)
        print(name, out[name], flush=True)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    os.environ["METALENS_CACHE"] = tempfile.mkdtemp(prefix="bench-field-")  # the set is computed, not read back
    design = _design()
    psf_rows = one_psf(design)
    psf_set, cold, warm, lams = field_set(design)
    print(f"set {cold:.0f} s, cached {warm:.1f} s", flush=True)
    forms = formation(design, psf_set, lams, args.repeats)
    heights = ", ".join(map(str, psf_set.near.heights_px))
    windows = f"{psf_set.near.psfs.shape[-1]} / {psf_set.far.psfs.shape[-1]}"
    off_axis = (len(psf_set.near.heights_px) - 1) * len(psf_set.wavelengths_m)
    field, axis = forms["field"], forms["on-axis"]
    lines = [
        "## Over the field of view, cpu (`python benchmarks/bench_field.py`)",
        "",
        f"The paper's lens (hyperbolic 532 nm, f 4 mm, D 2.516 mm, pitch 395 nm), sensor {PIXELS}² of 1.85 µm "
        f"(edge 6.75°, corner 9.5°), {args.threads} threads, run alone.",
        "",
        "One PSF, 530 nm, ∞, 255-pixel window (`optics.field.field_psf`): seconds in all and kernels (the shifted "
        "transfer functions) / propagation; the last column is the relative L2 of the single-margin PSF against "
        "the doubled-margin one.",
        "",
        "| field | angle | FFT grid | s | kernels / propagate s | rel. L2 |",
        "|---|---|---|---|---|---|",
        *psf_rows,
        "",
        f"The field PSF set of a {PIXELS}² capture (`imaging.field_psfs`, near {Z_NEAR * 1e3:g} mm, far {Z_FAR:g} m): "
        f"heights {heights} px, {len(psf_set.wavelengths_m)} wavelengths (8 strata per channel), windows near / far "
        f"{windows} px, i.e. {off_axis} off-axis (wavelength, height) pairs, each one transfer function and two "
        f"propagations: **{cold:.0f} s** computed (target ≤ 120 s: not met; bound: one full-aperture 2-D FFT grid "
        f"per PSF), {warm:.1f} s read back from the cache. Its measured errors: sampling {psf_set.sampling_error:.1e}, "
        f"spectral (8 strata against the 5 nm quadrature, on axis) near {psf_set.spectral_error['near']:.3f} / far "
        f"{psf_set.spectral_error['far']:.3f}.",
        "",
        f"A {PIXELS}² RGB obstructed capture, float32, median of {args.repeats} (random images, the set above):",
        "",
        "| model | transforms once (s) | capture median (s) | min (s) | canvas | expansion error near / far |",
        "|---|---|---|---|---|---|",
        f"| on axis (`form_image`) | {axis['prepare']:.2f} | {axis['median']:.3f} | {axis['min']:.3f} | "
        f"{axis['canvas']}² | — |",
        f"| over the field (`form_image_field`) | {field['prepare']:.1f} | {field['median']:.3f} | "
        f"{field['min']:.3f} | "
        f"{field['canvas']}² | {field['error'][0]:.4f} / {field['error'][1]:.4f} |",
        "",
        "Target for the capture: ≤ 2 s once the PSFs exist.",
    ]
    write_section("field", "\n".join(lines))


if __name__ == "__main__":
    main()
