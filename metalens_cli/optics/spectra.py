"""Spectral sensitivity of the sensor's colour channels and wavelength sampling.

S^c(λ) = CRF^c(λ) · T_filter(λ) · η(λ) for the channels c in ``CHANNELS`` = ("R", "G", "B"):
every array of this module with a leading axis of length 3 is indexed R, G, B in that order.

- CRF^c: the camera's relative spectral response (colour-science's shipped data or a table).
- T_filter: the multi-band filter's transmission in 0..1 (smooth band model or a table).
- η: the meta-atoms' polarisation-conversion efficiency in 0..1 (a table).

Wavelengths are SI metres at every interface. This module reads no files: measured spectra
in CSV files are read by :mod:`metalens_cli.io.spectra_files`. S^c is tabulated on a wavelength grid and treated as
linear between grid points. colour-science (slow to import) and torch are imported only inside the functions that need
them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from metalens_cli import arguments
from metalens_cli.errors import InputError
from metalens_cli.optics.band_rules import CAMERA_NAMES, check_bands

CHANNELS = ("R", "G", "B")
DEFAULT_CAMERA = "Nikon 5100 (NPL)"
DEFAULT_EDGE_WIDTH_M = 2e-9
"""10-90 % rise distance of each filter band edge (typical of hard-coated interference filters)."""
WEIGHT_THRESHOLD = 1e-3  # a wavelength matters to a channel above this fraction of its peak weight

_NM = 1e-9


@dataclass(frozen=True)
class SpectralSensitivity:
    """S^c(λ) tabulated on a wavelength grid, linear between grid points.

    Made by :func:`spectral_sensitivity`; ``support()`` gives the range where a channel matters.

    Attributes:
        wavelengths_m: (L,) strictly increasing, metres.
        values: (3, L), channels R, G, B, non-negative, in arbitrary units (only the shape of each
            channel matters to sampling).
    """

    wavelengths_m: np.ndarray
    values: np.ndarray

    def support(self) -> list[float]:
        """[shortest, longest] wavelength (m) where a channel's S^c exceeds ``WEIGHT_THRESHOLD``
        of its own peak: the range whose rays PSF windows must hold."""
        inside = self.wavelengths_m[significant(self.values)]
        return [float(inside.min()), float(inside.max())]


def significant(values: np.ndarray) -> np.ndarray:
    """(L,) mask of the wavelengths where some channel of ``values`` (3, L) (a sensitivity or
    quadrature weights) exceeds ``WEIGHT_THRESHOLD`` of that channel's peak: the one rule for the
    filter's tails in training and evaluation."""
    values = np.asarray(values, dtype=float)
    return (values > WEIGHT_THRESHOLD * values.max(axis=1, keepdims=True)).any(axis=0)


@dataclass(frozen=True)
class ChannelWeights:
    """Monochromatic wavelengths and the weights that mix them into the three channels.

    ``wavelengths_m``: (W,) metres, the wavelengths at which to compute monochromatic PSFs.
    ``weights``: (3, W), channels R, G, B; each row sums to 1, so ``weights @ f(wavelengths_m)``
    estimates the S^c-weighted mean of f. Pass it to ``mix_channels``.
    ``coverage``: (3,), the fraction of each channel's ∫S^c dλ that the wavelengths represent
    (1 for importance samples; below 1 when a scan's range cuts off part of a channel).
    """

    wavelengths_m: np.ndarray
    weights: np.ndarray
    coverage: np.ndarray


def wavelength_grid(start_m: float = 380e-9, stop_m: float = 780e-9, step_m: float = 1e-9) -> np.ndarray:
    """Uniform grid from ``start_m`` to ``stop_m`` inclusive (metres), step rounded to fit exactly."""
    if not (0 < start_m < stop_m and step_m > 0):
        raise InputError("wavelengths", f"bad grid {start_m}:{stop_m}:{step_m}", "0 < start < stop, step > 0 (metres)")
    count = max(round((stop_m - start_m) / step_m), 1) + 1
    return np.linspace(start_m, stop_m, count)


