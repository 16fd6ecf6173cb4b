"""PSF-based MTF: radially averaged modulus of the OTF of sensor PSFs (Suppl. Note 13 of the paper).

Conventions. A PSF is an N × N array of intensities integrated over pixels of pitch p (metres),
optical axis at the centre of pixel (N//2, N//2) (``docs/formats.md``). Its OTF is the 2-D DFT
normalised at zero frequency. The modulus does not depend on where the axis sits (a circular
shift only changes the phase), so the DFT is taken without ``ifftshift``; the phase (PTF) is
not reported. The DFT grid has spacing Δν = 1/(N·p) and, on each axis, reaches the sampling
Nyquist 1/(2p).

Radial average. The real-input half-plane (``rfft2``) is binned in rings k = round(|ν|/Δν),
k = 0 … N//2; samples beyond that (the corners) are dropped. Each half-plane column stands for
itself and its mirror image, so columns 1 … (N−1)//2 count twice: the average equals the
full-plane ring average. The lattice points of a ring do not sit at k·Δν on average (up to
0.2·Δν off for k < 30, which biases a steep curve by a few 1e-3), so each ring average is
placed at its ring's mean |ν| and linearly interpolated back onto the axis k·Δν, k = 0 … N//2
(extrapolated from the last two rings where needed): 0 to Nyquist, exactly Nyquist for even N,
Δν/2 below it for odd N. This brings a sampled Gaussian within 2e-4 of its analytic MTF at
N = 256. The reference curves (pixel aperture, diffraction limit) are evaluated
on the same 2-D grid and averaged with the same rings, so they compare like with like with a
measured curve, binning bias of the first rings included.

Pixel aperture. A PSF integrated over square pixels carries the pixel MTF
|sinc(νx·p)·sinc(νy·p)| (not radially symmetric). It is included by default; with
``remove_pixel_mtf`` each 2-D OTF sample is divided by it before the radial average. No guard
is needed: its zeros lie at multiples of 1/p, and inside the rings kept (|ν| ≤ 1/(2p)) it is at
least sinc(1/2) = 2/π, so the division amplifies noise by at most π/2.

Aliasing. The DFT of a sampled PSF is the OTF folded at the sampling frequency 1/p; content
above Nyquist (e.g. a lens of NA 0.3 has a cutoff 2·NA/λ ≈ 4 × Nyquist at 1.85 µm) folds back
into the measured curve. The diffraction-limited reference is not folded: it is the analytic
MTF (times the pixel MTF unless removed), ring-averaged on the same grid.

Speed: ``scipy.fft.rfft2`` (float32 in, complex64 out, all cores; numpy.fft is ~4× slower here)
and one precomputed sparse ring operator: 88 PSFs of 512² in ~0.5 s on 2 cores.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metalens_cli.errors import InputError

RGB_NAMES = ("R", "G", "B")
MTF50_LEVEL = 0.5
PER_MM = 1e-3  # cycles per metre → line pairs per mm


@dataclass(frozen=True)
class RadialGrid:
    """Ring averaging of the ``rfft2`` half-plane of N × N images of pitch ``pixel_pitch_m``.

    ``operator``: sparse (K, N·(N//2+1)) matrix taking half-plane samples to the ring averages
    at k·Δν (binning, mirror weights and the interpolation from the rings' mean radii in one).
    ``radius_per_m`` and ``pixel_mtf_2d`` (N, N//2+1): |ν| in cycles/m and the pixel-aperture
    MTF at each half-plane sample.
    """

    n: int
    pixel_pitch_m: float
    operator: object
    radius_per_m: np.ndarray
    pixel_mtf_2d: np.ndarray

    @property
    def rings(self) -> int:
        """Number of rings K = N//2 + 1 (frequencies 0 … N//2 · Δν)."""
        return self.n // 2 + 1

    @property
    def frequencies_lpmm(self) -> np.ndarray:
        """(K,) ring frequencies k/(N·p) in line pairs per mm."""
        return np.arange(self.rings) / (self.n * self.pixel_pitch_m) * PER_MM

    @property
    def nyquist_lpmm(self) -> float:
        """Sampling Nyquist 1/(2p) in line pairs per mm."""
        return 1 / (2 * self.pixel_pitch_m) * PER_MM

    def average(self, values: np.ndarray, sample_weights: np.ndarray | None = None) -> np.ndarray:
        """Ring averages (..., K) at k·Δν of half-plane values (..., N, N//2+1), each sample
        optionally multiplied by ``sample_weights`` (N, N//2+1) first. One sparse product for
        all leading indices; float32 values give float32 averages."""
        values = np.asarray(values)
        lead = values.shape[:-2]
        operator = (
            self.operator if sample_weights is None else self.operator.multiply(sample_weights.reshape(1, -1)).tocsr()
        )
        flat = values.reshape(-1, values.shape[-2] * values.shape[-1])
        return np.asarray((operator.astype(values.dtype) @ flat.T).T).reshape(*lead, self.rings)


def radial_grid(n: int, pixel_pitch_m: float) -> RadialGrid:
    """The ring averaging of N × N images with pixel pitch ``pixel_pitch_m`` (metres).

    Sample weights: mirror multiplicity (1 for the νx = 0 column and, for even N, the νx = N/2
    column, else 2) over the ring's total, so a ring's weighted sum is its full-plane average.
    """
    from scipy import sparse

    if n < 2:
        raise InputError("psf", f"{n} × {n} pixels", "at least 2 × 2 pixels for an MTF")
    fy = np.fft.fftfreq(n)[:, None]  # cycles per pixel
    fx = np.fft.rfftfreq(n)[None, :]
    radius = np.hypot(fx, fy)
    rings = n // 2 + 1
    bins = np.rint(radius * n).astype(np.int64).ravel()
    multiplicity = np.full(radius.shape, 2.0)
    multiplicity[:, 0] = 1.0  # νx = 0 is its own mirror
    if n % 2 == 0:
        multiplicity[:, -1] = 1.0  # νx = Nyquist: only −N/2 exists in the full plane
    kept = np.flatnonzero(bins < rings)
    bins, multiplicity = bins[kept], multiplicity.ravel()[kept]
    weights = multiplicity / np.bincount(bins, weights=multiplicity, minlength=rings)[bins]
    centres = np.bincount(bins, weights=weights * radius.ravel()[kept] * n, minlength=rings)  # mean ring radius / Δν
    binning = sparse.csr_matrix((weights, (bins, kept)), shape=(rings, radius.size))
    nominal = np.arange(rings)
    lower = np.clip(
        np.searchsorted(centres, nominal, side="right") - 1, 0, rings - 2
    )  # no ring is empty: (k, 0) is in ring k
    upper = lower + 1
    fraction = (nominal - centres[lower]) / (centres[upper] - centres[lower])
    interpolation = sparse.csr_matrix(
        (np.r_[1 - fraction, fraction], (np.r_[nominal, nominal], np.r_[lower, upper])), shape=(rings, rings)
    )
    pixel = np.abs(np.sinc(fx) * np.sinc(fy))
    return RadialGrid(n, float(pixel_pitch_m), (interpolation @ binning).tocsr(), radius / pixel_pitch_m, pixel)


def psf_mtf(psf: np.ndarray, grid: RadialGrid, *, remove_pixel_mtf: bool = False, field: str = "psf") -> np.ndarray:
    """Radially averaged MTF (..., K) of PSFs (..., N, N) on ``grid``'s rings (1 at k = 0).

    One batched real FFT over all PSFs; each OTF is normalised by its zero-frequency value
    (the PSF's sum), so the PSFs' scale does not matter. A PSF whose sum is not positive is
    refused (InputError naming ``field`` and its index).
    """
    from scipy import fft  # several times faster than numpy.fft here, and multi-threaded

    psf = np.asarray(psf)
    if psf.shape[-2:] != (grid.n, grid.n):
        raise InputError(field, f"PSFs of shape {psf.shape[-2:]}", f"{grid.n} × {grid.n} pixels")
    otf = fft.rfft2(psf, workers=-1)
    dc = otf[..., 0, 0].real
    if np.any(dc <= 0):
        index = np.unravel_index(int(np.argmin(dc)), dc.shape)
        raise InputError(
            field,
            f"PSF at index {tuple(int(i) for i in index)} has no power (sum {float(dc[index]):.3g})",
            "PSFs with a positive sum",
        )
    reweight = 1.0 / grid.pixel_mtf_2d if remove_pixel_mtf else None
    return grid.average(np.abs(otf), reweight) / dc[..., None]


def pixel_aperture_mtf(grid: RadialGrid) -> np.ndarray:
    """(K,) ring average of the square-pixel MTF |sinc(νx·p)·sinc(νy·p)|."""
    return grid.average(grid.pixel_mtf_2d)


def diffraction_mtf(frequency_per_m: np.ndarray, na: float, wavelength_m: np.ndarray) -> np.ndarray:
    """MTF of an aberration-free incoherent circular pupil, broadcast over its arguments.

    With s = ν/νc and cutoff νc = 2·NA/λ: (2/π)·(arccos s − s·√(1 − s²)) for s ≤ 1, else 0.
    ``frequency_per_m`` in cycles per metre, ``wavelength_m`` in metres.
    """
    s = np.clip(np.asarray(frequency_per_m) * np.asarray(wavelength_m) / (2 * na), 0.0, 1.0)
    return 2 / np.pi * (np.arccos(s) - s * np.sqrt(1 - s * s))


def diffraction_limited_mtf(
    grid: RadialGrid, na: float, wavelengths_m: np.ndarray, *, include_pixel: bool = True
) -> np.ndarray:
    """(W, K) ring averages of the diffraction MTF at NA and each wavelength, on ``grid``.

    With ``include_pixel`` the 2-D pixel-aperture MTF multiplies it sample by sample (what an
    aberration-free lens gives on these pixels, aliasing aside).
    """
    from scipy import sparse

    if not 0 < na < 1:
        raise InputError("na", f"{na!r}", "a numerical aperture in (0, 1)")
    radii, which = np.unique(grid.radius_per_m.ravel(), return_inverse=True)
    # The same sum as grid.average(D(|ν|)·pixel), grouped by distinct radius (~4× fewer D values).
    weights = grid.pixel_mtf_2d.ravel() if include_pixel else np.ones(which.size)
    grouping = sparse.csr_matrix((weights, (np.arange(which.size), which)), shape=(which.size, radii.size))
    per_radius = grid.operator @ grouping  # (K, distinct radii)
    values = diffraction_mtf(radii[None, :], na, np.asarray(wavelengths_m, dtype=float)[:, None])
    return np.asarray((per_radius @ values.T).T)


def mtf50(frequencies: np.ndarray, mtf: np.ndarray, *, level: float = MTF50_LEVEL) -> np.ndarray:
    """(...,) frequency where each curve (..., K) first drops below ``level``, linearly
    interpolated between the samples on each side; NaN where it never does."""
    mtf = np.asarray(mtf, dtype=float)
    below = mtf < level
    first = np.argmax(below, axis=-1)
    found = below.any(axis=-1) & (first > 0)
    upper = np.maximum(first - 1, 0)
    f0, f1 = frequencies[upper], frequencies[first]
    m0 = np.take_along_axis(mtf, upper[..., None], -1)[..., 0]
    m1 = np.take_along_axis(mtf, first[..., None], -1)[..., 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        crossing = f0 + (m0 - level) / (m0 - m1) * (f1 - f0)
    return np.where(found, crossing, np.nan)


def mtf_at(frequencies: np.ndarray, mtf: np.ndarray, at: np.ndarray, field: str = "at") -> np.ndarray:
    """(..., A) curves (..., K) linearly interpolated at ``at`` (same unit as ``frequencies``)."""
    at = np.asarray(at, dtype=float)
    outside = at[(at < frequencies[0]) | (at > frequencies[-1])]
    if outside.size:
        raise InputError(
            field,
            f"{outside[0]:g} is outside the frequency axis",
            f"frequencies in {frequencies[0]:g}…{frequencies[-1]:.4g}",
        )
    k = np.clip(np.searchsorted(frequencies, at, side="right") - 1, 0, frequencies.size - 2)
    t = (at - frequencies[k]) / (frequencies[k + 1] - frequencies[k])
    return mtf[..., k] * (1 - t) + mtf[..., k + 1] * t


@dataclass(frozen=True)
class CubeMtf:
    """MTFs of a PSF cube. Frequencies in lp/mm; depths in metres (``inf`` at infinity).

    ``mtf`` (D, W, K), ``mtf50_lpmm`` (D, W) (NaN: never below 0.5), ``mtf_at`` (D, W, A) at
    ``at_lpmm`` (A,); ``rgb_*`` the same for the R, G, B channel PSFs (D, 3, …) or None.
    ``pixel_mtf`` (K,): the ring-averaged pixel-aperture MTF; ``pixel_mtf_removed``: whether it
    was divided out of the curves. ``diffraction`` (W, K): the diffraction-limited reference at
    ``na`` (times the pixel MTF unless removed), None without an NA.
    """

    frequencies_lpmm: np.ndarray
    nyquist_lpmm: float
    depths_m: np.ndarray
    wavelengths_m: np.ndarray
    mtf: np.ndarray
    mtf50_lpmm: np.ndarray
    rgb_mtf: np.ndarray | None
    rgb_mtf50_lpmm: np.ndarray | None
    at_lpmm: np.ndarray
    mtf_at: np.ndarray
    rgb_mtf_at: np.ndarray | None
    pixel_mtf: np.ndarray
    pixel_mtf_removed: bool
    na: float | None
    diffraction: np.ndarray | None

    def curves(self) -> list[dict]:
        """One record per curve: ``depth_m``, ``wavelength_m`` or ``channel``, ``mtf`` (list),
        ``mtf50_lpmm`` (None where never below 0.5) and, when ``at_lpmm`` is not empty, ``mtf_at``
        (list, one value per ``at_lpmm``).
        Monochromatic curves first (depth-major), then the channel curves."""
        records = []
        for i, depth in enumerate(self.depths_m):
            for j, wavelength in enumerate(self.wavelengths_m):
                records.append(
                    _record(
                        depth,
                        "wavelength_m",
                        float(wavelength),
                        self.mtf[i, j],
                        self.mtf50_lpmm[i, j],
                        self.mtf_at[i, j],
                    )
                )
        if self.rgb_mtf is not None:
            for i, depth in enumerate(self.depths_m):
                for c, name in enumerate(RGB_NAMES):
                    records.append(
                        _record(
                            depth, "channel", name, self.rgb_mtf[i, c], self.rgb_mtf50_lpmm[i, c], self.rgb_mtf_at[i, c]
                        )
                    )
        return records


def _record(depth: float, key: str, value, mtf: np.ndarray, mtf50_value: float, at_values: np.ndarray) -> dict:
    record = {
        "depth_m": float(depth),
        key: value,
        "mtf": mtf.tolist(),
        "mtf50_lpmm": None if np.isnan(mtf50_value) else float(mtf50_value),
    }
    if at_values.size:
        record["mtf_at"] = at_values.tolist()
    return record


def cube_mtf(cube, *, at_lpmm=(), na: float | None = None, remove_pixel_mtf: bool = False) -> CubeMtf:
    """MTFs of every (depth, wavelength) PSF and every R, G, B channel PSF of a ``PsfCube``.

    ``na`` overrides the cube's ``na`` metadata; with neither, no diffraction reference.
    ``at_lpmm``: frequencies (lp/mm, 0 … the last ring) at which to interpolate each curve.
    """
    grid = radial_grid(cube.psf.shape[-1], cube.pixel_pitch_m)
    freqs = grid.frequencies_lpmm
    at = np.asarray(at_lpmm, dtype=float)
    mtf = psf_mtf(cube.psf, grid, remove_pixel_mtf=remove_pixel_mtf, field="psf (depth index, wavelength index)")
    rgb = (
        None
        if cube.rgb is None
        else psf_mtf(cube.rgb, grid, remove_pixel_mtf=remove_pixel_mtf, field="rgb (depth index, channel index)")
    )
    na = _numerical_aperture(cube.metadata.get("na") if na is None else na)
    diffraction = (
        None
        if na is None
        else diffraction_limited_mtf(grid, na, cube.wavelengths_m, include_pixel=not remove_pixel_mtf)
    )
    return CubeMtf(
        frequencies_lpmm=freqs,
        nyquist_lpmm=grid.nyquist_lpmm,
        depths_m=cube.depths_m,
        wavelengths_m=cube.wavelengths_m,
        mtf=mtf,
        mtf50_lpmm=mtf50(freqs, mtf),
        rgb_mtf=rgb,
        rgb_mtf50_lpmm=None if rgb is None else mtf50(freqs, rgb),
        at_lpmm=at,
        mtf_at=mtf_at(freqs, mtf, at, "at (lp/mm)"),
        rgb_mtf_at=None if rgb is None else mtf_at(freqs, rgb, at, "at (lp/mm)"),
        pixel_mtf=pixel_aperture_mtf(grid),
        pixel_mtf_removed=remove_pixel_mtf,
        na=na,
        diffraction=diffraction,
    )


def _numerical_aperture(value) -> float | None:
    """The NA as a float (None stays None); anything but a number is refused."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError("na", f"{value!r}", "a numerical aperture in (0, 1)")
    return float(value)
