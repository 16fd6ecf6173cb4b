"""The results of a finished run: θ files, the PSF cube, loss files, figures and ``run.json``."""

from __future__ import annotations

import math
import statistics
import time

import numpy as np
import torch

from metalens_cli.analysis.psf_metrics import central_energy
from metalens_cli.constants import __version__
from metalens_cli.design.model import build_model
from metalens_cli.imaging.channel_psfs import KEPT_WARNING
from metalens_cli.imaging.psf_scan import run_scan
from metalens_cli.io.designs import Design
from metalens_cli.io.exr import write_exr_cube
from metalens_cli.io.json_files import jsonable, write_json
from metalens_cli.io.preset_spectra import efficiency_report
from metalens_cli.io.presets import to_dict
from metalens_cli.optics.lens import Metalens
from metalens_cli.optics.sampling import PsfGrid

PSF_STEP_M = 5e-9
FINAL_WINDOW = 50  # steps averaged into the final loss


def psf_depths(preset) -> list[float]:
    """Depths of psf.exr: the centre of the near interval and infinity (the paper's measured PSFs)."""
    return [sum(preset.scene.z_near_m) / 2, math.inf]


def psf_wavelengths(preset) -> list[float]:
    """Wavelengths (m) of psf.exr: the sensor's wavelength range, both ends included, evenly spaced
    about ``PSF_STEP_M`` (5 nm) apart."""
    lo, hi = preset.sensor.wavelength_range_m
    count = int(round((hi - lo) / PSF_STEP_M)) + 1
    return list(np.linspace(lo, hi, count))


def channel_energies(rgb: np.ndarray, window: int) -> dict:
    """Per depth and channel: energy in the window and in its central w × w pixels."""
    return {
        "energy_in_window": rgb.sum(axis=(-2, -1)).tolist(),
        f"energy_center_{window}x{window}": central_energy(rgb, window).tolist(),
    }


def kept_summary(history: list[dict], prefix: str = "kept_") -> dict:
    """Per depth and channel, the least and mean over the steps of ``prefix`` values: ``kept_``,
    the fraction of the light through the aperture the step windows kept; ``held_``, of the
    light on the sensor plane; ``window_``, the window sides (pixels)."""
    keys = sorted({k for row in history for k in row if k.startswith(prefix)})
    return {
        k[len(prefix) :]: {
            "min": min(r[k] for r in history if k in r),
            "mean": statistics.fmean(r[k] for r in history if k in r),
        }
        for k in keys
    }


def write_results(
    run,
    preset,
    summary,
    grid: dict,
    timing: dict,
    notes: list[str],
    world: int,
    device: str,
    threads: int,
    validation: dict,
    windows: dict,
    filter_report: dict | None = None,
) -> dict:
    """Write a finished optimize run's results into ``run`` (theta.npy and theta_radial.csv,
    psf.exr, loss.csv, loss.png, steering.png, filter.png with a learned filter, theta.png, run.json)
    and return the run.json report.

    ``summary`` is the training's (θ, history, steps, resumed step); ``grid``, ``timing`` (seconds
    by stage), ``notes``, ``validation``, ``windows`` and ``filter_report`` go into the report as
    they are."""
    from metalens_cli.plotting.optimize import filter_figure, loss_figure, steering_figure, theta_figure

    start = time.perf_counter()
    theta = summary.theta
    pitch = preset.nanofin.pitch_m
    run.write_theta(theta, pitch)
    lens = Metalens(torch.from_numpy(theta), pitch, preset.lens.aperture_m, preset.lens.focal_length_m)
    design = Design(str(run.path), "run", lens, preset.lens.focal_length_m, preset)
    waves, depths = psf_wavelengths(preset), psf_depths(preset)
    scan = run_scan(design, PsfGrid(waves, depths, preset.sensor.pixels, preset.sensor.pixel_pitch_m))
    window = preset.loss.sharp_window
    psf_report = {
        "depths_m": depths,
        "channels": ["R", "G", "B"],
        **channel_energies(scan.rgb, window),
        "grid": scan.grid,
        "seconds": scan.timing_s.get("total"),
    }
    write_exr_cube(
        run.path / "psf.exr",
        scan.psf,
        waves,
        depths,
        preset.sensor.pixel_pitch_m,
        design.describe(),
        rgb=scan.rgb,
        extra=jsonable(
            {
                "f_m": preset.lens.focal_length_m,
                "aperture_m": preset.lens.aperture_m,
                "grid": scan.grid,
                "timing_s": scan.timing_s,
                "spectra": scan.spectra,
            }
        ),
    )
    run.write_loss_csv(summary.history)
    if summary.history:
        loss_figure(run.path / "loss.png", summary.history)
    if any("terms" in validation.get("steering", {}).get(s, {}) for s in ("initial", "final")):
        steering_figure(run.path / "steering.png", validation["steering"])
    if filter_report is not None and summary.history:
        filter_figure(run.path / "filter.png", summary.history, preset.sensor.wavelength_range_m)
    initial = None
    if theta.ndim == 1:
        initial = build_model(preset).full_theta().detach().numpy()
    theta_figure(run.path / "theta.png", theta, pitch, initial)
    kept = kept_summary(summary.history)
    tail = summary.history[-FINAL_WINDOW:]
    final = (
        {k: statistics.fmean(r[k] for r in tail) for k in ("total", "l1", "ssim", "bright", "sharp")} if tail else {}
    )
    seconds = [r["seconds"] for r in summary.history[summary.resumed_from :]]
    report = {
        "metalens_version": __version__,
        "preset": to_dict(preset),
        "efficiency": efficiency_report(preset),
        "settings": {
            "steps": summary.steps,
            "seed": preset.optimize.seed,
            "device": device,
            "world_size": world,
            "threads": threads,
            "parameterization": preset.lens.parameterization,
            "init": preset.optimize.init,
            "init_from": preset.optimize.init_from,
            "theta_shape": list(theta.shape),
            "resumed_from_step": summary.resumed_from,
        },
        "cost": {
            "seconds_per_step_median": summary.seconds_per_step,
            "seconds_per_step_mean": statistics.fmean(seconds) if seconds else None,
            "seconds_training": sum(seconds),
            "seconds_by_stage": timing,
            "seconds_results": None,
        },
        "accuracy": {
            "psf_grid": grid,
            "psf_exr_grid": scan.grid,
            "note": "PSF sampling plans follow the sampling guard; see docs/benchmarks.md for measured errors",
        },
        "final_loss": final,
        "validation_loss": validation,
        "psf": psf_report,
        **({"filter": filter_report} if filter_report is not None else {}),
        "psf_windows": {
            **windows,
            "kept": kept,
            "held": kept_summary(summary.history, "held_"),
            "window_px": {
                k: {**v, "max": max(r[f"window_{k}"] for r in summary.history if f"window_{k}" in r)}
                for k, v in kept_summary(summary.history, "window_").items()
            },
        },
        "notes": notes
        + [
            f"the {name.replace('_', ' ')} PSF window kept as little as {v['min']:.3f} of the light in a step "
            f"(< {KEPT_WARNING})"
            for name, v in kept.items()
            if v["min"] < KEPT_WARNING
        ],
    }
    report["cost"]["seconds_results"] = time.perf_counter() - start
    write_json(run.path / "run.json", report)
    return report