# ---------------------------------------------------------------------------- camera response


def camera_response(wavelengths_m: np.ndarray, name: str = DEFAULT_CAMERA) -> np.ndarray:
    """CRF^c(λ) of a camera at ``wavelengths_m``, shape (3, L), channels R, G, B.

    Linear interpolation; zero outside the tabulated range (no measured response).
    colour-science is imported on the first call (slow).

    Args:
        wavelengths_m: wavelengths (m).
        name: one of ``CAMERA_NAMES`` (colour-science's ``MSDS_CAMERA_SENSITIVITIES``; a measured
            response in a CSV is read by :mod:`metalens_cli.io.spectra_files`).

    Returns:
        The relative response of each channel, each normalised to peak 1.

    Shape:
        - Input: :math:`(L,)`
        - Output: :math:`(3, L)`, channels R, G, B.
    """
    grid = arguments.array(wavelengths_m, "wavelengths_m", ndim=(0, 1), form="wavelengths (L,) in m")
    if name not in CAMERA_NAMES:
        raise InputError("name", f"unknown camera {str(name)!r}", f"one of {', '.join(CAMERA_NAMES)} or a CSV file")
    return tabulated_response(grid, *_colour_camera(name))


def tabulated_response(wavelengths_m: np.ndarray, table_nm: np.ndarray, table: np.ndarray) -> np.ndarray:
    """(C, L): each row of ``table`` (C, T), tabulated at ``table_nm`` (T,), interpolated
    linearly at ``wavelengths_m``, zero outside the table."""
    grid_nm = np.asarray(wavelengths_m, dtype=float) / _NM
    return np.stack([np.interp(grid_nm, table_nm, row, left=0.0, right=0.0) for row in table])


def _colour_camera(name: str) -> tuple[np.ndarray, np.ndarray]:
    """(wavelengths in nm, (3, L) responses R, G, B) from colour-science's shipped data."""
    import colour  # ~2-3 s: imported only when a named camera is asked for

    data = colour.MSDS_CAMERA_SENSITIVITIES[name]
    columns = [data.labels.index(label) for label in ("red", "green", "blue")]
    return np.asarray(data.wavelengths, dtype=float), np.asarray(data.values, dtype=float)[:, columns].T


# ---------------------------------------------------------------------------- filter


