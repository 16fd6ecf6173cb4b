"""The run of ``metalens psf import`` around the bench protocol (:mod:`.measured_psf`): its
settings from the options and the manifest, its cost, the dark frame, the cube file and its
report (lengths in metres, times in seconds)."""

from __future__ import annotations

import math
import os
from pathlib import Path

from metalens_cli.analysis.measured_psf import ImportSettings, MeasuredCube, dark_frame
from metalens_cli.errors import InputError
from metalens_cli.io.exr import write_exr_cube
from metalens_cli.io.json_files import jsonable
from metalens_cli.io.psf_manifest import Manifest, frame_shape, read_frame_file
from metalens_cli.io.resources import Estimate
from metalens_cli.io.units import format_length

WORKERS = 2
BYTES_PER_FRAME_PIXEL = 48  # float32 working copies of one frame (values, median, smoothed, masks)
SECONDS_PER_FRAME_PIXEL = 2.5e-8  # measured 1.5e-8 (16-bit PNG, 2 cores: docs/benchmarks.md), with a margin
CAMERA_PITCH_M = (0.1e-6, 100e-6)  # camera pixels: from a phone sensor's 0.56 µm to a large-format CCD's tens of µm
CUBE_PITCH_M = (1e-12, 1e-2)  # the cube's pitch (camera pitch / magnification): 1 pm to 1 cm


def import_settings(
    manifest: Manifest,
    manifest_path: str | os.PathLike[str],
    *,
    pixel_pitch_m: float | None = None,
    magnification: float | None = None,
    pixels: int | None = None,
    normalization: str = "sum-to-one",
    centring: str = "centroid",
    saturation: float | None = None,
    allow_saturated: bool = False,
    hot_pixel_sigma: float = 6.0,
) -> ImportSettings:
    """The settings of an import: the pixel pitch, magnification and saturation given, else the
    manifest's. Refused, naming the option or the manifest's key: no pixel pitch, a camera pitch
    outside ``CAMERA_PITCH_M``, a cube pitch outside ``CUBE_PITCH_M``."""
    pitch = pixel_pitch_m or manifest.settings.get("pixel_pitch_m")
    if pitch is None:
        raise InputError(
            "--pixel-pitch",
            "the camera's pixel pitch is not given",
            "--pixel-pitch 3.45um or pixel_pitch in a TOML manifest",
        )
    if not CAMERA_PITCH_M[0] <= pitch <= CAMERA_PITCH_M[1]:
        raise InputError(
            "--pixel-pitch" if pixel_pitch_m else f"{Path(manifest_path).name}: pixel_pitch",
            f"{format_length(pitch)} is not a camera's pixel pitch",
            "0.1 µm to 100 µm, e.g. 3.45um",
        )
    settings = ImportSettings(
        pitch,
        magnification or manifest.settings.get("magnification", 1.0),
        pixels,
        normalization,
        centring,
        saturation or manifest.settings.get("saturation"),
        allow_saturated,
        hot_pixel_sigma,
    )
    if not CUBE_PITCH_M[0] <= settings.pixel_pitch_m <= CUBE_PITCH_M[1]:
        raise InputError(
            "--magnification" if magnification else f"{Path(manifest_path).name}: magnification",
            f"the cube's pitch {settings.pixel_pitch_m:.3g} m (camera pitch / magnification) is not a pixel's",
            "a camera pitch and magnification giving 1 pm to 1 cm",
        )
    return settings


def estimate_import(manifest: Manifest, pixels: int | None) -> Estimate:
    """Memory and time of importing the manifest's frames (sized from the first frame's header)
    with ``WORKERS`` workers, and the bytes of the cube (a 64-pixel window when automatic)."""
    height, width = frame_shape(manifest.frames[0])
    return Estimate(
        f"psf import of {len(manifest.frames)} frames of {width} × {height} pixels",
        BYTES_PER_FRAME_PIXEL * WORKERS * height * width,
        "--pixels",
        SECONDS_PER_FRAME_PIXEL * len(manifest.frames) * height * width,
        disk_bytes=len(manifest.depths_m) * len(manifest.wavelengths_m) * (pixels or 64) ** 2 * 4,
    )


def read_dark(
    manifest: Manifest, manifest_path: str | os.PathLike[str], dark_path=None, hot_pixel_sigma: float = 6.0
) -> tuple[str | os.PathLike[str] | None, tuple | None]:
    """The dark frame's path (``dark_path``, else the manifest's, else None) and the frame with
    its hot pixels (:func:`.measured_psf.dark_frame`), or None without one."""
    source = dark_path or manifest.settings.get("dark")
    if source is None:
        return None, None
    field = "--dark" if dark_path else f"{Path(manifest_path).name}: dark"
    values, _ = read_frame_file(Path(source), None, field)
    return source, dark_frame(values, hot_pixel_sigma)


def cube_metadata(cube: MeasuredCube, settings: ImportSettings, dark_source) -> dict:
    """What the cube's header and the report say of the measurement: camera pitch, magnification,
    centring, hot pixels replaced, the dark frame and every frame's report."""
    return {
        "source": "measured",
        "camera_pixel_pitch_m": settings.camera_pixel_pitch_m,
        "magnification": settings.magnification,
        "centring": settings.centring,
        "hot_pixels": cube.hot_pixels,
        "dark": None if dark_source is None else str(dark_source),
        "frames": cube.frames,
    }


def write_measured_cube(
    path: str | os.PathLike[str], cube: MeasuredCube, design: str, normalization: str, metadata: dict
) -> None:
    """The cube as an EXR PSF cube (``io.exr``), ``metadata`` in its header."""
    write_exr_cube(
        path,
        cube.psf,
        cube.wavelengths_m,
        cube.depths_m,
        cube.pixel_pitch_m,
        design,
        normalization=normalization,
        extra=jsonable(metadata),
    )


def import_report(
    path: str | os.PathLike[str],
    cube: MeasuredCube,
    design: str,
    normalization: str,
    metadata: dict,
    seconds: float,
    plot_path=None,
) -> dict:
    """The JSON report of a cube written to ``path`` (and plotted to ``plot_path``): its window,
    axes (a source at infinity: None), ``metadata``, the run's ``seconds`` and the warnings."""
    return {
        "file": str(path),
        "design": design,
        "pixels": int(cube.psf.shape[-1]),
        "pixel_pitch_m": cube.pixel_pitch_m,
        "wavelengths_m": cube.wavelengths_m.tolist(),
        "depths_m": [None if math.isinf(d) else float(d) for d in cube.depths_m],
        "normalization": normalization,
        **metadata,
        "seconds": seconds,
        "warnings": cube.warnings,
        **({"plot": str(plot_path)} if plot_path else {}),
    }
