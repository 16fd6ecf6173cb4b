"""One camera for every design in a table: its light, its noise, the nanofins' efficiency and the
zero-order light.

- **Light level** L (electrons): what a full-scale white pixel collects in the exposure through an
  ideal lens (η = 1) with no filter: the full well of the unfiltered ideal camera. Polarisers in
  front of and behind the lens (the paper's setup) cost every design the same and are inside L.
- **Budget of a design's channel c**: its focused light at full scale holds L·t_c electrons,
  t_c = ∫CRF_c·T·η dλ / ∫CRF_c dλ: the filter T and the conversion η both cost light, counted
  before each design's filter. Noise-free, t_c is invisible (the channel PSFs are normalised).
- **Zero-order light**: the unconverted 1 − η, passed by the analyzer with ``leak``, adds
  ζ_c = leak·∫CRF_c·T·(1 − η) dλ / ∫CRF_c·T·η dλ of the focused signal, unfocused
  (``optics.zero_order``; formed by ``imaging.formation.zero_order_light``).
- **Noise**: shot noise of the electrons collected (Gaussian approximation of Poisson, as
  ``imaging.formation.add_noise``) and read noise of ``read_electrons`` rms.

Integrals run over 380-780 nm at 1 nm. Arrays indexed R, G, B.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metalens_cli.constants import DEFAULT_READ_ELECTRONS, DEFAULT_ZERO_ORDER_LEAK


@dataclass(frozen=True)
class Camera:
    """The camera of a table: ``light`` (electrons at full scale before the filter; None: no
    noise), ``read_electrons`` rms and the analyzer's ``zero_order_leak`` in 0..1."""

    light: float | None = None
    read_electrons: float = DEFAULT_READ_ELECTRONS
    zero_order_leak: float = DEFAULT_ZERO_ORDER_LEAK

    def label(self) -> str:
        """How tables name this camera's light: "noise-free" or e.g. "2000 e⁻"."""
        return "noise-free" if self.light is None else f"{self.light:g} e⁻"


@dataclass(frozen=True)
class ChannelBudget:
    """Per channel R, G, B: ``throughput`` t_c and ``zero_order`` ζ_c (module docstring)."""

    throughput: np.ndarray
    zero_order: np.ndarray


def design_factors(design, wavelengths_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(CRF (3, L), T (L,), η (L,)) of a design on ``wavelengths_m``: its preset's, or the default
    camera with no filter and the design's ``efficiency`` (η = 1 without one)."""
    from metalens_cli.io.preset_spectra import camera_factors
    from metalens_cli.optics.spectra import camera_response

    if design.preset is not None:
        return camera_factors(design.preset, wavelengths_m)
    eta = np.ones(wavelengths_m.size) if design.efficiency is None else design.efficiency.at(wavelengths_m)
    return camera_response(wavelengths_m), np.ones(wavelengths_m.size), eta


def channel_budget(design, zero_order_leak: float = DEFAULT_ZERO_ORDER_LEAK) -> ChannelBudget:
    """t_c and ζ_c of ``design`` (module docstring)."""
    from metalens_cli.optics.spectra import wavelength_grid

    return _budget(*design_factors(design, wavelength_grid()), zero_order_leak)


def preset_budget(preset, zero_order_leak: float = DEFAULT_ZERO_ORDER_LEAK) -> ChannelBudget:
    """t_c and ζ_c of a preset's camera, lens-independent (module docstring): what ``optimize``
    trains under with ``[optimize] light``, as ``evaluate --light`` images the preset's design."""
    from metalens_cli.io.preset_spectra import camera_factors
    from metalens_cli.optics.spectra import wavelength_grid

    return _budget(*camera_factors(preset, wavelength_grid()), zero_order_leak)


def efficiency_share(preset) -> np.ndarray:
    """(3,) ∫CRF_c·η dλ / ∫CRF_c dλ: t_c of the preset's camera without its filter (the nanofins'
    share of each channel's light; times a filter's share of the rest, g_c, it gives t_c)."""
    import dataclasses

    return preset_budget(dataclasses.replace(preset, filter=None), 0.0).throughput


def _budget(crf: np.ndarray, transmission: np.ndarray, eta: np.ndarray, zero_order_leak: float) -> ChannelBudget:
    """t_c and ζ_c from the camera response (3, L), filter (L,) and η (L,) on a uniform grid."""
    from metalens_cli.errors import InputError

    if not 0 <= zero_order_leak <= 1:
        raise InputError("--zero-order-leak", repr(zero_order_leak), "a fraction in 0..1")
    bare = crf.sum(axis=1)
    focused = (crf * transmission * eta).sum(axis=1)
    unconverted = (crf * transmission * (1 - eta)).sum(axis=1)
    return ChannelBudget(focused / bare, zero_order_leak * unconverted / focused)


def electrons(budget: ChannelBudget, camera: Camera) -> np.ndarray | None:
    """(3,) electrons a full-scale capture value of each channel stands for (None: noise-free)."""
    return None if camera.light is None else camera.light * budget.throughput


def efficiency_sources(designs) -> tuple[object, list[str], list[str]]:
    """The η every design of a table is imaged with: designs without a preset take the η of the
    first design that has one (the same fin for every design; a note says so); presets whose η
    differ are named in a warning. Returns (the shared ``FinEfficiency`` or None, warnings, notes)."""
    from metalens_cli.io.preset_spectra import preset_efficiency

    sources = {}
    for design in designs:
        if design.preset is not None:
            efficiency = preset_efficiency(design.preset.nanofin, design.preset.sensor.wavelength_range_m)
            sources[design.spec] = efficiency
    if not sources:
        return None, [], []
    first_spec, first = next(iter(sources.items()))
    probe = np.linspace(430e-9, 650e-9, 221)
    warnings = [
        f"{spec} is imaged with another nanofin efficiency than {first_spec} (η differs by up to "
        f"{np.abs(e.at(probe) - first.at(probe)).max():.3f} over 430-650 nm): the table compares fins as well as "
        "phase profiles"
        for spec, e in sources.items()
        if np.abs(e.at(probe) - first.at(probe)).max() > 1e-6
    ]
    bare = [d.spec for d in designs if d.preset is None]
    notes = [f"{', '.join(bare)}: no preset; imaged with the nanofin efficiency of {first_spec}"] if bare else []
    return first, warnings, notes
