"""What ``metalens simulate`` writes: per capture, the clean scene and the unobstructed and
obstructed captures as sRGB PNG and linear EXR, the obstruction and α maps; the run's report
(``simulate.json``: lengths in metres, times in seconds)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from metalens_cli.imaging.channel_psfs import ChannelPsfs
from metalens_cli.imaging.pipeline import CaptureSetup, SimulatedCapture
from metalens_cli.io.image_files import linear_to_srgb, write_exr_rgb, write_png


def write_captures(out: Path, captures: list[SimulatedCapture]) -> list[str]:
    """PNG (sRGB) and linear EXR of clean, unobstructed and obstructed; obstruction and α maps.
    Returns the file names written in ``out``."""
    files = []
    for c in captures:
        grey = np.full_like(c.clean, 0.5)
        mask = c.obstruction.sensor_mask
        composite = c.obstruction.sensor_rgb * mask + grey * (1 - mask)
        for label, image in (("clean", c.clean), ("unobstructed", c.unobstructed), ("obstructed", c.obstructed)):
            write_png(out / f"{c.name}_{label}.png", linear_to_srgb(image))
            write_exr_rgb(out / f"{c.name}_{label}.exr", image)
            files += [f"{c.name}_{label}.png", f"{c.name}_{label}.exr"]
        write_png(out / f"{c.name}_obstruction.png", linear_to_srgb(composite))
        write_png(out / f"{c.name}_alpha.png", np.clip(c.alpha, 0, 1))
        write_exr_rgb(out / f"{c.name}_obstruction_mask.exr", mask)
        write_exr_rgb(out / f"{c.name}_alpha.exr", c.alpha)
        files += [f"{c.name}_{x}" for x in ("obstruction.png", "alpha.png", "obstruction_mask.exr", "alpha.exr")]
    return files


def simulation_report(
    setup: CaptureSetup,
    kind: str,
    seed: int,
    psfs: ChannelPsfs,
    captures: list[SimulatedCapture],
    formation_options: dict,
    *,
    efficiency: dict,
    files: list[str],
    seconds: float,
) -> dict:
    """The report of captures through ``setup``'s (first) design under obstruction ``kind``: the
    depths drawn and their intervals, sensor, wavelengths, ``formation_options`` (the image-formation
    keywords of :func:`~metalens_cli.imaging.pipeline.simulate_captures`: formation, alpha_gain,
    photons, read_noise), device, PSF windows and kept light, the nanofin ``efficiency`` used,
    per image coverages and seconds, timings (``seconds``: the whole run), warnings and ``files``."""
    return {
        "design": setup.designs[0].describe(),
        "obstruction": kind,
        "seed": seed,
        "z_near_m": psfs.z_near_m,
        "z_far_m": psfs.z_far_m,
        "z_near_interval_m": list(setup.z_near_interval_m),
        "z_far_interval_m": list(setup.z_far_interval_m),
        "pixels": setup.pixels,
        "pixel_pitch_m": setup.pixel_pitch_m,
        "canvas_margin_px": psfs.margin,
        "wavelengths_m": setup.wavelengths_m,
        **formation_options,
        "device": str(setup.device),
        **psfs.report(),
        "spectral_coverage": dict(zip("RGB", psfs.coverage)),
        "efficiency": efficiency,
        "images": [
            {
                "name": c.name,
                "obstruction_coverage": c.obstruction.coverage,
                "alpha_coverage": c.alpha_coverage,
                "obstruction_settings": c.obstruction.settings,
                "seconds": c.seconds,
            }
            for c in captures
        ],
        "timing_s": {"psf": psfs.seconds, "captures": sum(c.seconds for c in captures), "total": seconds},
        "warnings": psfs.warnings(),
        "files": files,
    }
