"""What a broadband baseline can be held to (issue 54, item 5; docs/training.md, "What no phase
design can do").

A geometric-phase lens cannot raise its band-integrated far core energy by more than ~1.2×: it can
only move sharpness between wavelengths and colours. So a broadband baseline is judged by

- spectral coverage: the far (source at infinity) central 5 × 5-pixel energy E(λ), a fraction of
  the power through the aperture, is ≥ 0.02 at ≥ 80 % of 430-650 nm sampled every 1 nm;
- band mean: the mean of E(λ) over those 221 wavelengths is ≥ 0.85 × the hyperbolic lens's
  (λd = 532 nm; the same distance, aperture and meta-atom pitch);
- colour balance: the smallest channel's MTF at 10 lp/mm is ≥ 0.05 (far channel PSFs: the
  camera's spectral sensitivity S^c over its whole grid, pixel aperture included);
- recoverable quality: the oracle Wiener or the Recon PSNR is ≥ the hyperbolic lens's, paired
  95 % CI above 0. It comes from ``metalens evaluate``, not from PSFs: the caller fills it
  (:meth:`BroadbandCriteria.with_recoverable`); until then it is not judged (None).

Wavelengths and lengths in SI metres. Sample at 1 nm: a 5-nm grid moves a peaked lens's mean by
several per cent either way, depending on where its peak falls (the hyperbolic lens: 0.0398 at
5 nm against 0.0381 at 1 nm; tests/optics/test_spectral_invariant.py).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from metalens_cli.analysis.mtf import mtf_at, psf_mtf, radial_grid
from metalens_cli.analysis.psf_metrics import central_energy
from metalens_cli.errors import InputError
from metalens_cli.optics.spectra import CHANNELS, SpectralSensitivity, quadrature_weights, wavelength_grid

BAND_M = (430e-9, 650e-9)
STEP_M = 1e-9
CORE_WINDOW = 5  # pixels, as L_sharp
COVERAGE_LEVEL = 0.02  # far core energy a wavelength needs to count as covered
COVERAGE_SHARE = 0.80  # of the band's wavelengths
MEAN_RATIO = 0.85  # of the hyperbolic lens's band mean
BALANCE_LPMM = 10.0
BALANCE_LEVEL = 0.05
REFERENCE_WAVELENGTH_M = 532e-9  # the hyperbolic baseline's design wavelength
CAPACITY = 1535  # largest far channel window looked for (pixels; learned lenses need up to ~1300)


@dataclass(frozen=True)
class Criterion:
    """One criterion: its value, the threshold it is held to, the verdict (value ≥ threshold; for
    the recoverable quality, CI lower bound > 0; None: not judged) and what the value is."""

    name: str
    value: float | None
    threshold: float
    passed: bool | None
    meaning: str


@dataclass(frozen=True)
class FarSpectrum:
    """What the criteria read from a lens's far PSFs.

    ``wavelengths_m`` (W,) the band's 1-nm grid; ``core`` (W,) the central 5 × 5 energy at each,
    fractions of the aperture power; ``channel_mtf`` (3,) R, G, B MTF at ``BALANCE_LPMM`` of the
    far channel PSFs; ``channel_held`` (3,) their light inside the window, fractions of the
    aperture power; ``channel_coverage`` (3,) the share of each channel's ∫S^c dλ the PSF
    wavelengths represent (below 1 when PSFs were given over part of the camera's range)."""

    wavelengths_m: np.ndarray
    core: np.ndarray
    channel_mtf: np.ndarray
    channel_held: np.ndarray
    channel_coverage: np.ndarray

    @property
    def band_mean(self) -> float:
        """Mean of the core energy over the band's wavelengths."""
        return float(np.mean(self.core))


@dataclass(frozen=True)
class BroadbandCriteria:
    """The four criteria of a design against the hyperbolic lens (module docstring)."""

    coverage: Criterion
    band_mean: Criterion
    colour_balance: Criterion
    recoverable: Criterion
    spectrum: FarSpectrum
    reference_band_mean: float

    @property
    def criteria(self) -> tuple[Criterion, ...]:
        """Coverage, band mean, colour balance, recoverable quality."""
        return (self.coverage, self.band_mean, self.colour_balance, self.recoverable)

    @property
    def passed(self) -> bool | None:
        """False if any criterion fails, None while one is not judged, else True."""
        verdicts = [c.passed for c in self.criteria]
        return False if False in verdicts else None if None in verdicts else True

    def with_recoverable(self, rows: dict[str, tuple[float, float, float]]) -> BroadbandCriteria:
        """The recoverable-quality criterion filled from ``metalens evaluate``: ``rows`` maps a row
        ("wiener", "recon") to the paired PSNR difference design − hyperbolic (dB) and its CI
        (lo, hi). Met when some row's CI lies above 0; the value is the highest lower bound."""
        if not rows:
            raise InputError("recoverable", "no rows", 'e.g. {"wiener": (difference, lo, hi)} in dB')
        best = max(rows, key=lambda row: rows[row][1])
        lo = float(rows[best][1])
        text = "; ".join(f"{row} {d:+.2f} [{a:+.2f}, {b:+.2f}] dB" for row, (d, a, b) in rows.items())
        criterion = Criterion("recoverable", lo, 0.0, lo > 0, f"paired PSNR − hyperbolic, CI lower bound: {text}")
        return dataclasses.replace(self, recoverable=criterion)

    def report(self) -> dict:
        """JSON-ready: each criterion, the verdict, the spectrum's summary."""
        s = self.spectrum
        return {
            "criteria": [dataclasses.asdict(c) for c in self.criteria],
            "passed": self.passed,
            "band_m": [float(s.wavelengths_m[0]), float(s.wavelengths_m[-1])],
            "band_mean": s.band_mean,
            "reference_band_mean": self.reference_band_mean,
            "core_max": float(s.core.max()),
            "core_max_wavelength_m": float(s.wavelengths_m[int(np.argmax(s.core))]),
            "channel_mtf": dict(zip(CHANNELS, s.channel_mtf.tolist())),
            "channel_held": dict(zip(CHANNELS, s.channel_held.tolist())),
        }


def band_grid() -> np.ndarray:
    """430-650 nm every 1 nm (221 wavelengths, m)."""
    return wavelength_grid(*BAND_M, STEP_M)


def judge(spectrum: FarSpectrum, reference_band_mean: float) -> BroadbandCriteria:
    """Judge ``spectrum`` against the hyperbolic lens's band mean; recoverable quality left open."""
    share = float(np.mean(spectrum.core >= COVERAGE_LEVEL))
    ratio = spectrum.band_mean / reference_band_mean
    weakest = float(spectrum.channel_mtf.min())
    name = CHANNELS[int(np.argmin(spectrum.channel_mtf))]
    return BroadbandCriteria(
        Criterion(
            "coverage",
            share,
            COVERAGE_SHARE,
            share >= COVERAGE_SHARE,
            f"share of 430-650 nm (1 nm) with far 5 × 5 energy ≥ {COVERAGE_LEVEL}",
        ),
        Criterion(
            "band_mean",
            ratio,
            MEAN_RATIO,
            ratio >= MEAN_RATIO,
            f"far 5 × 5 band mean {spectrum.band_mean:.4f} over the hyperbolic lens's {reference_band_mean:.4f}",
        ),
        Criterion(
            "colour_balance",
            weakest,
            BALANCE_LEVEL,
            weakest >= BALANCE_LEVEL,
            f"smallest channel's far MTF at {BALANCE_LPMM:g} lp/mm ({name})",
        ),
        Criterion("recoverable", None, 0.0, None, "oracle Wiener or Recon PSNR − hyperbolic, CI lower bound (dB)"),
        spectrum,
        float(reference_band_mean),
    )


def channel_mtf(channel_psfs: np.ndarray, pixel_pitch_m: float, lpmm: float = BALANCE_LPMM) -> np.ndarray:
    """(3,) radially averaged MTF at ``lpmm`` of R, G, B PSFs (3, N, N), pixel aperture included.
    The PSFs are zero-padded to rings ≤ lpmm/16 apart (the same OTF, sampled finer): the linear
    interpolation between rings is then within ~1e-4 on a smooth curve."""
    psfs = np.asarray(channel_psfs, dtype=np.float64)
    n = psfs.shape[-1]
    if lpmm * 1e3 * pixel_pitch_m > 0.5:
        raise InputError("lpmm", f"{lpmm:g} lp/mm", f"a frequency below Nyquist, {0.5e-3 / pixel_pitch_m:.4g} lp/mm")
    pad = max(0, math.ceil(16 / (lpmm * 1e3 * pixel_pitch_m)) - n + 1) // 2
    psfs = np.pad(psfs, [(0, 0), (pad, pad), (pad, pad)])
    grid = radial_grid(psfs.shape[-1], pixel_pitch_m)
    return mtf_at(grid.frequencies_lpmm, psf_mtf(psfs, grid), [lpmm])[:, 0]


def spectrum_from_psfs(
    psfs: np.ndarray, wavelengths_m, pixel_pitch_m: float, sensitivity: SpectralSensitivity
) -> FarSpectrum:
    """:class:`FarSpectrum` from monochromatic far PSFs (W, N, N) at ``wavelengths_m`` (W,), axis at
    pixel (N//2, N//2), in fractions of the aperture power. They must include the band's 1-nm grid;
    the channels mix every given wavelength by ``sensitivity`` (its part outside them is lost:
    ``channel_coverage``); N must hold the channels' light (the MTF is of what the window holds)."""
    waves = np.asarray(wavelengths_m, dtype=float)
    psfs = np.asarray(psfs, dtype=np.float64)
    if psfs.ndim != 3 or psfs.shape[0] != waves.size:
        raise InputError("psfs", f"shape {psfs.shape} for {waves.size} wavelengths", "(W, N, N)")
    band = _band_indices(waves)
    weights = quadrature_weights(sensitivity, waves)
    channels = np.einsum("cw,wij->cij", weights.weights, psfs)
    return FarSpectrum(
        waves[band],
        central_energy(psfs[band], CORE_WINDOW),
        channel_mtf(channels, pixel_pitch_m),
        channels.sum(axis=(-2, -1)),
        weights.coverage,
    )


def far_spectrum(
    lens, distance_m: float, pixel_pitch_m: float, sensitivity: SpectralSensitivity, *, capacity: int = CAPACITY
) -> FarSpectrum:
    """:class:`FarSpectrum` of a lens (``optics.lens.Metalens``) at ``distance_m`` from the sensor:
    PSFs at every 1-nm wavelength of the band and of the sensitivity's grid range, channel PSFs in
    windows holding 99.9 % of their light (``optics.channel_psf``; up to ``capacity`` pixels).
    A 2-D map goes through the 2-D angular spectrum at every wavelength, far slower than a radial
    lens's Hankel path."""
    from metalens_cli.optics.channel_psf import channel_psf_stack

    grid = sensitivity.wavelengths_m
    waves = wavelength_grid(min(grid[0], BAND_M[0]), max(grid[-1], BAND_M[1]), STEP_M)
    weights = quadrature_weights(sensitivity, waves)
    stack = channel_psf_stack(
        lens, waves, [math.inf], weights.weights, capacity, pixel_pitch_m, distance_m, core_window=CORE_WINDOW
    )
    if stack.outgrown.any():
        raise InputError("capacity", f"the far channel light passes {capacity} pixels", "a larger capacity")
    band = _band_indices(waves)
    channels = stack.psfs[0].detach().double().cpu().numpy()
    return FarSpectrum(
        waves[band],
        stack.cores[0].detach().double().cpu().numpy()[band],
        channel_mtf(channels, pixel_pitch_m),
        stack.kept[0],
        weights.coverage,
    )


def reference_lens(lens, distance_m: float):
    """The hyperbolic lens (λd = 532 nm, radial) of ``lens``'s aperture and pitch, focused at
    ``distance_m``: what the band mean is compared with."""
    from metalens_cli.optics.lens import hyperbolic

    return hyperbolic(REFERENCE_WAVELENGTH_M, distance_m, lens.aperture_m, lens.pitch_m)


def lens_criteria(
    lens,
    distance_m: float,
    pixel_pitch_m: float,
    sensitivity: SpectralSensitivity,
    *,
    reference_band_mean: float | None = None,
    capacity: int = CAPACITY,
) -> BroadbandCriteria:
    """The criteria of a lens at ``distance_m`` for a camera of this pixel pitch and spectral
    sensitivity; the hyperbolic reference is computed alike unless its band mean is given (to
    share it between designs)."""
    spectrum = far_spectrum(lens, distance_m, pixel_pitch_m, sensitivity, capacity=capacity)
    if reference_band_mean is None:
        reference = far_spectrum(
            reference_lens(lens, distance_m), distance_m, pixel_pitch_m, sensitivity, capacity=capacity
        )
        reference_band_mean = reference.band_mean
    return judge(spectrum, reference_band_mean)


def design_criteria(design, camera=None, *, reference_band_mean: float | None = None) -> BroadbandCriteria:
    """:func:`lens_criteria` of an ``io.designs.Design`` at its focal length, with the camera of the
    preset ``camera`` (default: the design's own): its pixel pitch and the spectral sensitivity
    (camera response × filter × η) over its sensor's wavelength range, every 1 nm."""
    from metalens_cli.io.preset_spectra import preset_sensitivity

    preset = camera or design.preset
    if preset is None:
        raise InputError("camera", f"{design.spec} carries no preset", "a preset naming the camera")
    sensitivity = preset_sensitivity(preset, wavelength_grid(*preset.sensor.wavelength_range_m, STEP_M))
    return lens_criteria(
        design.lens,
        design.focal_length_m,
        preset.sensor.pixel_pitch_m,
        sensitivity,
        reference_band_mean=reference_band_mean,
    )


def _band_indices(waves: np.ndarray) -> np.ndarray:
    """Indices of the band's 1-nm grid in ``waves`` (m); refuses a grid that lacks one of them."""
    band = band_grid()
    index = np.argmin(np.abs(waves[None, :] - band[:, None]), axis=1)
    if not np.allclose(waves[index], band, rtol=0, atol=1e-12):
        raise InputError("wavelengths", "the PSFs miss part of 430-650 nm at 1 nm", "every 1-nm wavelength of it")
    return index
