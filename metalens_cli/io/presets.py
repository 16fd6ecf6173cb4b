"""Presets: TOML files describing a whole camera (lens, nanofins, filter, sensor, scene, learning).

A preset is read into a tree of frozen dataclasses holding SI values (metres, fractions).
Each dataclass field declares its TOML key and kind in its metadata, so the schema, the
validation and the resolved view (:func:`to_dict`) come from one definition. Every error
names the TOML key path (``lens.focal_length``) and the accepted form.

Lengths are TOML strings with units (``"4mm"``); lists of lengths are arrays of such strings
or one comma-separated string; intervals are ``"40mm:50mm"`` or a two-element array.
"""

from __future__ import annotations

import dataclasses
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from metalens_cli import arguments
from metalens_cli.constants import DEFAULT_READ_ELECTRONS, DEFAULT_ZERO_ORDER_LEAK, LIGHT_NAMES, SENSOR_RANGE_M
from metalens_cli.errors import InputError
from metalens_cli.io import units
from metalens_cli.io.input_files import read_text, regular_file
from metalens_cli.optics.nanofin import DEFAULT_HARMONICS
from metalens_cli.optics.split_spectrum import (
    incidence_factor,
    label_bands,
    largest_margin,
    oblique_bands,
    sensed_bands,
    split_conditions,
    steepest_incidence,
)
from metalens_cli.optics.window import WINDOW_PER_BLOCK

WAVELENGTH_MODES = ("log_wavelength", "harmonic_wavelength")  # loss.sharp_mode on each wavelength's own core
SHARP_MODES = ("total", "per_channel", "log", *WAVELENGTH_MODES)  # design.losses.sharp_loss


def toml_key(toml_key: str, kind: str, *, default: Any = dataclasses.MISSING, **limits: Any) -> Any:
    """A dataclass field read from ``toml_key`` as ``kind``, with optional ``lo``/``hi`` limits."""
    meta = {"key": toml_key, "kind": kind, **limits}
    if default is dataclasses.MISSING:
        return field(metadata=meta)
    if isinstance(default, (list, tuple)):
        return field(default_factory=lambda: tuple(default), metadata=meta)
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class LensConfig:
    """The flat lens: focal (sensor) distance, aperture diameter, and how θ is initialised."""

    focal_length_m: float = toml_key("focal_length", "length")
    aperture_m: float = toml_key("aperture", "length")
    design: str = toml_key("design", "choice", choices=("learned", "hyperbolic"))
    design_wavelength_m: float | None = toml_key("design_wavelength", "length", default=None)
    parameterization: str = toml_key("parameterization", "choice", choices=("radial", "2d"), default="radial")


@dataclass(frozen=True)
class NanofinConfig:
    """Nanofin meta-atoms on a square grid, and their conversion efficiency η(λ): a table
    (``efficiency`` = fractions at ``efficiency_wavelengths``), a CSV (``efficiency_csv``), or
    ``efficiency = "rcwa"``: computed for this fin of ``material`` on ``substrate`` with
    ``harmonics`` Fourier orders per axis, once, then read from the cache
    (:mod:`metalens_cli.io.preset_spectra`). Materials take the forms of ``--material``."""

    pitch_m: float = toml_key("pitch", "length")
    height_m: float = toml_key("height", "length")
    width_m: float = toml_key("width", "length")
    length_m: float = toml_key("length", "length")
    material: str = toml_key("material", "material", default="sinx")
    substrate: str = toml_key("substrate", "material", default="fused-silica")
    efficiency: tuple[float, ...] | str = toml_key("efficiency", "efficiency", default="rcwa")
    efficiency_wavelengths_m: tuple[float, ...] = toml_key("efficiency_wavelengths", "length_list", default=())
    efficiency_csv: str | None = toml_key("efficiency_csv", "path", default=None)  # replaces the table
    harmonics: int = toml_key("harmonics", "odd_int", lo=1, hi=41, default=DEFAULT_HARMONICS)


@dataclass(frozen=True)
class FilterConfig:
    """Multi-band filter: pass band i is [centre − width/2, centre + width/2] (width = FWHM) with
    logistic edges (10-90 % rise ``edge_width``), or a measured transmission ``csv``
    (wavelength_nm, transmission; pass bands where it exceeds ``threshold``).

    Oblique rays up to ``max_incidence`` ("auto": the steepest ray on the sensor) move the bands
    blue by √(1 − sin²θ/n_eff²); the split-spectrum conditions account for it (``analysis.bands``).
    ``learn = true``: ``optimize`` learns the centres, widths and edge width with θ (their own
    ``learning_rate``, nm per step), within ``min_width``-``max_width``, edges ≥ ``min_edge_width``,
    gaps ≥ ``min_gap``, and the split-spectrum conditions with ``split_margin`` (a penalty of
    weight ``split_weight`` on nm² of shortfall); ``light_weight`` w adds −w·mean_c log g_c, g_c
    the channels' throughput, so that the PSF terms see the light a band costs; with a
    ``catalogue`` CSV the result snaps to the nearest listed filter that meets them
    (``design.filter_learning``)."""

    centers_m: tuple[float, ...] = toml_key("centers", "length_list", default=())
    widths_m: tuple[float, ...] = toml_key("widths", "length_list", default=())
    csv: str | None = toml_key("csv", "path", default=None)
    threshold: float = toml_key("threshold", "fraction", default=0.5)
    edge_width_m: float = toml_key("edge_width", "length", default=2e-9)
    peak_transmission: float = toml_key("peak_transmission", "fraction", default=0.9)
    max_incidence: str = toml_key("max_incidence", "incidence", default="0deg")
    n_eff: float = toml_key("n_eff", "float", lo=1.0, hi=5.0, default=1.8)
    learn: bool = toml_key("learn", "bool", default=False)
    learning_rate: float = toml_key("learning_rate", "float", lo=0.0, hi=100.0, default=0.3)
    min_width_m: float = toml_key("min_width", "length", default=10e-9)
    max_width_m: float = toml_key("max_width", "length", default=40e-9)
    min_edge_width_m: float = toml_key("min_edge_width", "length", default=1e-9)
    min_gap_m: float = toml_key("min_gap", "length", default=5e-9)
    split_margin_m: float = toml_key("split_margin", "length", default=1e-9)
    split_weight: float = toml_key("split_weight", "float", lo=0.0, hi=1e6, default=1.0)
    light_weight: float = toml_key("light_weight", "float", lo=0.0, hi=1e3, default=0.0)
    catalogue: str | None = toml_key("catalogue", "path", default=None)


