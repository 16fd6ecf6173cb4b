"""The model a run learns and its sampling plan: θ's parameterisation as the preset starts it
(``design.parameterization``), the wavelengths and depths the plan covers, and the planned field
frequency with headroom for the lens to steepen (``optics.sampling``)."""

from __future__ import annotations

from metalens_cli.design.parameterization import initial_parameterization
from metalens_cli.errors import InputError
from metalens_cli.io.input_files import read_npy
from metalens_cli.io.presets import INITIAL_THETA
from metalens_cli.optics.sampling import check_lens_sampling

DEFAULT_LAMBDA_D_M = 532e-9  # the hyperbolic start's design wavelength when the preset names none
PLAN_HEADROOM = 1.25  # plans (windows, field frequency) hold this much more than the start needs


def design_wavelength(preset) -> float:
    """The hyperbolic start's design wavelength (m): the preset's, else ``DEFAULT_LAMBDA_D_M``."""
    return preset.lens.design_wavelength_m or DEFAULT_LAMBDA_D_M


def build_model(preset):
    """θ's parameterisation at the start of a run of ``preset`` (its lens, pitch, design grid,
    basis and seed; from ``optimize.init_from``'s θ where the preset names one)."""
    o = preset.optimize
    if o.init_from is not None and o.init == "random":
        raise InputError("optimize.init_from", "given with init = random", "one of init_from and init = random")
    if o.init_from is not None and preset.lens.design == "hyperbolic":
        raise InputError("optimize.init_from", "given for a hyperbolic lens.design", "lens.design = learned")
    start = None if o.init_from is None else read_npy(o.init_from, "optimize.init_from", INITIAL_THETA)
    return initial_parameterization(
        preset.lens.parameterization,
        "hyperbolic" if preset.lens.design == "hyperbolic" else o.init,
        design_wavelength(preset),
        preset.lens.focal_length_m,
        preset.lens.aperture_m,
        preset.nanofin.pitch_m,
        design_grid=o.design_grid,
        seed=o.seed,
        basis=o.theta_basis,
        start=start,
    )


def plan_range(preset) -> tuple[list[float], list[float]]:
    """Wavelengths and depths the run's sampling plan covers: the sensor range, the nearest depth."""
    return list(preset.sensor.wavelength_range_m), [preset.scene.z_near_m[0]]


def plan_frequency(preset) -> float:
    """The run's planned field frequency (cycles/m): the initial design's, plus ``PLAN_HEADROOM``,
    so that kernels are rebuilt only if the learned lens steepens beyond it."""
    plan_l, plan_z = plan_range(preset)
    return PLAN_HEADROOM * check_lens_sampling(build_model(preset).lens(), plan_l, plan_z, force=False)