def bandpass_transmission(
    wavelengths_m,
    centres_m,
    widths_m,
    *,
    edge_width_m=DEFAULT_EDGE_WIDTH_M,
    peak=1.0,
):
    """Transmission of a multi-band filter with smooth edges, in 0..``peak``.

    Each band b is a product of two logistic edges σ(t) = 1 / (1 + e^(−t)),

        T_b(λ) = peak · σ((λ − c_b + h_b)/s) · σ((c_b + h_b − λ)/s) / σ(h_b/s)²,

    with s = edge_width_m / (2 ln 9), so each edge rises from 10 % to 90 % over
    ``edge_width_m``. The half-width h_b is solved in closed form so that T_b(c_b) = peak
    and T_b(c_b ± w_b/2) = peak/2 exactly: the FWHM is ``widths_m`` and the pass band is
    [c − w/2, c + w/2]. The filter is the sum of its bands, which must not overlap. A band
    narrower than 2·arccosh(3)·s ≈ 0.80 · edge_width_m cannot have that FWHM and is refused.

    With torch tensors for the centres (and widths, edge width), the same model in torch,
    differentiable in every parameter (a learned filter, ``design.filter_learning``); the bands
    are then not checked (the learning keeps them valid).

    Args:
        wavelengths_m: wavelengths λ (m) at which to evaluate.
        centres_m: band centres c_b (m).
        widths_m: band FWHMs w_b (m), one per centre.
        edge_width_m: 10-90 % rise distance of each edge (m).
        peak: the transmission at each centre, in (0, 1].

    Returns:
        T(λ) (numpy, or a torch tensor for tensor centres).

    Shape:
        - Input: ``wavelengths_m`` :math:`(L,)`, ``centres_m`` and ``widths_m`` :math:`(B,)`
        - Output: :math:`(L,)`

    Examples:
        >>> import numpy as np
        >>> t = bandpass_transmission(np.array([520e-9, 530e-9, 540e-9, 600e-9]), [530e-9], [20e-9])
        >>> t.round(6).tolist()  # half the peak at c ± w/2
        [0.5, 1.0, 0.5, 0.0]
    """
    if _is_tensor(centres_m):
        import torch

        grid = torch.as_tensor(wavelengths_m, dtype=centres_m.dtype, device=centres_m.device)
        return _bands(grid, centres_m, widths_m, edge_width_m, peak, torch)
    grid = np.asarray(arguments.array(wavelengths_m, "wavelengths_m", form="wavelengths in m"), dtype=float)
    centres = np.array(arguments.lengths(centres_m, "centres_m"))
    widths = np.array(arguments.lengths(widths_m, "widths_m"))
    arguments.positive(edge_width_m, "edge_width_m")
    arguments.number(peak, "peak", lo=0.0, hi=1.0, open_lo=True, form="a peak transmission in (0, 1]")
    arguments.fits_in_memory(
        BAND_BYTES * grid.size * centres.size, "wavelengths_m", f"{grid.size} wavelengths × {centres.size} bands"
    )
    check_bands(centres.tolist(), widths.tolist(), edge_width_m, peak)
    return _bands(grid, centres, widths, edge_width_m, peak, np)


BAND_BYTES = 48  # per (wavelength, band): the offsets and the three logistic factors, float64


def _is_tensor(value) -> bool:
    return type(value).__module__.startswith("torch")


def _bands(grid, centres, widths, edge_width, peak, xp):
    """Σ_b T_b(grid) for arrays of the namespace ``xp`` (numpy or torch), bands on the last axis."""
    scale = edge_width / (2.0 * math.log(9.0))
    x = _band_half_width(widths / (2.0 * scale), xp)
    offset = (grid[..., None] - centres) / scale
    return peak * (_logistic(offset + x, xp) * _logistic(x - offset, xp) / _logistic(x, xp) ** 2).sum(-1)


def _band_half_width(u, xp=np):
    """x = h/s such that σ(x + u)·σ(x − u) = σ(x)²/2, for u = w/(2s) ≥ arccosh 3.

    With a = e^(−x) the condition is a² + (4 − q)a + 1 = 0, q = 2 cosh u; the smaller root
    (the band whose edges sit near ±w/2) is a = 2 / ((q − 4) + √((q − 4)² − 4)). Written with
    q − 4 = e^u·(1 + e^(−2u) − 4e^(−u)) so that no term overflows for wide bands.
    """
    g = 1.0 + xp.exp(-2.0 * u) - 4.0 * xp.exp(-u)
    ratio = 4.0 * xp.exp(-2.0 * u) / g**2
    return u + xp.log(g) + xp.log((1.0 + xp.sqrt(xp.clip(1.0 - ratio, 0.0, None))) / 2.0)


def _logistic(t, xp=np):
    """σ(t) = 1/(1 + e^(−t)), written with tanh so that it never overflows."""
    return 0.5 * (1.0 + xp.tanh(0.5 * t))


# ---------------------------------------------------------------------------- efficiency