@dataclass(frozen=True)
class ToleranceConfig:
    """What ``metalens tolerance`` analyses for this preset's lens when its options do not say:
    the fabrication error sources and their magnitudes (``optics.fabrication``; a bias may be
    negative), the ``budget`` ("strehl -10%"), Monte Carlo ``draws`` and ``photos``. Optional."""

    rotation_sigma_rad: float | None = toml_key("rotation_sigma", "angle", default=None)
    theta_levels: int | None = toml_key("theta_levels", "int", lo=2, hi=4096, default=None)
    missing: float | None = toml_key("missing", "float", lo=0.0, hi=0.999999, default=None)
    stitch_field_m: float | None = toml_key("stitch_field", "length", default=None)
    stitch_sigma_m: float | None = toml_key("stitch_sigma", "signed_length", default=None)
    width_bias_m: float | None = toml_key("width_bias", "signed_length", default=None)
    width_sigma_m: float | None = toml_key("width_sigma", "signed_length", default=None)
    length_bias_m: float | None = toml_key("length_bias", "signed_length", default=None)
    length_sigma_m: float | None = toml_key("length_sigma", "signed_length", default=None)
    budget: str | None = toml_key("budget", "string", default=None)
    draws: int | None = toml_key("draws", "int", lo=0, hi=10000, default=None)
    photos: int | None = toml_key("photos", "int", lo=0, hi=1000, default=None)


@dataclass(frozen=True)
class SensorConfig:
    """Colour sensor: square pixels, window size, spectral response and range."""

    pixel_pitch_m: float = toml_key("pixel_pitch", "length")
    pixels: int = toml_key("pixels", "int", lo=1, hi=8192)
    # the whole sensor (pixels a side) of which ``pixels`` is the central crop a training step images: L_bright
    # counts the light on it, and ``field_angles = "sensor"`` samples its field; none: the crop is the sensor
    full_pixels: int | None = toml_key("full_pixels", "int", lo=1, hi=65536, default=None)
    camera_response: str = toml_key("camera_response", "string", default="Nikon 5100 (NPL)")  # name or CSV path
    wavelength_range_m: tuple[float, float] = toml_key("wavelength_range", "interval", default=SENSOR_RANGE_M)


@dataclass(frozen=True)
class SceneConfig:
    """Depth ranges of near obstructions and far scenes (uniformly sampled in training)."""

    z_near_m: tuple[float, float] = toml_key("z_near", "interval")
    z_far_m: tuple[float, float] = toml_key("z_far", "interval")


SCENE_GENERATORS = ("auto", "numpy", "torch")
DEVICE_OBSTRUCTIONS = ("dirt", "fence")  # the obstructions design.device_scenes draws


@dataclass(frozen=True)
class OptimizeConfig:
    """End-to-end learning of θ (Suppl. Note 4): AdamW with cosine annealing."""

    steps: int = toml_key("steps", "int", lo=0, hi=10_000_000)
    learning_rate: float = toml_key("learning_rate", "float", lo=0.0, hi=10.0)
    t_max: int = toml_key("t_max", "int", lo=1, hi=10_000_000)
    optimizer: str = toml_key("optimizer", "choice", choices=("adamw",), default="adamw")
    scheduler: str = toml_key("scheduler", "choice", choices=("cosine", "constant"), default="cosine")
    weight_decay: float = toml_key("weight_decay", "float", lo=0.0, default=0.0)  # AdamW decay of the unwrapped θ
    batch_size: int = toml_key("batch_size", "int", lo=1, hi=4096, default=1)
    wavelengths_per_channel: int = toml_key("wavelengths_per_channel", "int", lo=1, hi=1024, default=3)
    seed: int = toml_key("seed", "int", lo=0, hi=2**63 - 1, default=0)
    init: str = toml_key("init", "choice", choices=("hyperbolic", "random"), default="hyperbolic")
    # a learned θ to start from instead: a run directory of ``metalens optimize`` (its theta.npy) or a radial θ .npy
    # (rad at r = k·pitch) with as many rings as this lens; resolved to the .npy's absolute path
    init_from: str | None = toml_key("init_from", "path", default=None)
    design_grid: int = toml_key(
        "design_grid", "int", lo=0, hi=100_000, default=0
    )  # radial samples / 2-D side; 0 = per meta-atom
    theta_basis: str = toml_key(
        "theta_basis", "choice", choices=("samples", "spline"), default="samples"
    )  # see design.parameterization
    spectral_sampling: str = toml_key(
        "spectral_sampling", "choice", choices=("stratified", "midpoint", "bands"), default="stratified"
    )
    obstructions: tuple[str, ...] = toml_key("obstructions", "string_list", default=("dirt",))
    photons: float = toml_key(
        "photons", "float", lo=0.0, hi=1e15, default=0.0
    )  # full-well e⁻ before the filter; 0: no shot noise
    read_noise: float = toml_key("read_noise", "float", lo=0.0, hi=1.0, default=0.0)  # σ, fraction of full scale
    # the verdict's camera (imaging.camera): e⁻ a full-scale white pixel collects before the filter through an ideal
    # lens (a number or dim, indoor, daylight; 0: noise-free), its read noise (e⁻ rms) and the analyzer's leak of the
    # unconverted light; each channel then collects light × t_c (the filter and the nanofins' η both cost light)
    light: float = toml_key("light", "light", default=0.0)
    read_electrons: float = toml_key("read_electrons", "float", lo=0.0, hi=1e6, default=DEFAULT_READ_ELECTRONS)
    zero_order_leak: float = toml_key("zero_order_leak", "float", lo=0.0, hi=1.0, default=DEFAULT_ZERO_ORDER_LEAK)
    images: str | None = toml_key("images", "folder", default=None)  # training images; none: procedural scenes
    checkpoint_every: int = toml_key("checkpoint_every", "int", lo=1, hi=10_000_000, default=100)
    sample_every: int = toml_key("sample_every", "int", lo=1, hi=10_000_000, default=100)
    # field angles (rad) a step draws its PSFs at, equally likely (design.step.draw_field); (0,): on axis, the paper's
    # "sensor" or "sensor:K": the K (4) radii that split a uniform point on the whole sensor (sensor.full_pixels)
    # into equal shares, as field angles at the focal length (io.presets.sensor_field_angles)
    field_angles_rad: tuple[float, ...] = toml_key("field_angles", "angle_list", default=(0.0,), hi=math.radians(60))
    # the step's PSFs as core and halo (optics.two_scale; docs/benchmarks.md, two-scale PSF): the central core_pixels
    # at the sensor's pitch, the rest in halo pixels of halo_scale × halo_scale (odd; 1: one scale, the exact path),
    # core_pixels an odd multiple of halo_scale; a radial lens's halo sampled halo_radial_step × the core's radial step
    halo_scale: int = toml_key("halo_scale", "int", lo=1, hi=31, default=5)
    core_pixels: int = toml_key("core_pixels", "int", lo=1, hi=1023, default=65)
    halo_radial_step: int = toml_key("halo_radial_step", "int", lo=1, hi=4, default=2)
    # a PSF window of N px takes halo blocks of at most N / halo_window_blocks px (optics.two_scale.TwoScale.at): the
    # guard that keeps small windows (a near defocus disc) at one scale; 130 puts 390-649 px windows at s = 3
    # (3-5e-4 of the captures, docs/benchmarks.md, the window rule)
    halo_window_blocks: int = toml_key("halo_window_blocks", "int", lo=1, hi=10_000, default=WINDOW_PER_BLOCK)
    # procedural scenes and dirt drawn at the pixels only within the cores' reach of the field (core_pixels // 2, at
    # least the scenes' detail band) and in halo_scale × halo_scale cells beyond, which only the halos see
    # (imaging.sample_grid; docs/benchmarks.md, scenes at the halo's blocks); false: every pixel, the exact path
    scene_blocks: bool = toml_key("scene_blocks", "bool", default=True)
    # a radial lens's angle margin: the sin-angle its propagator keeps beyond the field's steepest ray (optics.sampling.
    # plan_radial; edge diffraction). 0.2, the doubled margin of every other radial PSF; 0.1 shrinks the Hankel products
    # about 1.5× at ≤ 5e-4 of the PSFs (docs/benchmarks.md, radial margin)
    radial_margin: float = toml_key("radial_margin", "float", lo=0.05, hi=0.5, default=0.1)
    # where a step's procedural scenes and obstructions are drawn (design.step.scenes_on_device): "numpy" on the
    # host (design.scenes; scene_blocks applies), "torch" on the run's device (design.device_scenes: every pixel,
    # dirt and fence only, no training images), "auto": torch on an accelerator where it can, else numpy
    scene_generator: str = toml_key("scene_generator", "choice", choices=SCENE_GENERATORS, default="auto")


