"""Reconstruction presets: how ``metalens reconstruct train`` builds and trains the network.

A reconstruction preset holds only the network, the schedule and the data; the camera (lens,
filter, sensor pitch, depth intervals, obstruction sizes) comes from the design being trained
for (its own preset, or the defaults of ``simulate``). Same TOML conventions and errors as
:mod:`metalens_cli.io.presets`::

    name = "quick-reconstruct"
    [network]   width, depth, frequencies, reduction, spectral_bins
    [train]     steps, batch_size, crop, learning_rate, weight_decay, warmup_steps, restart_period,
                restart_growth, seed, checkpoint_every, validate_every, l1, ssim, lpips
    [data]      obstructions, scenes, images, pool_size, pool_pixels, sensor_pixels, pool_refresh, clear_fraction,
                near_depths, far_depths, wavelengths, photons, read_noise, noise_sigma,
                brightness, contrast, validation_pairs
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

from metalens_cli.constants import OBSTRUCTION_KINDS, SENSOR_PIXELS
from metalens_cli.errors import InputError
from metalens_cli.io.presets import (
    as_str,
    build_section,
    check_name,
    image_folder,
    obstruction_file,
    read_toml,
    toml_field,
    toml_key,
)
from metalens_cli.io.tables import check_wavelengths

# generated training scenes (``design.reconstruct_data``): "natural" the procedural scenes with text, tilings, flat
# surfaces and gradients (``procedural_scene(..., structure=True)``), "procedural" those without (the optimiser's),
# "dead-leaves" charts (never the evaluation charts' seeds), "mixed" natural or dead-leaves, half each
SCENES = ("mixed", "natural", "procedural", "dead-leaves")


@dataclass(frozen=True)
class NetworkConfig:
    """U-Net width (channels at full resolution), depth (downsamplings), positional frequencies
    per axis, the CBAM channel reduction and the knots of the learned spectral filter
    (``imaging.network``; 0: none)."""

    width: int = toml_key("width", "int", lo=4, hi=256, default=16)
    depth: int = toml_key("depth", "int", lo=1, hi=6, default=3)
    frequencies: int = toml_key("frequencies", "int", lo=0, hi=12, default=4)
    reduction: int = toml_key("reduction", "int", lo=1, hi=64, default=4)
    spectral_bins: int = toml_key("spectral_bins", "int", lo=0, hi=1024, default=32)


@dataclass(frozen=True)
class TrainConfig:
    """AdamW; linear warm-up from 0.1·lr over ``warmup_steps``, then cosine annealing with warm
    restarts every ``restart_period`` steps (× ``restart_growth`` after each restart);
    loss l1·L1 + ssim·(1 − SSIM) + lpips·LPIPS on sRGB-encoded images."""

    steps: int = toml_key("steps", "int", lo=0, hi=10_000_000)
    batch_size: int = toml_key("batch_size", "int", lo=1, hi=4096, default=8)
    crop: int = toml_key("crop", "int", lo=16, hi=4096, default=128)
    learning_rate: float = toml_key("learning_rate", "float", lo=0.0, hi=10.0, default=2e-3)
    weight_decay: float = toml_key("weight_decay", "float", lo=0.0, default=1e-4)
    warmup_steps: int = toml_key("warmup_steps", "int", lo=0, hi=10_000_000, default=50)
    restart_period: int = toml_key("restart_period", "int", lo=1, hi=10_000_000, default=1000)
    restart_growth: int = toml_key("restart_growth", "int", lo=1, hi=16, default=1)
    seed: int = toml_key("seed", "int", lo=0, hi=2**63 - 1, default=0)
    checkpoint_every: int = toml_key("checkpoint_every", "int", lo=1, hi=10_000_000, default=100)
    validate_every: int = toml_key("validate_every", "int", lo=1, hi=10_000_000, default=250)
    l1: float = toml_key("l1", "float", lo=0.0, hi=1e3, default=1.0)
    ssim: float = toml_key("ssim", "float", lo=0.0, hi=1e3, default=0.1)
    lpips: float = toml_key("lpips", "float", lo=0.0, default=0.1)


@dataclass(frozen=True)
class DataConfig:
    """Simulated training pairs: a pool of ``pool_size`` captures of ``pool_pixels``² sensor
    pixels, regenerated every ``pool_refresh`` steps (0: never), from which each step crops;
    ``clear_fraction`` of the inputs are unobstructed captures. Each capture lies at a random place
    on a sensor of ``sensor_pixels``² (the image formation is shift-invariant), so the training
    crops carry positions over the whole sensor. PSFs from a bank of
    ``near_depths`` × ``far_depths`` depths (stratum midpoints of the camera's intervals), mixed
    over ``wavelengths``. Sensor noise (``photons``, ``read_noise``) in the pool; per step
    Gaussian noise σ ``noise_sigma``, gain 1 ± ``brightness`` and contrast 1 ± ``contrast`` on the
    input, flips and quarter turns on both."""

    obstructions: tuple[str, ...] = toml_key("obstructions", "string_list", default=("dirt", "fence"))
    scenes: str = toml_key("scenes", "choice", choices=SCENES, default="mixed")
    images: str | None = toml_key("images", "folder", default=None)  # replaces the generated scenes
    pool_size: int = toml_key("pool_size", "int", lo=1, hi=100_000, default=64)
    pool_pixels: int = toml_key("pool_pixels", "int", lo=16, hi=4096, default=256)
    sensor_pixels: int = toml_key("sensor_pixels", "int", lo=16, hi=65536, default=SENSOR_PIXELS)
    pool_refresh: int = toml_key("pool_refresh", "int", lo=0, hi=10_000_000, default=0)
    clear_fraction: float = toml_key("clear_fraction", "float", lo=0.0, hi=1.0, default=0.2)
    near_depths: int = toml_key("near_depths", "int", lo=1, hi=64, default=4)
    far_depths: int = toml_key("far_depths", "int", lo=1, hi=64, default=2)
    wavelengths_m: tuple[float, ...] = toml_key(
        "wavelengths", "length_list", default=tuple(k * 1e-9 for k in range(400, 701, 10))
    )
    photons: float = toml_key("photons", "float", lo=0.0, default=0.0)
    read_noise: float = toml_key("read_noise", "float", lo=0.0, hi=1.0, default=0.0)
    noise_sigma: float = toml_key("noise_sigma", "float", lo=0.0, hi=1.0, default=5e-3)
    brightness: float = toml_key("brightness", "float", lo=0.0, hi=0.9, default=0.1)
    contrast: float = toml_key("contrast", "float", lo=0.0, hi=0.9, default=0.1)
    validation_pairs: int = toml_key("validation_pairs", "int", lo=1, hi=10_000, default=8)


@dataclass(frozen=True)
class ReconstructPreset:
    """A checked reconstruction preset: its ``name`` (a plain name), the ``network``, ``train`` and
    ``data`` sections, a ``description``, and the ``source`` file it was read from (None when not
    read from one)."""

    name: str
    network: NetworkConfig = field(default_factory=NetworkConfig)
    train: TrainConfig = field(default_factory=lambda: TrainConfig(steps=1000))
    data: DataConfig = field(default_factory=DataConfig)
    description: str = ""
    source: str | None = None


SECTIONS = {"network": NetworkConfig, "train": TrainConfig, "data": DataConfig}


def reconstruct_preset_from_dict(data: dict, name: str = "reconstruct", source: str | None = None) -> ReconstructPreset:
    """Validate a parsed TOML document (every section optional except ``[train]``)."""
    allowed = {"name", "description", *SECTIONS}
    unknown = sorted(set(data) - allowed)
    if unknown:
        raise InputError(unknown[0], "unknown section or key", "one of " + ", ".join(sorted(allowed)))
    if "train" not in data:
        raise InputError("train", "missing section", "a [train] table with at least steps")
    sections = {key: build_section(cls, data.get(key, {}), key) for key, cls in SECTIONS.items()}
    preset = ReconstructPreset(
        as_str(data.get("name", name), "name", "a string"),
        description=as_str(data.get("description", ""), "description", "a string"),
        source=source,
        **sections,
    )
    check_name(preset.name)  # the camera presets' rule
    for kind in preset.data.obstructions:
        if kind not in OBSTRUCTION_KINDS:
            raise InputError("data.obstructions", f"unknown obstruction {kind!r}", ", ".join(OBSTRUCTION_KINDS))
    if preset.data.pool_pixels > preset.data.sensor_pixels:
        raise InputError(
            "data.pool_pixels",
            f"{preset.data.pool_pixels} px exceeds data.sensor_pixels {preset.data.sensor_pixels}",
            "simulated captures no larger than the sensor",
        )
    if preset.network.spectral_bins == 1:
        raise InputError(
            "network.spectral_bins", "1 leaves the filter only its fixed DC knot", "0 (no filter) or at least 2"
        )
    if preset.train.crop > preset.data.pool_pixels:
        raise InputError(
            "train.crop",
            f"{preset.train.crop} px exceeds data.pool_pixels {preset.data.pool_pixels}",
            "a crop no larger than the simulated captures",
        )
    if len(preset.data.wavelengths_m) < 2 or list(preset.data.wavelengths_m) != sorted(set(preset.data.wavelengths_m)):
        raise InputError(
            "data.wavelengths", "needs at least two increasing wavelengths", "a range such as 400:700:10nm"
        )
    check_wavelengths(preset.data.wavelengths_m, "data.wavelengths")
    return preset


def load_reconstruct_preset(path: str | Path) -> ReconstructPreset:
    """Read and validate a reconstruction preset; ``data.images`` and ``file:`` obstructions are
    relative to the file, and checked as :func:`~metalens_cli.io.presets.load_preset` checks its own."""
    path = Path(path)
    data = read_toml(path, "--preset")
    try:
        preset = reconstruct_preset_from_dict(data, name=path.stem, source=str(path))
    except InputError as exc:
        raise InputError(f"{path.name}: {exc.field}", exc.message, exc.expected) from None
    try:  # the files it names, resolved against its folder and checked now (io.presets)
        images = preset.data.images
        data = dataclasses.replace(
            preset.data,
            images=None if images is None else str(image_folder(path.parent / images, "data.images")),
            obstructions=tuple(obstruction_file(k, path.parent, "data.obstructions") for k in preset.data.obstructions),
        )
    except InputError as exc:
        raise InputError(f"{path.name}: {exc.field}", exc.message, exc.expected) from None
    return dataclasses.replace(preset, data=data)


def reconstruct_to_toml(preset: ReconstructPreset, **overrides: dict) -> str:
    """The resolved preset as TOML that :func:`load_reconstruct_preset` reads back equal;
    ``overrides`` maps a section to {field: value}."""
    from metalens_cli.io.presets import toml_value

    lines = [f"name = {toml_value(preset.name)}", f"description = {toml_value(preset.description)}"]
    for section in SECTIONS:
        config = dataclasses.replace(getattr(preset, section), **overrides.get(section, {}))
        lines += ["", f"[{section}]"]
        lines += [
            f"{f.metadata['key']} = {toml_field(getattr(config, f.name), f.metadata['kind'])}"
            for f in dataclasses.fields(config)
            if getattr(config, f.name) is not None
        ]
    return "\n".join(lines) + "\n"
