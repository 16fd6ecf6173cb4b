"""metalens: design and analysis of learned split-spectrum metalenses.

The public Python API (``import metalens_cli as ml``); docs/api.md shows it at work. Every
length is in SI metres, wavelengths and depths too (``ml.parse_length("450nm")`` reads the
units users type). Names are imported on first use, so that ``import metalens_cli`` stays
light (the CLI's start-up time matters in pipelines) and torch is loaded only by the names
that need it. The stable names are those in ``__all__``; deeper modules may change.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from metalens_cli.constants import __version__

# public name → the module that defines it (relative to this package)
_EXPORTS = {
    # errors, units, constants
    "InputError": "errors",
    "ResultFailed": "errors",
    "parse_length": "io.units",
    "parse_range": "io.units",
    "parse_angle": "io.units",
    "format_length": "io.units",
    "constants": None,
    # lenses, designs, presets
    "Metalens": "optics.lens",
    "hyperbolic": "optics.lens",
    "Design": "io.designs",
    "resolve_design": "io.designs",
    "Preset": "io.presets",
    "load_preset": "io.presets",
    # PSFs and propagators
    "PsfResult": "optics.psf",
    "PsfGrid": "optics.sampling",
    "compute_psf": "optics.psf",
    "estimate_psf": "optics.psf",
    "asm_propagate": "optics.propagate",
    "radial_propagate": "optics.propagate",
    "rayleigh_sommerfeld": "optics.propagate",
    "channel_psf_stack": "optics.channel_psf",
    "crop_window": "optics.window",
    "PsfCube": "io.exr",
    "read_psf_cube": "io.psf_cube_files",
    "write_psf_cube": "io.psf_cube_files",
    "run_scan": "imaging.psf_scan",
    # the field of view: off-axis PSFs and captures that vary over the field
    "FieldPsf": "optics.field",
    "field_psf": "optics.field",
    "field_angle": "optics.field",
    "chief_ray": "optics.field",
    "ray_landings": "optics.field",
    "rms_spot": "optics.field",
    "field_channel_psfs": "imaging.field_psfs",
    "FieldPsfSet": "imaging.field_formation",
    "field_transform": "imaging.field_formation",
    "form_image_field": "imaging.field_formation",
    # spectra and the filter
    "SpectralSensitivity": "optics.spectra",
    "spectral_sensitivity": "optics.spectra",
    "camera_response": "optics.spectra",
    "bandpass_transmission": "optics.spectra",
    "quadrature_weights": "optics.spectra",
    "Band": "optics.split_spectrum",
    "BandsReport": "analysis.bands",
    "bands_from_centers": "analysis.bands",
    "check_bands": "analysis.bands",
    "depth_for_wavelength": "analysis.symmetry",
    "wavelength_for_depth": "analysis.symmetry",
    # the meta-atom
    "Fin": "optics.fin",
    "FinResponse": "optics.fin",
    "fin_response": "optics.nanofin",
    # image formation and metrics
    "Capture": "imaging.formation",
    "form_image": "imaging.formation",
    "add_noise": "imaging.formation",
    "simulate_captures": "imaging.pipeline",
    "psnr": "imaging.metrics",
    "ssim": "imaging.metrics",
    "EvaluationSettings": "imaging.evaluation",
    "evaluate": "imaging.evaluation",
    # MTF
    "RadialGrid": "analysis.mtf",
    "radial_grid": "analysis.mtf",
    "psf_mtf": "analysis.mtf",
    "diffraction_limited_mtf": "analysis.mtf",
    "mtf50": "analysis.mtf",
    "cube_mtf": "analysis.mtf",
    "line_mtf": "analysis.mtf",
    "field_mtf": "analysis.mtf",
    "slanted_edge_sfr": "analysis.slanted_edge",
    # layout export
    "FinGeometry": "io.layout",
    "export_layout": "io.layout",
    # learning
    "train": "design.training",
    "train_reconstruction": "design.reconstruct_training",
}

__all__ = [
    "__version__",
    "Band",
    "BandsReport",
    "Capture",
    "Design",
    "EvaluationSettings",
    "FieldPsf",
    "FieldPsfSet",
    "Fin",
    "FinGeometry",
    "FinResponse",
    "InputError",
    "Metalens",
    "Preset",
    "PsfCube",
    "PsfGrid",
    "PsfResult",
    "RadialGrid",
    "ResultFailed",
    "SpectralSensitivity",
    "add_noise",
    "asm_propagate",
    "bandpass_transmission",
    "bands_from_centers",
    "camera_response",
    "channel_psf_stack",
    "check_bands",
    "chief_ray",
    "compute_psf",
    "constants",
    "crop_window",
    "cube_mtf",
    "depth_for_wavelength",
    "diffraction_limited_mtf",
    "estimate_psf",
    "evaluate",
    "export_layout",
    "field_angle",
    "field_channel_psfs",
    "field_mtf",
    "field_psf",
    "field_transform",
    "fin_response",
    "form_image",
    "form_image_field",
    "format_length",
    "hyperbolic",
    "line_mtf",
    "load_preset",
    "mtf50",
    "parse_angle",
    "parse_length",
    "parse_range",
    "psf_mtf",
    "psnr",
    "quadrature_weights",
    "radial_grid",
    "radial_propagate",
    "ray_landings",
    "rayleigh_sommerfeld",
    "read_psf_cube",
    "resolve_design",
    "rms_spot",
    "run_scan",
    "simulate_captures",
    "slanted_edge_sfr",
    "spectral_sensitivity",
    "ssim",
    "train",
    "train_reconstruction",
    "wavelength_for_depth",
    "write_psf_cube",
]


def __getattr__(name: str) -> Any:
    """Import a public name from its module on first use (PEP 562)."""
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    module = _EXPORTS[name]
    value = (
        importlib.import_module(f"{__name__}.{name}")
        if module is None
        else getattr(importlib.import_module(f"{__name__}.{module}"), name)
    )
    globals()[name] = value  # later lookups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


if TYPE_CHECKING:  # static checkers and IDEs see the names eagerly
    from metalens_cli import constants
    from metalens_cli.analysis.bands import BandsReport, bands_from_centers, check_bands
    from metalens_cli.analysis.mtf import (
        RadialGrid,
        cube_mtf,
        diffraction_limited_mtf,
        field_mtf,
        line_mtf,
        mtf50,
        psf_mtf,
        radial_grid,
    )
    from metalens_cli.analysis.slanted_edge import slanted_edge_sfr
    from metalens_cli.analysis.symmetry import depth_for_wavelength, wavelength_for_depth
    from metalens_cli.design.reconstruct_training import train_reconstruction
    from metalens_cli.design.training import train
    from metalens_cli.errors import InputError, ResultFailed
    from metalens_cli.imaging.evaluation import EvaluationSettings, evaluate
    from metalens_cli.imaging.field_formation import FieldPsfSet, field_transform, form_image_field
    from metalens_cli.imaging.field_psfs import field_channel_psfs
    from metalens_cli.imaging.formation import Capture, add_noise, form_image
    from metalens_cli.imaging.metrics import psnr, ssim
    from metalens_cli.imaging.pipeline import simulate_captures
    from metalens_cli.imaging.psf_scan import run_scan
    from metalens_cli.io.designs import Design, resolve_design
    from metalens_cli.io.exr import PsfCube
    from metalens_cli.io.layout import FinGeometry, export_layout
    from metalens_cli.io.presets import Preset, load_preset
    from metalens_cli.io.psf_cube_files import read_psf_cube, write_psf_cube
    from metalens_cli.io.units import format_length, parse_angle, parse_length, parse_range
    from metalens_cli.optics.channel_psf import channel_psf_stack
    from metalens_cli.optics.field import FieldPsf, chief_ray, field_angle, field_psf, ray_landings, rms_spot
    from metalens_cli.optics.fin import Fin, FinResponse
    from metalens_cli.optics.lens import Metalens, hyperbolic
    from metalens_cli.optics.nanofin import fin_response
    from metalens_cli.optics.propagate import asm_propagate, radial_propagate, rayleigh_sommerfeld
    from metalens_cli.optics.psf import PsfResult, compute_psf, estimate_psf
    from metalens_cli.optics.sampling import PsfGrid
    from metalens_cli.optics.spectra import (
        SpectralSensitivity,
        bandpass_transmission,
        camera_response,
        quadrature_weights,
        spectral_sensitivity,
    )
    from metalens_cli.optics.split_spectrum import Band
    from metalens_cli.optics.window import crop_window