LOSS_SPACES = ("linear", "metric")  # design.losses.training_loss


@dataclass(frozen=True)
class LossConfig:
    """Weights of L1, 1 − SSIM, domain adaptation, L_bright and L_sharp."""

    l1: float = toml_key("l1", "float", lo=0.0, hi=1e3, default=1.0)
    ssim: float = toml_key("ssim", "float", lo=0.0, hi=1e3, default=1.0)
    domain_adaptation: float = toml_key("domain_adaptation", "float", lo=0.0, hi=1e3, default=1.0)
    bright: float = toml_key("bright", "float", lo=0.0, hi=1e3, default=1.0)
    sharp: float = toml_key("sharp", "float", lo=0.0, hi=1e3, default=1.0)
    sharp_window: int = toml_key("sharp_window", "int", lo=1, hi=101, default=5)
    sharp_mode: str = toml_key("sharp_mode", "choice", choices=SHARP_MODES, default="total")  # see design.losses
    # what the image terms compare: "linear" values, or "metric": the evaluation's (least-squares match, sRGB)
    space: str = toml_key("space", "choice", choices=LOSS_SPACES, default="linear")
    domain_adaptation_weights: str | None = toml_key(
        "domain_adaptation_weights", "path", default=None
    )  # DeepLabv3+ checkpoint


@dataclass(frozen=True)
class ObstructionConfig:
    """Obstruction generators: sizes on the cover glass (m), coverages as fractions of the sensor.

    Defaults suit the paper's camera (f = 4 mm, 1.85 µm pixels, z_near ≈ 45 mm).
    """

    dirt_scale_m: float = toml_key("dirt_scale", "length", default=1.5e-3)  # largest Perlin cell
    dirt_octaves: int = toml_key("dirt_octaves", "int", lo=1, hi=10, default=5)
    dirt_coverage: tuple[float, float] = toml_key("dirt_coverage", "fraction_pair", default=(0.15, 0.35))
    dirt_edge: float = toml_key("dirt_edge", "float", lo=0.0, hi=1.0, default=0.04)  # soft edge, noise units
    fence_pitch_m: float = toml_key("fence_pitch", "length", default=3e-3)
    fence_width_m: float = toml_key("fence_width", "length", default=0.3e-3)
    fence_angle_deg: float = toml_key("fence_angle_deg", "float", lo=-180.0, hi=180.0, default=45.0)
    drop_radius_m: tuple[float, float] = toml_key("drop_radius", "interval", default=(0.2e-3, 0.8e-3))
    drop_coverage: tuple[float, float] = toml_key("drop_coverage", "fraction_pair", default=(0.05, 0.15))
    drop_opacity: float = toml_key("drop_opacity", "fraction", default=0.85)
    rain_radius_m: tuple[float, float] = toml_key("rain_radius", "interval", default=(0.3e-3, 1.2e-3))
    rain_coverage: tuple[float, float] = toml_key("rain_coverage", "fraction_pair", default=(0.10, 0.25))


@dataclass(frozen=True)
class Preset:
    """A resolved preset: the sections of a preset TOML file, validated (:func:`load_preset`).

    Attributes:
        name: the preset's name (the file's stem).
        lens: ``[lens]``: focal (sensor) distance, aperture diameter (m), how θ is initialised.
        nanofin: ``[nanofin]``: the meta-atoms and their conversion efficiency η(λ).
        sensor: ``[sensor]``: pixel pitch (m), window, spectral response and range.
        scene: ``[scene]``: depth ranges (m) of near obstructions and far scenes.
        optimize: ``[optimize]``: the end-to-end learning of θ.
        loss: ``[loss]``: the loss weights.
        filter: ``[filter]``: the multi-band filter; None for a camera without one.
        obstruction: ``[obstruction]``: the obstruction generators (defaults: the paper's camera).
        description: free text.
        source: the file it was read from, or None.
    """

    name: str
    lens: LensConfig
    nanofin: NanofinConfig
    sensor: SensorConfig
    scene: SceneConfig
    optimize: OptimizeConfig
    loss: LossConfig
    filter: FilterConfig | None = None
    obstruction: ObstructionConfig = field(default_factory=ObstructionConfig)
    tolerance: ToleranceConfig | None = None
    description: str = ""
    source: str | None = None


SECTIONS: dict[str, tuple[type, bool]] = {
    "lens": (LensConfig, True),
    "nanofin": (NanofinConfig, True),
    "filter": (FilterConfig, False),
    "sensor": (SensorConfig, True),
    "scene": (SceneConfig, True),
    "optimize": (OptimizeConfig, True),
    "loss": (LossConfig, False),
    "obstruction": (ObstructionConfig, False),
    "tolerance": (ToleranceConfig, False),
}
OPTIONAL_DEFAULTS = {"loss": LossConfig, "obstruction": ObstructionConfig}
TOP_LEVEL_KEYS = {"name", "description"}
MAX_OBSTRUCTION_M = 0.1  # obstruction features (dirt cells, wires, drops) on a cover glass
NAME_PATTERN = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9._-]{0,99}")


def check_name(name: str) -> None:
    """A preset's ``name`` names ``runs/NAME``: a plain file name, never a path."""
    if not NAME_PATTERN.fullmatch(name):
        raise InputError(
            "name",
            f"{name!r} is not a plain name",
            "letters, digits, '.', '_' or '-', not starting with '.' (it names runs/NAME)",
        )