def efficiency_from_table(
    wavelengths_m: np.ndarray, table_wavelengths_m: np.ndarray, table_efficiencies: np.ndarray
) -> np.ndarray:
    """η(λ) (L,) by linear interpolation of a table, flat extrapolation beyond its ends.

    ``table_wavelengths_m`` strictly increasing (metres), ``table_efficiencies`` fractions in
    0..1 (the paper: 0.784, 0.729, 0.669 at 457, 530, 628 nm). One entry gives a constant.
    """
    table_wl = np.atleast_1d(np.asarray(table_wavelengths_m, dtype=float))
    table_eta = np.atleast_1d(np.asarray(table_efficiencies, dtype=float))
    if table_wl.shape != table_eta.shape or table_wl.ndim != 1 or table_wl.size == 0:
        raise InputError(
            "efficiency", "wavelength and efficiency lists differ in length", "one efficiency per wavelength"
        )
    if not (np.all(np.isfinite(table_wl)) and np.all(np.diff(table_wl) > 0)):
        raise InputError("efficiency", "table wavelengths are not strictly increasing", "increasing metres")
    if not (np.all(table_eta >= 0) and np.all(table_eta <= 1)):
        raise InputError("efficiency", "efficiencies outside 0..1", "fractions, e.g. 0.784 for 78.4 %")
    return np.interp(np.asarray(wavelengths_m, dtype=float), table_wl, table_eta)


# ---------------------------------------------------------------------------- assembly


def spectral_sensitivity(
    wavelengths_m: np.ndarray,
    crf: np.ndarray,
    transmission: np.ndarray | None = None,
    efficiency: np.ndarray | None = None,
) -> SpectralSensitivity:
    """S^c = CRF^c · T_filter · η on ``wavelengths_m`` (L,), metres.

    Args:
        wavelengths_m: (L,) at least 2 strictly increasing wavelengths (m).
        crf: (3, L) camera response, channels R, G, B (:func:`camera_response`).
        transmission: (L,) filter transmission in 0..1 (:func:`bandpass_transmission`), or None
            for 1 (no filter).
        efficiency: (L,) meta-atom conversion efficiency η in 0..1, or None for 1 (ideal
            conversion).

    Returns:
        The :class:`SpectralSensitivity`.

    Raises:
        InputError: a malformed input, or a channel with no sensitivity anywhere on the grid.
    """
    grid = np.asarray(
        arguments.array(wavelengths_m, "wavelengths_m", ndim=1, form="wavelengths (L,) in m"), dtype=float
    )
    if grid.size < 2 or not np.all(np.diff(grid) > 0):
        raise InputError("wavelengths", "the grid must hold at least 2 strictly increasing wavelengths", "metres")
    values = np.array(arguments.array(crf, "crf", form=f"(3, {grid.size}) responses R, G, B"), dtype=float)
    if values.shape != (3, grid.size):
        raise InputError("crf", f"response of shape {values.shape}", f"(3, {grid.size}), channels R, G, B")
    for name, factor in (("transmission", transmission), ("efficiency", efficiency)):
        if factor is not None:
            values = values * _on_grid(factor, grid.size, name)
    for name, row in zip(CHANNELS, values):
        if not _trapezoid(row, grid) > 0:
            raise InputError(
                "spectra",
                f"channel {name} has no sensitivity on the grid",
                "a filter band inside the camera's response",
            )
    return SpectralSensitivity(grid, values)


def _on_grid(factor: np.ndarray, size: int, name: str) -> np.ndarray:
    """Check one (L,) factor of S, ``name``: finite, shape and range 0..1."""
    factor = np.asarray(arguments.array(factor, name, form=f"({size},) fractions in 0..1"), dtype=float)
    if factor.shape != (size,) or not (np.all(factor >= 0) and np.all(factor <= 1)):
        raise InputError(name, "is malformed", f"shape ({size},), values in 0..1")
    return factor


# ---------------------------------------------------------------------------- sampling


