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

Speed: ``scipy.fft.rfft2`` (float32 in, complex64 out, all cores) and one precomputed sparse
ring operator (timings: docs/benchmarks.md, ``benchmarks/bench_mtf.py``).

Over the field (a field cube, ``io.exr``). For a field at azimuth ψ (counter-clockwise from the
sensor's +x axis; x = column, y = row) the tangential (meridional) MTF is |OTF| along ν·(cos ψ,
sin ψ), the radial direction of the sensor through the chief ray, and the sagittal MTF along
ν·(−sin ψ, cos ψ), at ν = k·Δν, k = 0 … N//2: the radial curves' axis. Each point is the 2-D DFT
of the PSF evaluated exactly there (:func:`line_mtf`: two matrix products, no interpolation of
the FFT grid); along an axis of the pixel grid this is the DFT of the line spread function (for
ψ = 0, tangential: the PSF summed over rows; sagittal: over columns). The pixel aperture is
handled as in the radial curves (divided out, sample by sample, with ``remove_pixel_mtf``); the
radial curves of a field cube are those of field 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from metalens_cli import arguments
from metalens_cli.errors import InputError
from metalens_cli.io.exr import PsfCube

RGB_NAMES = ("R", "G", "B")
MTF50_LEVEL = 0.5
PER_MM = 1e-3  # cycles per metre → line pairs per mm
DIRECTIONS = ("tangential", "sagittal")
LINE_DFT_CHUNK = 2**23  # line_mtf's intermediate products hold at most this many values per step


GRID_BYTES = 80  # per rfft sample of radial_grid: radii, ring indices, weights, the pixel MTF, the operator's entries