def as_str(value: Any, path: str, form: str) -> str:
    """``value`` when it is a str, else an :class:`InputError` at ``path`` naming its type and the
    ``form`` expected."""
    if not isinstance(value, str):
        raise InputError(path, f"expected a string, got {type(value).__name__}", form)
    return value


def _convert(value: Any, meta: dict[str, Any], path: str) -> Any:
    """Convert one TOML value according to the field's kind and limits."""
    kind = meta["kind"]
    if kind == "length":
        return units.parse_length(as_str(value, path, units.LENGTH_FORM), path)
    if kind == "length_list":
        if isinstance(value, list):
            return tuple(units.parse_length(as_str(v, path, units.LIST_FORM), path) for v in value)
        return tuple(units.parse_length_list(as_str(value, path, units.LIST_FORM), path))
    if kind == "interval":
        if isinstance(value, list):
            if len(value) != 2:
                raise InputError(path, "expected two values", units.INTERVAL_FORM)
            lo, hi = (units.parse_length(as_str(v, path, units.INTERVAL_FORM), path, allow_inf=True) for v in value)
            if hi < lo:
                raise InputError(path, "upper end below lower end", units.INTERVAL_FORM)
            return lo, hi
        return units.parse_interval(as_str(value, path, units.INTERVAL_FORM), path, allow_inf=True)
    if kind == "angle":
        return units.parse_angle(as_str(value, path, units.ANGLE_FORM), path)
    if kind == "signed_length":
        text = as_str(value, path, "a length, e.g. 10nm or -5nm").strip()
        return units.parse_signed_length(text, path)
    if kind == "angle_list":
        if isinstance(value, list):
            if not value:
                raise InputError(path, "expected at least one angle", units.ANGLE_LIST_FORM)
            angles = [units.parse_angle(as_str(v, path, units.ANGLE_LIST_FORM), path) for v in value]
        else:
            angles = units.parse_angle_list(as_str(value, path, units.ANGLE_LIST_FORM), path)
        top = math.degrees(meta["hi"])
        if max(angles) > meta["hi"] * (1 + 1e-12):
            raise InputError(path, f"{math.degrees(max(angles)):g}° is past {top:g}°", f"angles from 0 to {top:g}°")
        return tuple(angles)
    if kind == "light":
        if isinstance(value, str):
            word = value.strip().lower()
            if word in ("none", "noise-free"):
                return 0.0
            if word in LIGHT_NAMES:
                return LIGHT_NAMES[word]
        names = ", ".join(f"{k} ({v:g})" for k, v in LIGHT_NAMES.items())
        form = f"electrons ≥ 0 (0: noise-free), none, or one of {names}"
        if isinstance(value, str) or isinstance(value, bool):
            raise InputError(path, f"{value!r} is not a light level", form)
        return _number(value, path, lo=0.0, hi=1e15, form=form)
    if kind == "fraction_pair":
        if not isinstance(value, list) or len(value) != 2:
            raise InputError(path, "expected two numbers [lo, hi] in [0, 1]", "[0.15, 0.35]")
        lo, hi = (_number(v, path, lo=0.0, hi=1.0, form="numbers in [0, 1]") for v in value)
        if hi < lo:
            raise InputError(path, "upper end below lower end", "[lo, hi] with lo ≤ hi")
        return lo, hi
    if kind == "fraction_list":
        if not isinstance(value, list) or not value:
            raise InputError(path, "expected a non-empty array of numbers in (0, 1]", "[0.784, 0.729]")
        return tuple(_number(v, path, lo=0.0, hi=1.0, form="numbers in (0, 1]", open_lo=True) for v in value)
    if kind == "efficiency":
        if value == "rcwa":
            return value
        if not isinstance(value, list):
            raise InputError(
                path, f'expected "rcwa" or an array of fractions, got {value!r}', '"rcwa" or [0.784, 0.729, 0.669]'
            )
        return _convert(value, {"kind": "fraction_list"}, path)
    if kind == "odd_int":
        number = _convert(value, {**meta, "kind": "int"}, path)
        if number % 2 == 0:
            raise InputError(path, f"{number} is even", "an odd number of Fourier harmonics per axis, e.g. 21")
        return number
    if kind == "material":
        from metalens_cli.io.materials import MATERIAL_FORM

        return _material(as_str(value, path, MATERIAL_FORM), path)
    if kind == "fraction":
        return _number(value, path, lo=0.0, hi=1.0, form="a number in (0, 1]", open_lo=True)
    if kind == "float":
        return _number(value, path, lo=meta.get("lo"), hi=meta.get("hi"), form="a number")
    if kind == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            raise InputError(path, f"expected an integer, got {value!r}", "an integer")
        return int(_number(value, path, lo=meta.get("lo"), hi=meta.get("hi"), form="an integer"))
    if kind in ("string", "path", "folder"):
        forms = {
            "string": "a string",
            "path": "a file path (relative to the preset)",
            "folder": "a folder (relative to the preset)",
        }
        return as_str(value, path, forms[kind])
    if kind == "string_list":
        if not isinstance(value, list) or not value:
            raise InputError(path, "expected a non-empty array of strings", '["dirt", "fence"]')
        return tuple(as_str(v, path, "a string") for v in value)
    if kind == "bool":
        if not isinstance(value, bool):
            raise InputError(path, f"expected true or false, got {value!r}", "true or false")
        return value
    if kind == "incidence":
        text = as_str(value, path, f'"auto" or {units.ANGLE_FORM}')
        if text.strip() != "auto":
            units.parse_angle(text, path)
        return text.strip()
    if kind == "choice":
        choices = meta["choices"]
        if value not in choices:
            raise InputError(path, f"{value!r} is not allowed", "one of " + ", ".join(choices))
        return value
    raise AssertionError(f"unknown kind {kind}")


def _material(text: str, path: str) -> str:
    """A material's text, checked now unless it names a file (checked once resolved against the
    preset's folder, in :func:`_resolve_paths`)."""
    from metalens_cli.io.materials import material_file, parse_material

    if material_file(text) is None:
        parse_material(text, path)
    return text.strip()