def quadrature_weights(sensitivity: SpectralSensitivity, nodes_m: np.ndarray) -> ChannelWeights:
    """Deterministic quadrature of S^c at given scan wavelengths (the same nodes for all channels).

    The integrand f(λ) is taken as piecewise linear between the ``nodes_m`` (strictly
    increasing, at least 2), so node j's weight is ∫ S^c(λ)·hat_j(λ) dλ over
    [nodes[0], nodes[-1]], where hat_j is the linear interpolant of the j-th unit vector: the
    trapezoidal rule weighted by S^c, exact for f linear between nodes. Weights are
    normalised to sum to 1 per channel; the part of S^c outside the nodes' range is dropped
    and ``coverage`` reports the fraction kept (check it: a channel cut off by a short scan
    is no longer that channel's response). The integral is evaluated on the union of the
    sensitivity grid and the nodes, where S^c and hat_j are both linear on every interval, so
    the integral of their product is exact there.

    Args:
        sensitivity: S^c (:func:`spectral_sensitivity`).
        nodes_m: (W,) scan wavelengths (m), strictly increasing, at least 2.

    Returns:
        ``ChannelWeights``: ``wavelengths_m`` (W,) the nodes (m), ``weights`` (3, W) R, G, B, each
        row summing to 1, and ``coverage`` (3,) the fraction of each channel's ∫S^c dλ kept.

    Examples:
        >>> import numpy as np
        >>> grid = np.array([500e-9, 550e-9, 600e-9])
        >>> flat = spectral_sensitivity(grid, np.ones((3, 3)))
        >>> q = quadrature_weights(flat, grid)
        >>> q.weights[0].round(6).tolist(), q.coverage.round(6).tolist()
        ([0.25, 0.5, 0.25], [1.0, 1.0, 1.0])
    """
    arguments.instance(sensitivity, "sensitivity", SpectralSensitivity, "a SpectralSensitivity")
    nodes = np.atleast_1d(np.asarray(arguments.array(nodes_m, "wavelengths", form="scan wavelengths (m)"), dtype=float))
    if nodes.ndim != 1 or nodes.size < 2 or not np.all(np.diff(nodes) > 0):
        raise InputError(
            "wavelengths",
            "channel quadrature needs at least 2 strictly increasing wavelengths",
            "a scan like 430:645:5nm",
        )
    grid = sensitivity.wavelengths_m
    fine = np.union1d(grid[(grid > nodes[0]) & (grid < nodes[-1])], nodes)
    hats = np.stack([np.interp(fine, nodes, unit) for unit in np.eye(nodes.size)])
    sens_fine = np.stack([np.interp(fine, grid, row, left=0.0, right=0.0) for row in sensitivity.values])
    raw = _integrate_products(fine, sens_fine[:, None, :], hats[None, :, :])
    totals = _trapezoid(sensitivity.values, grid)
    kept = raw.sum(axis=-1)
    for name, mass in zip(CHANNELS, kept):
        if not mass > 0:
            span = f"{nodes[0] / _NM:.1f}-{nodes[-1] / _NM:.1f} nm"
            raise InputError(
                "wavelengths", f"channel {name} has no sensitivity in {span}", "a scan covering every channel's band"
            )
    return ChannelWeights(nodes, raw / kept[:, None], kept / totals)