@dataclass(frozen=True)
class RadialGrid:
    """Ring averaging of the ``rfft2`` half-plane of N × N images of pitch ``pixel_pitch_m``.

    Built by :func:`radial_grid`; K = N//2 + 1 rings at k·Δν, Δν = 1/(N·p) (``rings``,
    ``frequencies_lpmm``, ``nyquist_lpmm``; ``average`` applies the operator).

    Attributes:
        n: image side N (pixels).
        pixel_pitch_m: pixel pitch p (m).
        operator: sparse (K, N·(N//2+1)) matrix taking half-plane samples to the ring averages
            at k·Δν (binning, mirror weights and the interpolation from the rings' mean radii in one).
        radius_per_m: (N, N//2+1) |ν| in cycles/m at each half-plane sample.
        pixel_mtf_2d: (N, N//2+1) the pixel-aperture MTF |sinc(νx·p)·sinc(νy·p)| at each half-plane
            sample.
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

    Args:
        n: image side N (pixels), ≥ 2.
        pixel_pitch_m: pixel pitch p (m).

    Returns:
        The :class:`RadialGrid`: K = N//2 + 1 rings at k/(N·p), k = 0 … N//2.

    Examples:
        >>> grid = radial_grid(8, 2e-6)
        >>> grid.rings, grid.frequencies_lpmm.tolist(), grid.nyquist_lpmm
        (5, [0.0, 62.5, 125.0, 187.5, 250.0], 250.0)
    """
    from scipy import sparse

    arguments.count(n, "n", lo=2)
    arguments.positive(pixel_pitch_m, "pixel_pitch_m")
    arguments.fits_in_memory(GRID_BYTES * n * (n // 2 + 1), "n", f"the ring averaging of {n} × {n} images")
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
    (the PSF's sum), so the PSFs' scale does not matter.

    Args:
        psf: PSFs, finite, pixel intensities of pitch ``grid.pixel_pitch_m``, the axis at pixel
            (N//2, N//2) (any position: the modulus does not depend on it).
        grid: the ring averaging of N × N images (:func:`radial_grid`).
        remove_pixel_mtf: divide each 2-D OTF sample by the pixel-aperture MTF before averaging.
        field: the name errors give the PSFs.

    Returns:
        The MTF at the ring frequencies k·Δν (``grid.frequencies_lpmm``), float32 for float32 PSFs.

    Raises:
        InputError: naming ``field`` and the index of a PSF whose sum is not positive, or PSFs not
            N × N.

    Shape:
        - Input: :math:`(..., N, N)`
        - Output: :math:`(..., K)`, K = N//2 + 1.

    Examples:
        >>> import numpy as np
        >>> psf = np.zeros((8, 8))
        >>> psf[4, 4] = 2.0  # a point: flat MTF
        >>> psf_mtf(psf, radial_grid(8, 2e-6)).round(6).tolist()
        [1.0, 1.0, 1.0, 1.0, 1.0]
    """
    from scipy import fft  # several times faster than numpy.fft here, and multi-threaded

    psf = _psfs(psf, grid, field)
    if psf.shape[-2:] != (grid.n, grid.n):
        raise InputError(field, f"PSFs of shape {psf.shape[-2:]}", f"{grid.n} × {grid.n} pixels")
    otf = fft.rfft2(psf, workers=-1)
    dc = otf[..., 0, 0].real
    _check_power(dc, field)
    reweight = 1.0 / grid.pixel_mtf_2d if remove_pixel_mtf else None
    return grid.average(np.abs(otf), reweight) / dc[..., None]


def _psfs(psf, grid, field: str) -> np.ndarray:
    """PSFs (..., N, N) of finite values as a numpy array, and a :class:`RadialGrid`."""
    arguments.instance(grid, "grid", RadialGrid, "a RadialGrid (ml.radial_grid)")
    return np.asarray(arguments.array(psf, field, ndim=tuple(range(2, 9)), form="PSFs (..., N, N)"))


def _check_power(dc: np.ndarray, field: str) -> None:
    """Refuse PSFs whose sums ``dc`` (their OTFs at zero frequency) are not positive."""
    if np.any(dc <= 0):
        index = np.unravel_index(int(np.argmin(dc)), dc.shape)
        raise InputError(
            field,
            f"PSF at index {tuple(int(i) for i in index)} has no power (sum {float(dc[index]):.3g})",
            "PSFs with a positive sum",
        )


def line_mtf(
    psf: np.ndarray, grid: RadialGrid, angle_rad: float, *, remove_pixel_mtf: bool = False, field: str = "psf"
) -> np.ndarray:
    """MTF of PSFs along one direction of frequency: a tangential or sagittal curve.

    |Σ P[i, j]·exp(−2πi(νx·j + νy·i))| at exactly the points ν·(cos θ, sin θ), over the PSF's sum
    (1 at ν = 0; a PSF whose sum is not positive is refused as by :func:`psf_mtf`); with
    ``remove_pixel_mtf`` each point is divided by the pixel MTF |sinc(νx·p)·sinc(νy·p)| there
    (≥ 4/π² up to Nyquist). float32 PSFs give float32 curves, computed in float32 (as the radial
    ones).

    Args:
        psf: PSFs, finite, pixel intensities on ``grid``'s pitch.
        grid: the N × N ring grid (:func:`radial_grid`), whose axis ν = k·Δν, k = 0 … N//2, is used.
        angle_rad: direction θ (rad) counter-clockwise from +x (x = column, y = row).
        remove_pixel_mtf: divide out the pixel-aperture MTF.
        field: the name errors give the PSFs.

    Returns:
        The MTF at ν = k·Δν along θ.

    Shape:
        - Input: :math:`(..., N, N)`
        - Output: :math:`(..., K)`, K = N//2 + 1.
    """
    psf = _psfs(psf, grid, field)
    arguments.number(angle_rad, "angle_rad", form="a direction (rad)")
    n = grid.n
    if psf.shape[-2:] != (n, n):
        raise InputError(field, f"PSFs of shape {psf.shape[-2:]}", f"{n} × {n} pixels")
    dtype = np.float64 if psf.dtype == np.float64 else np.float32
    flat = psf.reshape(-1, n, n).astype(dtype, copy=False)
    dc = flat.sum(axis=(-2, -1), dtype=np.float64)
    _check_power(dc.reshape(psf.shape[:-2]), field)
    nu = np.arange(grid.rings) / n  # cycles per pixel
    fx, fy = nu * math.cos(angle_rad), nu * math.sin(angle_rad)
    fx[np.abs(fx) < 1e-12], fy[np.abs(fy) < 1e-12] = 0.0, 0.0  # cos(π/2) = 6e-17: an axis is an axis
    modulus = np.abs(_line_dft(flat, fx, fy, dtype)) / dc[:, None]
    if remove_pixel_mtf:
        modulus = modulus / np.abs(np.sinc(fx) * np.sinc(fy))
    return modulus.astype(dtype).reshape(*psf.shape[:-2], grid.rings)


def _line_dft(flat: np.ndarray, fx: np.ndarray, fy: np.ndarray, dtype) -> np.ndarray:
    """(B, K) complex DFT of images (B, N, N) at the K points (fx, fy) cycles/pixel (fx along
    columns j, fy along rows i). Along an axis: the DFT of the line spread function; otherwise
    Σ_i e^{−2πi·fy·i} (Σ_j P[i, j]·e^{−2πi·fx·j}), in chunks of images."""
    n = flat.shape[-1]

    def phasors(frequencies):
        phase = 2 * np.pi * np.outer(np.arange(n), frequencies)  # (N, K), float64 before rounding
        return np.cos(phase).astype(dtype), np.sin(phase).astype(dtype)

    if not fy.any() or not fx.any():
        lsf = flat.sum(axis=1 if not fy.any() else 2)  # over rows: a function of x; over columns: of y
        cos, sin = phasors(fx if not fy.any() else fy)
        return lsf @ cos - 1j * (lsf @ sin)
    cos_x, sin_x = phasors(fx)
    cos_y, sin_y = phasors(fy)
    out = np.empty((flat.shape[0], fx.size), dtype=np.complex128)
    step = max(1, LINE_DFT_CHUNK // (n * fx.size))
    for start in range(0, flat.shape[0], step):
        rows = flat[start : start + step].reshape(-1, n)
        real = (rows @ cos_x).reshape(-1, n, fx.size)  # Σ_j P[i, j]·e^{−2πi·fx·j} = real + i·imag
        imag = -(rows @ sin_x).reshape(-1, n, fx.size)
        out[start : start + step] = (
            np.einsum("bik,ik->bk", real, cos_y)
            + np.einsum("bik,ik->bk", imag, sin_y)
            + 1j * (np.einsum("bik,ik->bk", imag, cos_y) - np.einsum("bik,ik->bk", real, sin_y))
        )
    return out


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
    """Ring averages of the diffraction MTF at NA and each wavelength, on ``grid``.

    The MTF of an aberration-free incoherent circular pupil, cutoff 2·NA/λ, evaluated on the 2-D
    half-plane samples and averaged with the same rings as a measured curve; not folded (no
    aliasing).

    Args:
        grid: the ring grid (:func:`radial_grid`).
        na: numerical aperture, in (0, 1).
        wavelengths_m: wavelengths (m).
        include_pixel: multiply by the 2-D pixel-aperture MTF sample by sample (what an
            aberration-free lens gives on these pixels, aliasing aside).

    Returns:
        The reference MTF at the ring frequencies k·Δν (1 at k = 0).

    Shape:
        - Output: :math:`(W, K)` for W wavelengths, K = ``grid.rings``.

    Examples:
        >>> grid = radial_grid(8, 2e-6)  # rings at 0, 62.5, 125, 187.5, 250 lp/mm
        >>> mtf = diffraction_limited_mtf(grid, 0.1, [500e-9, 600e-9], include_pixel=False)
        >>> mtf.shape, mtf[:, 0].round(6).tolist()
        ((2, 5), [1.0, 1.0])
        >>> bool(mtf[0, 2] > mtf[1, 2])  # a shorter wavelength has the higher cutoff
        True
    """
    from scipy import sparse

    arguments.instance(grid, "grid", RadialGrid, "a RadialGrid (ml.radial_grid)")
    arguments.number(na, "na", lo=0.0, hi=1.0, open_lo=True, open_hi=True, form="a numerical aperture in (0, 1)")
    wavelengths_m = arguments.lengths(wavelengths_m, "wavelengths_m")
    radii, which = np.unique(grid.radius_per_m.ravel(), return_inverse=True)
    # The same sum as grid.average(D(|ν|)·pixel), grouped by distinct radius (~4× fewer D values).
    weights = grid.pixel_mtf_2d.ravel() if include_pixel else np.ones(which.size)
    grouping = sparse.csr_matrix((weights, (np.arange(which.size), which)), shape=(which.size, radii.size))
    per_radius = grid.operator @ grouping  # (K, distinct radii)
    values = diffraction_mtf(radii[None, :], na, np.asarray(wavelengths_m, dtype=float)[:, None])
    return np.asarray((per_radius @ values.T).T)


def mtf50(frequencies: np.ndarray, mtf: np.ndarray, *, level: float = MTF50_LEVEL) -> np.ndarray:
    """The frequency where each curve first drops below ``level`` (MTF50 by default).

    Linearly interpolated between the samples on each side of the crossing.

    Args:
        frequencies: the curves' frequency axis (any unit; the result is in the same).
        mtf: MTF curves on ``frequencies``.
        level: the level, in (0, 1).

    Returns:
        The crossing frequency of each curve; NaN where it never drops below ``level`` (or is
        below it already at the first sample).

    Shape:
        - Input: ``frequencies`` :math:`(K,)`, ``mtf`` :math:`(..., K)`
        - Output: :math:`(...)`

    Examples:
        >>> import numpy as np
        >>> curves = np.array([[1.0, 0.8, 0.4, 0.1], [1.0, 0.9, 0.8, 0.7]])
        >>> mtf50(np.array([0.0, 10.0, 20.0, 30.0]), curves).tolist()
        [17.5, nan]
    """
    frequencies = np.asarray(arguments.array(frequencies, "frequencies", ndim=1, form="frequencies (K,)"))
    mtf = np.asarray(arguments.array(mtf, "mtf", form="MTF curves (..., K)"), dtype=float)
    if mtf.ndim < 1 or mtf.shape[-1] != frequencies.size:
        raise InputError("mtf", f"shape {mtf.shape} for {frequencies.size} frequencies", "curves (..., K)")
    arguments.number(level, "level", lo=0.0, hi=1.0, open_lo=True, open_hi=True, form="a level in (0, 1)")
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
    ``na`` (times the pixel MTF unless removed), None without an NA. ``field``: the tangential
    and sagittal MTFs of a field cube (whose radial curves are field 0's), None on axis.
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
    field: FieldMtf | None = None

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

    def _labels(self) -> list[tuple[str, object, int, int, bool]]:
        """(key, value, depth index, wavelength or channel index, is channel) of each curve, in
        the order of :meth:`curves`."""
        labels = [
            ("wavelength_m", float(w), i, j, False)
            for i in range(self.depths_m.size)
            for j, w in enumerate(self.wavelengths_m)
        ]
        if self.rgb_mtf is not None:
            labels += [
                ("channel", name, i, c, True) for i in range(self.depths_m.size) for c, name in enumerate(RGB_NAMES)
            ]
        return labels

    def field_records(self) -> list[dict]:
        """Per field of a field cube ([] on axis): ``field`` (index), ``angle_rad``, ``angle_deg``,
        ``chief_ray_m`` [x, y], ``window_centre_px`` [column, row] and ``mtf50_lpmm``: one record
        per curve (as :meth:`curves`: ``depth_m``, ``wavelength_m`` or ``channel``) with
        ``tangential`` and ``sagittal`` MTF50 in lp/mm (None where never below 0.5)."""
        if self.field is None:
            return []
        f = self.field
        records = []
        for k, angle in enumerate(f.angles_rad):
            mtf50_records = []
            for key, value, i, j, channel in self._labels():
                values = {direction: _optional(f.mtf50(direction, channel)[k, i, j]) for direction in DIRECTIONS}
                mtf50_records.append({"depth_m": float(self.depths_m[i]), key: value, **values})
            records.append(
                {
                    "field": k,
                    "angle_rad": float(angle),
                    "angle_deg": math.degrees(float(angle)),
                    "chief_ray_m": f.chief_ray_m[k].tolist(),
                    "window_centre_px": f.window_centre_px[k].tolist(),
                    "mtf50_lpmm": mtf50_records,
                }
            )
        return records

    def field_curves(self) -> list[dict]:
        """Every tangential and sagittal curve of a field cube ([] on axis), field-major, then as
        :meth:`curves`, tangential before sagittal: ``field``, ``angle_deg``, ``direction``,
        ``depth_m``, ``wavelength_m`` or ``channel``, ``mtf`` (array, on ``frequencies_lpmm``)."""
        if self.field is None:
            return []
        f = self.field
        return [
            {
                "field": k,
                "angle_deg": math.degrees(float(angle)),
                "direction": direction,
                "depth_m": float(self.depths_m[i]),
                key: value,
                "mtf": f.curve(direction, channel)[k, i, j],
            }
            for k, angle in enumerate(f.angles_rad)
            for key, value, i, j, channel in self._labels()
            for direction in DIRECTIONS
        ]


@dataclass(frozen=True)
class FieldMtf:
    """Tangential and sagittal MTFs over the field of a field cube, on ``CubeMtf``'s frequencies.

    ``angles_rad`` (F,) field angles; ``azimuth_rad`` ψ; ``chief_ray_m`` (F, 2) [x, y] metres;
    ``window_centre_px`` (F, 2) [column, row]. ``tangential`` and ``sagittal`` (F, D, W, K): |OTF|
    along ν·(cos ψ, sin ψ) and ν·(−sin ψ, cos ψ); ``*_mtf50_lpmm`` (F, D, W) (NaN: never below
    0.5); ``rgb_*`` the same for the R, G, B channel PSFs (F, D, 3, …), or None.
    """

    angles_rad: np.ndarray
    azimuth_rad: float
    chief_ray_m: np.ndarray
    window_centre_px: np.ndarray
    tangential: np.ndarray
    sagittal: np.ndarray
    tangential_mtf50_lpmm: np.ndarray
    sagittal_mtf50_lpmm: np.ndarray
    rgb_tangential: np.ndarray | None
    rgb_sagittal: np.ndarray | None
    rgb_tangential_mtf50_lpmm: np.ndarray | None
    rgb_sagittal_mtf50_lpmm: np.ndarray | None

    def curve(self, direction: str, channel: bool = False) -> np.ndarray:
        """The curves (F, D, W or 3, K) of ``direction`` ("tangential" or "sagittal")."""
        return getattr(self, f"{'rgb_' if channel else ''}{direction}")

    def mtf50(self, direction: str, channel: bool = False) -> np.ndarray:
        """The MTF50s (F, D, W or 3) in lp/mm of ``direction``."""
        return getattr(self, f"{'rgb_' if channel else ''}{direction}_mtf50_lpmm")


def field_mtf(cube, grid: RadialGrid, *, remove_pixel_mtf: bool = False) -> FieldMtf:
    """Tangential and sagittal MTFs (:func:`line_mtf`) of every PSF and channel PSF of a field
    cube (``io.exr.PsfCube``), at the azimuth ψ of its fields, and their MTF50s.

    Tangential: along ν·(cos ψ, sin ψ), the radial direction of the sensor through the chief ray;
    sagittal: along ν·(−sin ψ, cos ψ).

    Args:
        cube: a field cube (:func:`read_psf_cube`).
        grid: the ring grid of its N × N PSFs and pitch (:func:`radial_grid`).
        remove_pixel_mtf: divide out the pixel-aperture MTF.

    Returns:
        A ``FieldMtf``: field angles (rad), azimuth (rad), chief rays (m), window centres (px), the
        curves on ``grid.frequencies_lpmm`` and their MTF50s (lp/mm, NaN: never below 0.5).

    Shape:
        - Output: curves :math:`(F, D, W, K)` (channels :math:`(F, D, 3, K)`), MTF50s :math:`(F, D, W)`.
    """
    arguments.instance(cube, "cube", PsfCube, "a PsfCube (ml.read_psf_cube)")
    arguments.instance(grid, "grid", RadialGrid, "a RadialGrid (ml.radial_grid)")
    psi = cube.field_azimuth_rad
    freqs = grid.frequencies_lpmm
    curves = {}
    for key, stack, where in (
        ("", cube.psf_by_field, "psf (field, depth, wavelength)"),
        ("rgb_", cube.rgb_by_field, "rgb (field, depth, channel)"),
    ):
        for direction, angle in zip(DIRECTIONS, (psi, psi + math.pi / 2)):
            curve = (
                None if stack is None else line_mtf(stack, grid, angle, remove_pixel_mtf=remove_pixel_mtf, field=where)
            )
            curves[f"{key}{direction}"] = curve
            curves[f"{key}{direction}_mtf50_lpmm"] = None if curve is None else mtf50(freqs, curve)
    return FieldMtf(
        angles_rad=cube.field_angles_rad,
        azimuth_rad=psi,
        chief_ray_m=cube.chief_ray_m,
        window_centre_px=cube.window_centre_px,
        **curves,
    )


def _optional(value: float) -> float | None:
    """None for NaN (an MTF that never falls below the level), else the float."""
    return None if np.isnan(value) else float(value)


def _record(depth: float, key: str, value, mtf: np.ndarray, mtf50_value: float, at_values: np.ndarray) -> dict:
    record = {
        "depth_m": float(depth),
        key: value,
        "mtf": mtf.tolist(),
        "mtf50_lpmm": _optional(mtf50_value),
    }
    if at_values.size:
        record["mtf_at"] = at_values.tolist()
    return record


def cube_mtf(cube, *, at_lpmm=(), na: float | None = None, remove_pixel_mtf: bool = False) -> CubeMtf:
    """MTFs of every (depth, wavelength) PSF and every R, G, B channel PSF of a ``PsfCube``; of
    a field cube, the radial curves of field 0 and the tangential and sagittal ones of every field
    (:func:`field_mtf`).

    Args:
        cube: the PSF cube (:func:`read_psf_cube`).
        at_lpmm: frequencies (lp/mm, 0 … the last ring) at which to interpolate each curve.
        na: numerical aperture of the diffraction reference; overrides the cube's ``na``
            metadata; with neither, no diffraction reference.
        remove_pixel_mtf: divide out the pixel-aperture MTF.

    Returns:
        A ``CubeMtf``: frequencies (lp/mm), depths and wavelengths (m), the curves, MTF50s (lp/mm,
        NaN: never below 0.5), values at ``at_lpmm``, the pixel MTF, the diffraction reference and,
        for a field cube, the ``FieldMtf``.

    Shape:
        - Output: ``mtf`` :math:`(D, W, K)`, ``mtf50_lpmm`` :math:`(D, W)`, ``mtf_at`` :math:`(D, W, A)`,
          ``rgb_mtf`` :math:`(D, 3, K)`, ``diffraction`` :math:`(W, K)`.
    """
    arguments.instance(cube, "cube", PsfCube, "a PsfCube (ml.read_psf_cube)")
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
        field=field_mtf(cube, grid, remove_pixel_mtf=remove_pixel_mtf) if cube.is_field_cube else None,
    )


def _numerical_aperture(value) -> float | None:
    """The NA as a float (None stays None); anything but a number is refused."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError("na", f"{value!r}", "a numerical aperture in (0, 1)")
    return float(value)