def _number(value: Any, path: str, *, lo=None, hi=None, form: str, open_lo: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(path, f"expected {form}, got {value!r}", form)
    too_low = lo is not None and (value <= lo if open_lo else value < lo)
    too_high = hi is not None and value > hi
    if too_low or too_high:
        low = "-inf" if lo is None else f"{lo:g}"
        high = "inf" if hi is None else f"{hi:g}"
        bracket = "(" if open_lo else "["
        raise InputError(path, f"{value!r} is out of range {bracket}{low}, {high}]", form)
    return value


def build_section(cls: type, table: Any, section: str) -> Any:
    """The section dataclass ``cls`` built from the TOML ``table`` of ``[section]``: each key
    converted by its field's kind and limits (lengths to metres, angles to radians); an
    :class:`InputError` names ``section.key`` for a value that is not a table, an unknown key, a
    missing required key or a bad value."""
    if not isinstance(table, dict):
        raise InputError(section, "expected a table", f"[{section}] with keys")
    fields = {f.metadata["key"]: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(table) - set(fields))
    if unknown:
        raise InputError(f"{section}.{unknown[0]}", "unknown key", "one of " + ", ".join(fields))
    kwargs = {}
    for key, f in fields.items():
        path = f"{section}.{key}"
        if key in table:
            kwargs[f.name] = _convert(table[key], f.metadata, path)
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise InputError(path, "missing", f"a value: {f.metadata['kind'].replace('_', ' ')}")
    return cls(**kwargs)


def _check_consistency(p: Preset) -> None:
    """Cross-field rules that no single key can express, and the physics checks every command
    would otherwise make later (bands disjoint, a known camera, optical wavelengths)."""
    from metalens_cli.io.tables import check_wavelengths
    from metalens_cli.optics.band_rules import CAMERA_NAMES, check_bands
    from metalens_cli.optics.window import check_scales

    check_name(p.name)
    check_scales(p.optimize.halo_scale, p.optimize.core_pixels, "optimize.")
    for key, values in (
        ("sensor.wavelength_range", p.sensor.wavelength_range_m),
        ("nanofin.efficiency_wavelengths", p.nanofin.efficiency_wavelengths_m),
        ("lens.design_wavelength", [p.lens.design_wavelength_m] if p.lens.design_wavelength_m else []),
        ("filter.centers", p.filter.centers_m if p.filter else []),
    ):
        check_wavelengths(values, key)
    if p.sensor.wavelength_range_m[0] >= p.sensor.wavelength_range_m[1]:
        raise InputError("sensor.wavelength_range", "is empty", "LO:HI with LO < HI, e.g. 400nm:700nm")
    o = p.obstruction
    for key, value in (
        ("dirt_scale", o.dirt_scale_m),
        ("fence_pitch", o.fence_pitch_m),
        ("fence_width", o.fence_width_m),
        ("drop_radius", o.drop_radius_m[1]),
        ("rain_radius", o.rain_radius_m[1]),
    ):
        if not value <= MAX_OBSTRUCTION_M:
            raise InputError(
                f"obstruction.{key}",
                f"{value:g} m is not a feature on a cover glass",
                f"at most {MAX_OBSTRUCTION_M * 1e3:g} mm",
            )
    if p.optimize.light > 0 and (p.optimize.photons > 0 or p.optimize.read_noise > 0):
        raise InputError(
            "optimize.light",
            "given with optimize.photons or optimize.read_noise",
            "one camera: light (the verdict's, with read_electrons) or photons and read_noise",
        )
    if p.sensor.full_pixels is not None and p.sensor.full_pixels < p.sensor.pixels:
        raise InputError(
            "sensor.full_pixels",
            f"{p.sensor.full_pixels} is below sensor.pixels ({p.sensor.pixels})",
            "the whole sensor",
        )
    camera = p.sensor.camera_response
    if camera not in CAMERA_NAMES and not camera.lower().endswith(".csv"):
        raise InputError(
            "sensor.camera_response", f"unknown camera {camera!r}", f"one of {', '.join(CAMERA_NAMES)} or a CSV path"
        )
    if p.lens.design == "hyperbolic" and p.lens.design_wavelength_m is None:
        raise InputError(
            "lens.design_wavelength", "missing (required when lens.design = 'hyperbolic')", units.LENGTH_FORM
        )
    if p.nanofin.efficiency == "rcwa" and p.nanofin.efficiency_wavelengths_m:
        raise InputError(
            "nanofin.efficiency_wavelengths",
            'given with efficiency = "rcwa"',
            "either a table (efficiency = [...]) or rcwa",
        )
    if p.nanofin.efficiency != "rcwa" and len(p.nanofin.efficiency) != len(p.nanofin.efficiency_wavelengths_m):
        raise InputError(
            "nanofin.efficiency", "needs one value per nanofin.efficiency_wavelengths entry", "equal lengths"
        )
    for key in ("width", "length"):
        if getattr(p.nanofin, f"{key}_m") > p.nanofin.pitch_m:
            raise InputError(f"nanofin.{key}", "is larger than nanofin.pitch", "a fin inside its cell")
    if p.nanofin.pitch_m * 2 > p.lens.aperture_m:
        raise InputError("nanofin.pitch", "is larger than half the aperture", "a pitch far below lens.aperture")
    if p.filter is not None:
        if p.filter.csv is None and not p.filter.centers_m:
            raise InputError("filter.centers", "missing", "band centres and widths, or filter.csv")
        if p.filter.csv is not None and p.filter.centers_m:
            raise InputError("filter.csv", "given together with filter.centers", "either bands or a CSV")
        if len(p.filter.centers_m) != len(p.filter.widths_m):
            raise InputError("filter.widths", "needs one width per filter.centers entry", "equal lengths")
        if list(p.filter.centers_m) != sorted(p.filter.centers_m):
            raise InputError("filter.centers", "must increase", "band centres in ascending order")
        if p.filter.centers_m:
            try:
                check_bands(
                    list(p.filter.centers_m),
                    list(p.filter.widths_m),
                    p.filter.edge_width_m,
                    p.filter.peak_transmission,
                )
            except InputError as exc:
                raise InputError("filter.widths", exc.message, exc.expected) from None
        _check_learned_filter(p)
    if p.optimize.spectral_sampling == "bands" and (p.filter is None or not p.filter.centers_m):
        raise InputError(
            "optimize.spectral_sampling", '"bands" without filter bands', "a [filter] with centers and widths"
        )
    if math.isinf(p.scene.z_near_m[1]):
        raise InputError("scene.z_near", "must be finite", units.INTERVAL_FORM)
    if not p.scene.z_near_m[1] < p.scene.z_far_m[0]:
        raise InputError("scene.z_far", "must lie beyond scene.z_near", "z_far's lower end above z_near's upper end")
    for kind in p.optimize.obstructions:
        if kind not in ("dirt", "fence", "drops", "rain") and not kind.startswith("file:"):
            raise InputError(
                "optimize.obstructions", f"unknown obstruction {kind!r}", "dirt, fence, drops, rain or file:PATH.png"
            )
    if p.optimize.scene_generator == "torch":
        if p.optimize.images is not None:
            raise InputError(
                "optimize.scene_generator", '"torch" with optimize.images', 'procedural scenes (no images) or "numpy"'
            )
        if not set(p.optimize.obstructions) <= set(DEVICE_OBSTRUCTIONS):
            raise InputError(
                "optimize.scene_generator",
                f'"torch" with obstructions {", ".join(p.optimize.obstructions)}',
                f'obstructions among {", ".join(DEVICE_OBSTRUCTIONS)}, or "numpy"',
            )
    if p.loss.sharp_mode in WAVELENGTH_MODES and p.loss.sharp_window % 2 == 0:
        raise InputError(
            "loss.sharp_window",
            f'{p.loss.sharp_window} with sharp_mode = "{p.loss.sharp_mode}"',
            "an odd window (each wavelength's core is centred on the axis pixel)",
        )


def _check_learned_filter(p: Preset) -> None:
    """A filter to learn: bands (not a CSV), limits that admit a filter, the band quadrature."""
    f = p.filter
    if f.catalogue is not None and not f.learn:
        raise InputError(
            "filter.catalogue", "given without filter.learn = true", "learn = true to snap a learned filter to it"
        )
    if not f.learn:
        return
    if f.csv is not None:
        raise InputError(
            "filter.learn",
            "a measured filter (filter.csv) cannot be learned",
            "filter.centers and filter.widths to start from",
        )
    if not 0 < f.min_width_m < f.max_width_m:
        raise InputError(
            "filter.max_width", f"{f.max_width_m:g} m with min_width {f.min_width_m:g} m", "0 < min_width < max_width"
        )
    if f.min_width_m < 0.81 * f.min_edge_width_m:
        raise InputError("filter.min_width", "is narrower than its edges allow", "min_width >= 0.81 × min_edge_width")
    if p.optimize.spectral_sampling != "bands":
        raise InputError(
            "optimize.spectral_sampling",
            f"{p.optimize.spectral_sampling!r} with filter.learn = true",
            '"bands": wavelengths that follow the learned bands',
        )
    _check_filter_fits(p)


def _nm(value_m: float) -> str:
    return f"{value_m * 1e9:.4g} nm"


def _check_filter_fits(p: Preset) -> None:
    """The limits of a filter to learn admit one: its bands at their narrowest, with their
    gaps, fit inside the sensor range, and the split margin asked for is below the largest any
    such filter keeps (``optics.split_spectrum.largest_margin``); each refusal names the bound."""
    f, (low, high) = p.filter, p.sensor.wavelength_range_m
    n, span = len(f.centers_m), high - low
    if n * f.min_width_m + (n - 1) * f.min_gap_m > span:
        need = f"{n} bands of at least {_nm(f.min_width_m)} (filter.min_width)"
        need += f" with gaps of at least {_nm(f.min_gap_m)}" if n > 1 else ""
        where = f"sensor.wavelength_range {_nm(low)}-{_nm(high)} holds {_nm(span)}"
        if n * f.min_width_m > span:
            raise InputError("filter.min_width", f"{need} do not fit: {where}", f"min_width at most {_nm(span / n)}")
        most = (span - n * f.min_width_m) / (n - 1)
        raise InputError("filter.min_gap", f"{need} do not fit: {where}", f"min_gap at most {_nm(most)}")
    k = preset_incidence_factor(p)
    f_m, z_near = p.lens.focal_length_m, p.scene.z_near_m
    best = largest_margin(n, f_m, z_near, (low, high), f.min_width_m, f.min_gap_m, k)
    if f.split_margin_m < best:
        return
    gap_binds = largest_margin(n, f_m, z_near, (low, high), f.min_width_m, 0.0, k) > best
    limits = (
        f"{n} bands of at least {_nm(f.min_width_m)} (filter.min_width)"
        + (f", {_nm(f.min_gap_m)} apart (filter.min_gap)" if gap_binds else "")
        + f" inside sensor.wavelength_range {_nm(low)}-{_nm(high)} at lens.focal_length {f_m * 1e3:g} mm,"
        + f" scene.z_near {z_near[0] * 1e3:g}-{z_near[1] * 1e3:g} mm"
        + (f" and the blue shift k = {k:.4f} of filter.max_incidence" if k < 1 else "")
    )
    if best <= 0:
        raise InputError(
            "filter.learn",
            f"no filter of {limits} meets the split-spectrum conditions (the best falls short by {_nm(-best)})",
            "a longer focal length, a nearer z_near, narrower bands or a smaller max_incidence",
        )
    raise InputError(
        "filter.split_margin",
        f"{_nm(f.split_margin_m)} is more than any filter of {limits} keeps: at most {_nm(best)}",
        f"split_margin below {_nm(best)}",
    )


def preset_incidence_factor(preset: Preset) -> float:
    """k of a preset's ``[filter]`` (``optics.split_spectrum.incidence_factor``): ``max_incidence``
    "auto" (the steepest ray on its sensor, :func:`~metalens_cli.optics.split_spectrum.steepest_incidence`)
    or an angle, with its ``n_eff``; 1 without a filter."""
    band_filter = preset.filter
    if band_filter is None:
        return 1.0
    if band_filter.max_incidence == "auto":
        half_diagonal = math.sqrt(2) * preset.sensor.pixels * preset.sensor.pixel_pitch_m / 2
        angle = steepest_incidence(preset.lens.aperture_m, half_diagonal, preset.lens.focal_length_m)
    else:
        angle = units.parse_angle(band_filter.max_incidence, "filter.max_incidence")
    return incidence_factor(angle, band_filter.n_eff)


def preset_from_dict(data: dict[str, Any], name: str = "preset", source: str | None = None) -> Preset:
    """Validate a parsed TOML document and return the resolved :class:`Preset`."""
    allowed = TOP_LEVEL_KEYS | set(SECTIONS)
    unknown = sorted(set(data) - allowed)
    if unknown:
        raise InputError(unknown[0], "unknown section or key", "one of " + ", ".join(sorted(allowed)))
    sections = {}
    for section, (cls, required) in SECTIONS.items():
        if section in data:
            table = data[section]
            if section == "optimize" and isinstance(table, dict) and isinstance(table.get("field_angles"), str):
                table = {**table, "field_angles": _field_angles_over_sensor(table["field_angles"], sections)}
            sections[section] = build_section(cls, table, section)
        elif required:
            raise InputError(section, "missing section", f"a [{section}] table")
        elif section in OPTIONAL_DEFAULTS:
            sections[section] = OPTIONAL_DEFAULTS[section]()
    preset = Preset(
        name=as_str(data.get("name", name), "name", "a string"),
        description=as_str(data.get("description", ""), "description", "a string"),
        source=source,
        **sections,
    )
    _check_consistency(preset)
    return preset


SENSOR_FIELD_COUNT = 4  # field angles of optimize.field_angles = "sensor"
SENSOR_FIELD_FORM = '"sensor" or "sensor:K" (K field angles over the whole sensor), or angles such as "0deg,10deg"'


def _field_angles_over_sensor(text: str, sections: dict) -> str | list[str]:
    """``optimize.field_angles = "sensor[:K]"`` as the angles of :func:`sensor_field_angles` over
    the whole sensor (``sensor.full_pixels``, else ``sensor.pixels``) at the focal length; any
    other text is returned to be parsed as angles."""
    word, _, count = text.strip().partition(":")
    if word.strip().lower() != "sensor":
        return text
    try:
        k = int(count) if count.strip() else SENSOR_FIELD_COUNT
    except ValueError:
        k = 0
    if not 1 <= k <= 64:
        raise InputError("optimize.field_angles", f"{text!r}", SENSOR_FIELD_FORM + "; K from 1 to 64")
    sensor, lens = sections["sensor"], sections["lens"]
    side = sensor.full_pixels or sensor.pixels
    angles = sensor_field_angles(side, sensor.pixel_pitch_m, lens.focal_length_m, k)
    return [f"{a!r}rad" for a in angles]


def sensor_field_angles(pixels: int, pixel_pitch_m: float, distance_m: float, count: int = SENSOR_FIELD_COUNT):
    """Field angles (rad) that sample a square sensor of ``pixels``² pixels of pitch
    ``pixel_pitch_m`` evenly by area: the image heights ρ at the middle quantiles (k + ½)/``count``
    of the height of a point uniform on the sensor, as angles atan(ρ/``distance_m``) (the chief
    ray's image height at the lens-to-sensor distance). Drawn equally likely, they weigh the field
    as the sensor's pixels do: the corners count as much as the area they hold."""
    import numpy as np

    n = 1024  # cell centres of a fine grid over one quadrant: the height distribution to < 1e-3 of the half side
    u = (np.arange(n) + 0.5) / n
    heights = np.sort(np.hypot(*np.meshgrid(u, u)).ravel()) * pixels * pixel_pitch_m / 2
    quantiles = (np.arange(count) + 0.5) / count
    return tuple(float(math.atan(h / distance_m)) for h in np.quantile(heights, quantiles))


def read_toml(path: Path, field: str = "preset") -> dict[str, Any]:
    """The parsed TOML document at ``path``; unreadable, non-UTF-8 or invalid files are an
    :class:`InputError` naming ``field``."""
    text = read_text(path, field, "a UTF-8 TOML file")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(field, f"{path.name} is not valid TOML: {exc}", "TOML (https://toml.io)") from None
    except RecursionError:
        raise InputError(field, f"{path.name} nests arrays or tables too deeply", "a preset's flat sections") from None


def load_preset(path: str | Path) -> Preset:
    """Read and validate a preset TOML file.

    File paths in the preset are relative to its folder; every file it names is opened and
    checked here.

    Args:
        path: the preset TOML file.

    Returns:
        The :class:`Preset`, named after the file's stem.

    Raises:
        InputError: naming the file and the key path.
    """
    path = Path(arguments.path(path, "path", "a preset TOML file"))
    data = read_toml(path)
    try:
        preset = preset_from_dict(data, name=path.stem, source=str(path))
    except InputError as exc:
        raise InputError(f"{path.name}: {exc.field}", exc.message, exc.expected) from None
    return _resolve_paths(preset, path.parent)


def _resolve_paths(preset: Preset, folder: Path) -> Preset:
    """File paths in a preset are relative to the preset's folder. Every file the preset names
    is opened and checked here, before any command does work: tables parsed over the sensor
    range, images' headers read, a filter catalogue read and required to hold a filter the run
    can snap to (:func:`_check_catalogue`), a checkpoint's format recognised."""
    import numpy as np

    from metalens_cli.io.filter_catalogue import read_catalogue
    from metalens_cli.io.spectra_files import camera_from_csv, efficiency_from_csv, filter_from_csv

    grid = np.linspace(*preset.sensor.wavelength_range_m, 31)

    def resolved(value: str | None, key: str, read=None, expected: str = "a CSV path relative to the preset"):
        if value is None:
            return None
        full = regular_file((folder / value).resolve(), key, expected)
        if read is not None:
            read(full, grid, key)
        return str(full)

    nanofin = dataclasses.replace(
        preset.nanofin,
        efficiency_csv=resolved(preset.nanofin.efficiency_csv, "nanofin.efficiency_csv", efficiency_from_csv),
        material=_resolved_material(preset.nanofin.material, folder, "nanofin.material"),
        substrate=_resolved_material(preset.nanofin.substrate, folder, "nanofin.substrate"),
    )
    band_filter = preset.filter
    if band_filter is not None:
        catalogue = resolved(band_filter.catalogue, "filter.catalogue", expected="a CSV path relative to the preset")
        band_filter = dataclasses.replace(
            band_filter, csv=resolved(band_filter.csv, "filter.csv", filter_from_csv), catalogue=catalogue
        )
    sensor = preset.sensor
    if sensor.camera_response.lower().endswith(".csv"):
        camera = resolved(sensor.camera_response, "sensor.camera_response", camera_from_csv)
        sensor = dataclasses.replace(sensor, camera_response=camera)
    weights = resolved(preset.loss.domain_adaptation_weights, "loss.domain_adaptation_weights", expected=CHECKPOINT)
    if weights is not None:
        _check_checkpoint(Path(weights), "loss.domain_adaptation_weights")
    loss = dataclasses.replace(preset.loss, domain_adaptation_weights=weights)
    optimize = dataclasses.replace(
        preset.optimize,
        images=None
        if preset.optimize.images is None
        else str(image_folder(folder / preset.optimize.images, "optimize.images")),
        obstructions=tuple(
            obstruction_file(kind, folder, "optimize.obstructions") for kind in preset.optimize.obstructions
        ),
        init_from=None
        if preset.optimize.init_from is None
        else str(initial_theta_file(folder / preset.optimize.init_from, "optimize.init_from")),
    )
    result = dataclasses.replace(
        preset, nanofin=nanofin, filter=band_filter, sensor=sensor, loss=loss, optimize=optimize
    )
    if band_filter is not None and band_filter.catalogue is not None:
        _check_catalogue(result, read_catalogue(band_filter.catalogue))
    return result


CHECKPOINT = "a PyTorch checkpoint (.pth) relative to the preset"


def _check_checkpoint(path: Path, key: str) -> None:
    """A PyTorch checkpoint: a zip archive (``torch.save``) or a pickle (the legacy format);
    its tensors are read, with ``weights_only``, where the run starts."""
    with open(path, "rb") as handle:
        head = handle.read(4)
    if not (head.startswith(b"PK\x03\x04") or head[:1] == b"\x80"):
        raise InputError(key, f"{path.name} is not a PyTorch checkpoint", CHECKPOINT)


def image_folder(path: Path, key: str) -> Path:
    """A preset's folder of images (``key``: ``optimize.images``, ``data.images``): at least one
    image, every image's header readable and within the pixel limit (pixels are decoded where the
    run starts)."""
    from metalens_cli.io.image_files import check_image_file
    from metalens_cli.io.input_files import IMAGE_SUFFIXES, image_files

    path, form = path.resolve(), f"a folder of {', '.join(IMAGE_SUFFIXES)} images relative to the preset"
    if not path.is_dir():
        raise InputError(key, f"no such folder {str(path)!r}", form)
    files = image_files(path)
    if not files:
        raise InputError(key, f"{str(path)!r} holds no images", form)
    for file in files:
        check_image_file(file, key)
    return path


INITIAL_THETA = "a run directory of metalens optimize or a radial θ .npy (rad), relative to the preset"


def initial_theta_file(path: Path, key: str) -> Path:
    """The θ file of ``optimize.init_from``: a run directory's ``theta.npy`` or the .npy itself,
    holding a finite 1-D radial θ (rad at r = k·pitch), checked here; its ring count is checked
    against the lens where the run builds its model (``design.model``)."""
    import numpy as np

    from metalens_cli.io.input_files import read_npy

    path = path.resolve()
    if path.is_dir():
        path = path / "theta.npy"
    theta = read_npy(path, key, INITIAL_THETA)
    if theta.ndim != 1 or theta.size < 2 or not np.all(np.isfinite(theta)):
        raise InputError(key, f"{path.name} holds a {theta.shape} array, not a finite radial θ", INITIAL_THETA)
    return path


def obstruction_file(kind: str, folder: Path, key: str) -> str:
    """An obstruction entry of a preset (``key``), a ``file:PATH`` resolved against the preset's
    ``folder`` and its image checked; other kinds as they are."""
    if not kind.startswith("file:"):
        return kind
    from metalens_cli.io.image_files import check_image_file

    full = regular_file((folder / kind[5:]).resolve(), key, "file:PATH.png relative to the preset")
    check_image_file(full, key)
    return f"file:{full}"


def catalogue_candidates(preset: Preset, catalogue: list) -> list:
    """The filters of ``catalogue`` (``io.filter_catalogue.CatalogueFilter``) a learned filter
    may snap to: as many bands as ``filter.centers``, meeting the split-spectrum conditions at
    the preset's f, z_near, sensor range and oblique incidence."""
    n, k, sensor = len(preset.filter.centers_m), preset_incidence_factor(preset), preset.sensor.wavelength_range_m
    (z_lo, z_hi), f_m = preset.scene.z_near_m, preset.lens.focal_length_m

    def meets(entry) -> bool:
        bands = sensed_bands(
            label_bands([(c - w / 2, c + w / 2) for c, w in zip(entry.centers_m, entry.widths_m)]), sensor
        )
        return bool(bands) and all(c.ok for c in split_conditions(oblique_bands(bands, k), f_m, z_lo, z_hi, sensor))

    return [entry for entry in catalogue if len(entry.centers_m) == n and meets(entry)]


def _check_catalogue(preset: Preset, catalogue: list) -> None:
    """A catalogue with at least one filter the run can snap to (:func:`catalogue_candidates`)."""
    if catalogue_candidates(preset, catalogue):
        return
    n, name = len(preset.filter.centers_m), Path(preset.filter.catalogue).name
    same = [entry for entry in catalogue if len(entry.centers_m) == n]
    if not same:
        counts = ", ".join(str(c) for c in sorted({len(entry.centers_m) for entry in catalogue}))
        raise InputError(
            "filter.catalogue",
            f"{name} lists no {n}-band filter (its filters have {counts} bands)",
            f"a catalogue with {n}-band filters, as many bands as filter.centers",
        )
    k, (z_lo, z_hi) = preset_incidence_factor(preset), preset.scene.z_near_m
    raise InputError(
        "filter.catalogue",
        f"none of the {len(same)} {n}-band filters in {name} meets the split-spectrum conditions at "
        f"lens.focal_length {preset.lens.focal_length_m * 1e3:g} mm, scene.z_near {z_lo * 1e3:g}-{z_hi * 1e3:g} mm"
        + (f" with the blue shift k = {k:.4f} of filter.max_incidence" if k < 1 else ""),
        "a catalogue with such a filter, or no catalogue",
    )


def _resolved_material(text: str, folder: Path, key: str) -> str:
    """A material naming a CSV file: the file's absolute path (relative to the preset), checked."""
    from metalens_cli.io.materials import material_file, parse_material

    if material_file(text) is None:
        return text
    full = str((folder / text).resolve())
    parse_material(full, key)
    return full


def to_toml(preset: Preset, **overrides: dict[str, Any]) -> str:
    """The resolved preset as TOML that :func:`load_preset` reads back to an equal preset:
    lengths written in metres with full precision, paths absolute. ``overrides`` maps a section
    name to {field name: value} replacing the preset's values (e.g. ``optimize={"steps": 10}``)."""
    lines = [f"name = {toml_value(preset.name)}", f"description = {toml_value(preset.description)}"]
    for section in SECTIONS:
        config = getattr(preset, section)
        if config is not None:
            lines += ["", section_toml(section, dataclasses.replace(config, **overrides.get(section, {}))).rstrip("\n")]
    return "\n".join(lines) + "\n"


def section_toml(section: str, config: Any) -> str:
    """One preset section (``[section]`` and its keys) as :func:`to_toml` writes it."""
    lines = [f"[{section}]"]
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if value is not None:
            lines.append(f"{f.metadata['key']} = {toml_field(value, f.metadata['kind'])}")
    return "\n".join(lines) + "\n"


def toml_field(value: Any, kind: str) -> str:
    """TOML text of one field's value by its kind: lengths as ``"<repr>m"`` strings (``"inf"`` for
    infinity), length lists and intervals as arrays of them, angle lists as ``"<repr>rad"`` strings,
    the rest by :func:`toml_value`."""

    def length(v: float) -> str:
        return '"inf"' if math.isinf(v) else f'"{v!r}m"'

    if kind in ("length", "signed_length"):
        return f'"{value!r}m"' if kind == "signed_length" else length(value)
    if kind == "angle":
        return f'"{value!r}rad"'
    if kind in ("length_list", "interval"):
        return "[" + ", ".join(length(v) for v in value) + "]"
    if kind == "angle_list":
        return "[" + ", ".join(f'"{v!r}rad"' for v in value) + "]"
    return toml_value(value)


def toml_value(value: Any) -> str:
    """TOML text of a bool, a number (its ``repr``), a list or tuple (an array), or anything else as
    a basic string with TOML escapes."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    return (
        '"'
        + "".join(
            _TOML_ESCAPES.get(c) or (f"\\u{ord(c):04x}" if ord(c) < 0x20 or ord(c) == 0x7F else c) for c in str(value)
        )
        + '"'
    )


_TOML_ESCAPES = {"\\": "\\\\", '"': '\\"', "\b": "\\b", "\t": "\\t", "\n": "\\n", "\f": "\\f", "\r": "\\r"}


def to_dict(obj: Any) -> Any:
    """The resolved preset as plain JSON-ready data: SI values, key names with units (``_m``)."""
    if dataclasses.is_dataclass(obj):
        return {f.name: to_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, tuple):
        return [to_dict(v) for v in obj]
    if isinstance(obj, float) and math.isinf(obj):
        return None
    return obj