def sample_wavelengths(
    sensitivity: SpectralSensitivity, samples_per_channel: int, rng: int | np.random.Generator | None
) -> ChannelWeights:
    """Stratified importance sampling of λ ∝ S^c, ``samples_per_channel`` = n per channel.

    For channel c and stratum k = 0..n−1, u = (k + 1 − U)/n with U ~ U[0, 1) from ``rng``
    (a seed or a ``numpy.random.Generator``; the same seed gives the same wavelengths; None: the
    strata's midpoints u = (k + 0.5)/n, a fixed quadrature with no sampling noise), and
    λ = F_c⁻¹(u), where F_c is the CDF of S^c with S^c's mass in each grid cell spread
    uniformly over the cell. Exactly one sample falls in each 1/n-quantile stratum, so the
    empirical CDF is within 1/n of F_c everywhere (lower variance than independent draws).

    Returns 3n wavelengths, channel-major (R's n samples in increasing order, then G's, then
    B's), and weights (3, 3n) equal to 1/n on the channel's own samples and 0 elsewhere:
    ``mix_channels`` then gives the Monte-Carlo estimate of each channel's PSF.
    """
    n = int(samples_per_channel)
    if n != samples_per_channel or n < 1:
        raise InputError("samples", f"{samples_per_channel!r} samples per channel", "a positive integer")
    strata = np.arange(n)
    if rng is None:
        offsets = [np.full(n, 0.5)] * 3
    else:
        generator = np.random.default_rng(rng)
        offsets = [1.0 - generator.random(n) for _ in range(3)]
    wavelengths = np.concatenate(
        [_inverse_cdf(sensitivity.wavelengths_m, row, (strata + u) / n) for row, u in zip(sensitivity.values, offsets)]
    )
    weights = np.kron(np.eye(3), np.full((1, n), 1.0 / n))
    return ChannelWeights(wavelengths, weights, np.ones(3))


def _cumulative(grid: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Normalised cumulative trapezoidal integral of ``values`` (..., L) over ``grid`` (L,)."""
    cells = 0.5 * (values[..., 1:] + values[..., :-1]) * np.diff(grid)
    cumulative = np.concatenate([np.zeros_like(values[..., :1]), np.cumsum(cells, axis=-1)], axis=-1)
    return cumulative / cumulative[..., -1:]


def _inverse_cdf(grid: np.ndarray, values: np.ndarray, u: np.ndarray) -> np.ndarray:
    """λ with F(λ) = u for u in (0, 1], F piecewise linear on ``grid`` (trapezoidal masses)."""
    cdf = _cumulative(grid, values)
    upper = np.clip(np.searchsorted(cdf, u, side="left"), 1, grid.size - 1)
    lower = upper - 1
    fraction = (u - cdf[lower]) / (cdf[upper] - cdf[lower])
    return grid[lower] + np.clip(fraction, 0.0, 1.0) * (grid[upper] - grid[lower])


def _trapezoid(values: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """∫ values dλ over ``grid`` (last axis), exact for values linear between grid points."""
    return np.sum(0.5 * (values[..., 1:] + values[..., :-1]) * np.diff(grid), axis=-1)


def _integrate_products(grid: np.ndarray, f: np.ndarray, g: np.ndarray) -> np.ndarray:
    """∫ f·g dλ over ``grid`` (last axis), exact for f and g both linear between grid points.

    On [a, b]: (b − a)/6 · (2 f_a g_a + f_a g_b + f_b g_a + 2 f_b g_b).
    """
    fa, fb, ga, gb = f[..., :-1], f[..., 1:], g[..., :-1], g[..., 1:]
    return np.sum(np.diff(grid) / 6.0 * (2 * fa * ga + fa * gb + fb * ga + 2 * fb * gb), axis=-1)


# ---------------------------------------------------------------------------- mixing


def mix_channels(psf_mono, weights):
    """3-channel PSF (..., 3, N, N) as the weighted mix of monochromatic PSFs (..., W, N, N).

    ``psf_mono`` is a torch tensor; ``weights`` (3, W), channels R, G, B (a tensor or an
    array, e.g. ``ChannelWeights.weights``), is cast to its dtype and device. Linear and
    differentiable in both arguments (a single einsum).
    """
    import torch

    mix = torch.as_tensor(weights, dtype=psf_mono.dtype, device=psf_mono.device)
    if mix.ndim != 2 or mix.shape[0] != 3 or psf_mono.ndim < 3 or psf_mono.shape[-3] != mix.shape[1]:
        shapes = f"weights {tuple(mix.shape)} for PSFs {tuple(psf_mono.shape)}"
        raise InputError("weights", shapes, "weights (3, W) for PSFs (..., W, N, N)")
    return torch.einsum("...wij,cw->...cij", psf_mono, mix)
