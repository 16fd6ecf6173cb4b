"""Design specs: the one way every command names a lens.

A spec is one of

- ``hyperbolic:532nm``: the hyperbolic lens of that design wavelength (f and D from options or
  the preset; meta-atom pitch from options, the preset, or the paper's 395 nm);
- ``PATH.npy``: a rotation map θ in radians, 1-D radial (θ at r = k·pitch) or 2-D on the
  meta-atom grid (axis at site (M//2, M//2)); pitch, f and D from options or the preset;
- ``PATH.toml``: a preset whose ``lens.design`` is ``hyperbolic``;
- a run directory (written by ``metalens optimize``) holding ``preset.toml`` and ``theta.npy``.

Explicit values (CLI options) win over the preset named with ``--preset``, which wins over the
preset a spec carries (a TOML spec or a run directory). Lengths in SI metres.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from metalens_cli import arguments
from metalens_cli.constants import PAPER_PITCH_M
from metalens_cli.errors import InputError
from metalens_cli.io import units
from metalens_cli.io.input_files import read_npy
from metalens_cli.io.presets import Preset, load_preset
from metalens_cli.io.tables import check_wavelengths

SPEC_FORM = "hyperbolic:WAVELENGTH (e.g. hyperbolic:532nm), a θ .npy file, a preset .toml or a run directory"


@dataclass(frozen=True)
class Design:
    """A resolved design: the lens, the lens-to-sensor distance and the preset in force (if any).

    Made by :func:`resolve_design`; ``describe()`` gives a JSON-ready summary.

    Attributes:
        spec: the design spec as given (``hyperbolic:532nm``, a θ .npy, a preset .toml or a run
            directory).
        kind: "hyperbolic", "npy", "preset" or "run".
        lens: the :class:`~metalens_cli.optics.lens.Metalens`.
        focal_length_m: lens-to-sensor distance (m).
        preset: the preset in force, or None.
        lambda_d_m: design wavelength (m) of a hyperbolic lens, else None.
        efficiency: the nanofin efficiency η(λ) (``io.preset_spectra.FinEfficiency``) a design without
            a preset is imaged with; None: η = 1.
    """

    spec: str
    kind: str  # "hyperbolic", "npy", "preset" or "run"
    lens: object  # metalens_cli.optics.lens.Metalens (torch is imported only when resolving)
    focal_length_m: float
    preset: Preset | None
    lambda_d_m: float | None = None
    efficiency: object = None  # io.preset_spectra.FinEfficiency a design without a preset is imaged with (None: η = 1)

    def describe(self) -> dict:
        """JSON-ready summary for file headers and reports."""
        return {
            "spec": self.spec,
            "kind": self.kind,
            "radial": bool(self.lens.radial),
            "lambda_d_m": self.lambda_d_m,
            "f_m": self.focal_length_m,
            "aperture_m": self.lens.aperture_m,
            "pitch_m": self.lens.pitch_m,
            "preset": None if self.preset is None else self.preset.name,
        }


def _value(explicit, preset: Preset | None, getter, option: str, fallback=None):
    if explicit is not None:
        return explicit
    if preset is not None and getter(preset) is not None:
        return getter(preset)
    if fallback is not None:
        return fallback
    raise InputError(option, "missing for this design", f"{units.LENGTH_FORM}, or --preset FILE")


def _geometry(preset, f_m, aperture_m, pitch_m, default_pitch=None):
    return (
        _value(f_m, preset, lambda p: p.lens.focal_length_m, "--f"),
        _value(aperture_m, preset, lambda p: p.lens.aperture_m, "--aperture"),
        _value(pitch_m, preset, lambda p: p.nanofin.pitch_m, "--pitch", default_pitch),
    )


def _load_theta(path: Path):
    import numpy as np

    theta = read_npy(path, "--design", "a float .npy array of angles in radians")
    if not np.all(np.isfinite(theta)):
        raise InputError("--design", f"{path.name} holds NaN or infinite angles", "finite angles in radians")
    return theta


def _hyperbolic_preset_design(
    spec: str, kind: str, preset: Preset, explicit: Preset | None, f_m, aperture_m, pitch_m, radial
):
    from metalens_cli.optics.lens import hyperbolic

    if preset.lens.design != "hyperbolic":
        raise InputError(
            "--design",
            f"preset {preset.name} describes a learned lens with no θ",
            "its run directory from metalens optimize, or a θ .npy",
        )
    in_force = explicit or preset
    f, aperture, pitch = _geometry(in_force, f_m, aperture_m, pitch_m)
    lam = preset.lens.design_wavelength_m
    return Design(spec, kind, hyperbolic(lam, f, aperture, pitch, radial=radial), f, in_force, lam)


def resolve_design(
    spec: str,
    preset: Preset | None = None,
    *,
    f_m: float | None = None,
    aperture_m: float | None = None,
    pitch_m: float | None = None,
    radial: bool = True,
) -> Design:
    """Turn a design spec into a :class:`Design`; ``preset`` is the one given with --preset.

    The lens geometry is taken from the explicit arguments, else from the preset in force (for a
    run directory: ``preset`` or else the run's own; for a preset .toml: ``preset`` or else that
    one), else (the pitch of ``hyperbolic:``) the paper's pitch.

    Args:
        spec: ``hyperbolic:WAVELENGTH`` (e.g. ``hyperbolic:532nm``), a θ .npy file (rad), a preset
            .toml of a hyperbolic lens or a run directory (``preset.toml`` and ``theta.npy``).
        preset: the preset given with --preset, or None.
        f_m: focal length, the lens-to-sensor distance (m); None: the preset's.
        aperture_m: pupil diameter (m); None: the preset's.
        pitch_m: meta-atom pitch (m); None: the preset's.
        radial: the radial profile for hyperbolic lenses (False: the 2-D map).

    Returns:
        The :class:`Design`.

    Raises:
        InputError: naming ``--design`` (or the missing option: ``--f``, ``--aperture``,
            ``--pitch``).
    """
    text = arguments.path(spec, "--design", SPEC_FORM).strip()
    if text.startswith("hyperbolic:"):
        from metalens_cli.optics.lens import hyperbolic

        lam = units.parse_length(text.split(":", 1)[1], "--design")
        check_wavelengths([lam], "--design")
        f, aperture, pitch = _geometry(preset, f_m, aperture_m, pitch_m, PAPER_PITCH_M)
        return Design(text, "hyperbolic", hyperbolic(lam, f, aperture, pitch, radial=radial), f, preset, lam)
    path = Path(text)
    if path.is_dir():
        run_preset, theta_path = path / "preset.toml", path / "theta.npy"
        if not (run_preset.is_file() and theta_path.is_file()):
            raise InputError(
                "--design", f"{text!r} is not a run directory (needs preset.toml and theta.npy)", SPEC_FORM
            )
        carried = load_preset(run_preset)
        in_force = preset or carried
        return _array_design(text, "run", theta_path, in_force, f_m, aperture_m, pitch_m)
    if not path.exists():
        raise InputError("--design", f"{text!r} is neither a known design nor an existing file", SPEC_FORM)
    if path.suffix == ".npy":
        return _array_design(text, "npy", path, preset, f_m, aperture_m, pitch_m)
    if path.suffix == ".toml":
        return _hyperbolic_preset_design(text, "preset", load_preset(path), preset, f_m, aperture_m, pitch_m, radial)
    raise InputError("--design", f"{text!r} has an unknown kind", SPEC_FORM)


def _array_design(spec: str, kind: str, path: Path, preset, f_m, aperture_m, pitch_m) -> Design:
    from metalens_cli.optics.lens import from_array

    f, aperture, pitch = _geometry(preset, f_m, aperture_m, pitch_m)
    lens = from_array(_load_theta(path), pitch, aperture, focal_length_m=f)
    return Design(spec, kind, lens, f, preset)
