"""Sensor PSF: intensity integrated over square pixels (never amplitude).

Pixel (row i, column j) of an N × N window with pitch Δ (m) is centred at x = (j − N//2)·Δ,
y = (i − N//2)·Δ: the optical axis is at the centre of pixel (N//2, N//2) for odd and even N.
Intensity samples are interpolated with the Catmull-Rom cubic (local, third-order accurate) and the
interpolant is integrated over each pixel exactly:

- 2-D samples on a uniform grid: separable weights ∫_pixel K((x − x_g)/h) dx, so
  P = Wy · I · Wxᵀ (``grid_pixel_matrix``). Each pixel touches only the samples within two of its
  edges, so W is a band of about Δ/h + 4 nonzeros a row: ``GridPixels`` applies it sparse.
- Radial samples I(k·δ): the weight of sample k in pixel p is ∫ φ_k(ρ) dA_p(ρ) = −∫ φ_k'(ρ) A_p(ρ) dρ,
  with A_p(ρ) the closed-form area of the pixel inside the disc of radius ρ (Gauss-Legendre in ρ,
  exact up to the quadrature of a smooth function). Built for the pixels of one octant, the rest
  by the 8-fold symmetry (``RadialSensor``), and cached per (δ, Δ), extended as windows grow.
"""

from __future__ import annotations

import math
import warnings
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse
import torch


def pixel_centres(n_pixels: int, pixel_pitch_m: float) -> np.ndarray:
    """Centres (m) of the pixels along one axis: (i − N//2)·Δ."""
    return (np.arange(n_pixels) - n_pixels // 2) * pixel_pitch_m


def _cr_kernel_deriv(t: np.ndarray) -> np.ndarray:
    """Derivative of the Catmull-Rom kernel K(t)."""
    a = np.abs(t)
    inner = 4.5 * a**2 - 5 * a
    outer = -1.5 * a**2 + 5 * a - 4
    return np.sign(t) * np.where(a < 1, inner, np.where(a < 2, outer, 0.0))


def _cr_kernel_integral(t: np.ndarray) -> np.ndarray:
    """∫_{−∞}^{t} K(s) ds for the Catmull-Rom kernel (0 below −2, 1 above 2)."""
    a = np.minimum(np.abs(t), 2.0)
    inner = 0.375 * a**4 - (2.5 / 3) * a**3 + a
    outer = 13 / 24 + (-0.125 * a**4 + (2.5 / 3) * a**3 - 2 * a**2 + 2 * a) - (17 / 24)
    return 0.5 + np.sign(t) * np.where(a < 1, inner, outer)


def grid_pixel_matrix(coords_m: np.ndarray, n_pixels: int, pixel_pitch_m: float) -> np.ndarray:
    """(N × len(coords)) weights: pixel integral along one axis of the Catmull-Rom interpolant of
    samples at the uniform positions ``coords_m`` (m). Units m: sum over a row = Δ."""
    h = coords_m[1] - coords_m[0]
    lo = pixel_centres(n_pixels, pixel_pitch_m)[:, None] - pixel_pitch_m / 2
    t0 = (lo - coords_m[None, :]) / h
    t1 = (lo + pixel_pitch_m - coords_m[None, :]) / h
    return h * (_cr_kernel_integral(t1) - _cr_kernel_integral(t0))


@dataclass(frozen=True)
class GridPixels:
    """P = W · I · Wᵀ, W = ``grid_pixel_matrix`` (N × S): held sparse (CSR) on the CPU and CUDA,
    where it costs ~N·S·(Δ/h + 4) instead of N·S² (10-20× less for the paper's windows); dense
    elsewhere. The same sums as the dense product (float rounding apart), differentiable in I."""

    matrix: torch.Tensor

    @classmethod
    def build(cls, coords_m: np.ndarray, n_pixels: int, pixel_pitch_m: float, device=None, dtype=torch.float32):
        """The operator for samples at the uniform positions ``coords_m`` (m) onto ``n_pixels``
        pixels of ``pixel_pitch_m`` (m), as ``dtype`` on ``device``: sparse CSR on the CPU and CUDA,
        dense elsewhere."""
        dense = torch.from_numpy(grid_pixel_matrix(coords_m, n_pixels, pixel_pitch_m)).to(device, dtype)
        if dense.device.type not in ("cpu", "cuda"):
            return cls(dense)
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", "Sparse CSR tensor support is in beta", UserWarning)
            return cls(dense.to_sparse_csr())

    def __call__(self, intensity: torch.Tensor) -> torch.Tensor:
        """Pixel powers (N, N) of samples (S, S) (rows y, columns x)."""
        return (self.matrix @ (self.matrix @ intensity).transpose(-1, -2)).transpose(-1, -2)


def _quadrant_area(x: np.ndarray, y: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """Signed area of the disc of radius ρ inside [0, x] × [0, y] (odd in x and in y)."""
    sx, sy = np.sign(x), np.sign(y)
    x, y = np.abs(x), np.abs(y)
    xm = np.minimum(x, rho)
    xc = np.minimum(np.sqrt(np.maximum(rho**2 - y**2, 0.0)), xm)

    def g(u):
        return 0.5 * (u * np.sqrt(np.maximum(rho**2 - u**2, 0.0)) + rho**2 * np.arcsin(u / rho))

    return sx * sy * (y * xc + g(xm) - g(xc))


def pixel_disc_area(x0, x1, y0, y1, rho):
    """Area (m²) of the rectangle [x0, x1] × [y0, y1] inside the disc of radius ρ > 0 (centre 0)."""
    return (
        _quadrant_area(x1, y1, rho)
        - _quadrant_area(x0, y1, rho)
        - _quadrant_area(x1, y0, rho)
        + _quadrant_area(x0, y0, rho)
    )


@dataclass(frozen=True)
class RadialSensor:
    """Linear map from radial intensity samples I(k·δ), k < n_radii, to the N × N pixel powers.

    Its matrix (octant pixels × n_radii, m²) is the first ``rows`` rows of ``matrix``, the
    operator it was cut from (``window``) or its own; ``index`` (N × N): each pixel's octant row."""

    step_m: float
    n_radii: int
    n_pixels: int
    pixel_pitch_m: float
    rows: int
    index: torch.Tensor
    matrix: SparseRows = field(repr=False, compare=False)

    def apply(self, intensity: torch.Tensor) -> torch.Tensor:
        """(n_radii, B) intensities (W/m²) → (B, N, N) pixel powers (W).

        CSR products both ways (``_OctantRows``): every output row is summed by one thread in a
        fixed order, so repeated passes agree bit for bit (tests/optics/test_sensor.py). The
        octant rows are spread to the pixels with ``index_select``: its backward sums each row's
        pixels in a fixed order (``index_add_``), where advanced indexing's backward adds them with
        atomics across threads and rounds differently from run to run on a busy CPU."""
        forward, transposed = self.matrix.on(intensity.dtype, intensity.device)
        end = int(self.matrix.csr.indptr[self.rows])  # from the host copy: no wait for the device
        octant = _OctantRows.apply(intensity, _csr_prefix(forward, self.rows, self.n_radii, end), transposed)
        pixels = torch.index_select(octant, 0, self.index.to(intensity.device).reshape(-1))
        return pixels.T.reshape(-1, self.n_pixels, self.n_pixels)

    def window(self, n_pixels: int) -> RadialSensor:
        """The operator of the central n × n window (n ≤ N): a pixel's weights depend only on its
        offset from the axis, and the octant lists pixels by their larger offset first, so the
        smaller window's rows are a prefix of these (and its radii a prefix of the samples)."""
        if n_pixels == self.n_pixels:
            return self
        if not 1 <= n_pixels <= self.n_pixels:
            raise ValueError(f"window of {n_pixels} pixels from a {self.n_pixels}-pixel operator")
        m = n_pixels // 2
        rows, n_radii = (m + 1) * (m + 2) // 2, radial_sensor_radii(self.step_m, n_pixels, self.pixel_pitch_m)
        return RadialSensor(
            self.step_m, n_radii, n_pixels, self.pixel_pitch_m, rows, _octant_index(n_pixels), self.matrix
        )


class SparseRows:
    """A sparse matrix (float64 CSR, scipy, from its ``indptr``, ``indices`` and ``data``) and,
    made once per (dtype, device) asked for, torch CSR copies of it and of its transpose (int32
    indices)."""

    def __init__(self, indptr: np.ndarray, indices: np.ndarray, data: np.ndarray, shape: tuple[int, int]):
        self.csr = scipy.sparse.csr_matrix((data, indices.astype(np.int32), indptr.astype(np.int32)), shape=shape)
        self._copies: dict = {}

    def on(self, dtype: torch.dtype, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
        """(matrix, transpose) as torch CSR tensors of ``dtype`` on ``device``, made at the first
        request and kept."""
        key = (dtype, str(device))
        if key not in self._copies:
            self._copies[key] = tuple(_torch_csr(m, dtype, device) for m in (self.csr, self.csr.T.tocsr()))
        return self._copies[key]


def _torch_csr(matrix, dtype: torch.dtype, device) -> torch.Tensor:
    return _csr(
        *(torch.from_numpy(a).to(device) for a in (matrix.indptr.astype(np.int32), matrix.indices.astype(np.int32))),
        torch.from_numpy(matrix.data).to(device, dtype),
        matrix.shape,
    )


def _csr_prefix(matrix: torch.Tensor, rows: int, cols: int, end: int) -> torch.Tensor:
    """The first ``rows`` rows of a CSR matrix (their ``end`` entries) as a (rows × cols) view (its columns < cols)."""
    return _csr(matrix.crow_indices()[: rows + 1], matrix.col_indices()[:end], matrix.values()[:end], (rows, cols))


def _csr(crow, cols, values, shape) -> torch.Tensor:
    with warnings.catch_warnings():  # torch's notes on CSR being beta (the products used here are not) and, in
        warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta")  # 2.11, on skipped checks
        warnings.filterwarnings("ignore", message="Sparse invariant checks are implicitly disabled")
        return torch.sparse_csr_tensor(crow, cols, values, shape, check_invariants=False)


class _OctantRows(torch.autograd.Function):
    """``weights @ intensity`` for a CSR prefix of an operator, its backward through the whole
    operator's transpose (the gradient's missing rows padded with zeros): torch's own backward of
    a sparse product builds the transpose at every call, which cost 20× the product. Its forward-mode
    derivative (``jvp``, for ``torch.autograd.forward_ad``: a Jacobian over a few parameters, as the
    phase retrieval builds) is the same product applied to the tangent."""

    @staticmethod
    def forward(ctx, intensity, weights, transposed):
        ctx.transposed, ctx.n_radii, ctx.weights = transposed, intensity.shape[0], weights
        return weights @ intensity

    @staticmethod
    def jvp(ctx, intensity_tangent, weights_tangent, transposed_tangent):
        return ctx.weights @ intensity_tangent

    @staticmethod
    def backward(ctx, grad):
        full = grad.new_zeros(ctx.transposed.shape[1], grad.shape[1])
        full[: grad.shape[0]] = grad
        return (ctx.transposed @ full)[: ctx.n_radii], None, None


def larger_window(n: int, factor: float = 1.25) -> int:
    """The odd window about ``factor`` times the side ``n`` (pixels), at least n + 2."""
    return max(2 * math.ceil(factor * n / 2) + 1, n + 2)


SENSOR_CACHE_ENTRIES = 8  # (step, pitch) pairs whose operators are kept
_SENSORS: OrderedDict = OrderedDict()


def radial_sensor(step_m: float, n_pixels: int, pixel_pitch_m: float, n_nodes: int = 4) -> RadialSensor:
    """The pixel operator of an n × n window for radial samples every ``step_m`` (m), cut
    (``RadialSensor.window``) from the cached one of (step, pitch). A cached operator that is too
    small is extended to at least ``larger_window`` of its size, computing only the rows of the
    pixels it lacks (``build_radial_sensor``): windows that grow from call to call (training steps
    that follow the light) pay for a few extensions whose total is about one build of the largest."""
    key = (float(step_m), float(pixel_pitch_m), n_nodes)
    have = _SENSORS.pop(key, None)
    if have is None:
        have = build_radial_sensor(step_m, n_pixels, pixel_pitch_m, n_nodes)
    elif have.n_pixels < n_pixels:
        have = build_radial_sensor(step_m, max(n_pixels, larger_window(have.n_pixels)), pixel_pitch_m, n_nodes, have)
    _SENSORS[key] = have
    while len(_SENSORS) > SENSOR_CACHE_ENTRIES:
        _SENSORS.popitem(last=False)
    return have.window(n_pixels)


def radial_sensor_radii(step_m: float, n_pixels: int, pixel_pitch_m: float) -> int:
    """Number of radial samples k·δ a ``RadialSensor`` needs (window corner plus the stencil)."""
    m = n_pixels // 2
    rho_max = math.hypot(m + 0.5, m + 0.5) * pixel_pitch_m
    return math.ceil(rho_max / step_m) + 3


def _octant_areas(x0, x1, y0, y1, rho, chunks: int = 8) -> np.ndarray:
    """pixel_disc_area for pixel p (x0[p].., rows of ``rho``), in row chunks on a thread pool:
    numpy releases the GIL in its ufuncs, so this uses every core (2.1× on 2 cores)."""
    bounds = np.linspace(0, len(x0), chunks + 1).astype(int)

    def rows(i: int) -> np.ndarray:
        s = slice(bounds[i], bounds[i + 1])
        return pixel_disc_area(x0[s, None, None], x1[s, None, None], y0[s, None, None], y1[s, None, None], rho[s])

    with ThreadPoolExecutor(max_workers=torch.get_num_threads()) as pool:
        return np.concatenate(list(pool.map(rows, range(chunks))))


def build_radial_sensor(
    step_m: float, n_pixels: int, pixel_pitch_m: float, n_nodes: int = 4, start: RadialSensor | None = None
) -> RadialSensor:
    """Build the pixel operator for radial samples every ``step_m`` (m); with ``start`` (one of
    the same step and pitch for a smaller window), only the rows of the pixels it lacks are
    computed and appended to its rows (the octant lists pixels by their larger offset first)."""
    m = n_pixels // 2
    n_radii = radial_sensor_radii(step_m, n_pixels, pixel_pitch_m)
    first = 0 if start is None else start.n_pixels // 2 + 1  # the first pixel offset to compute
    ii, jj = np.tril_indices(m + 1)  # octant: 0 ≤ j ≤ i ≤ m (pixel offsets)
    ii, jj = ii[ii >= first], jj[ii >= first]
    x0, x1 = (ii - 0.5) * pixel_pitch_m, (ii + 0.5) * pixel_pitch_m
    y0, y1 = (jj - 0.5) * pixel_pitch_m, (jj + 0.5) * pixel_pitch_m
    rmin = np.hypot(np.maximum(x0, 0), np.maximum(y0, 0))
    rmax = np.hypot(x1, y1)
    j_lo = np.floor(rmin / step_m).astype(int) - 1
    j_hi = np.ceil(rmax / step_m).astype(int) + 1
    n_int = int((j_hi - j_lo).max()) + 4
    k = (j_lo - 2)[:, None] + np.arange(n_int)[None, :]  # interval k: [kδ, (k+1)δ]
    t, wq = np.polynomial.legendre.leggauss(n_nodes)
    t, wq = (t + 1) / 2, wq / 2
    rho = (k[:, :, None] + t) * step_m  # (P, n_int, Q)
    valid = k[:, :, None] >= 0
    area = _octant_areas(x0, x1, y0, y1, np.where(valid, rho, step_m))
    area = np.where(valid, area, 0.0)
    # sample j = k + shift (shift = −1..2) gets −∫ K'(t − shift)·A dt from interval k: a (Q × 4) table
    table = -wq[:, None] * _cr_kernel_deriv(t[:, None] - np.arange(-1, 3)[None, :])
    contrib = area @ table  # (P, n_int, 4)
    local = np.zeros((len(ii), n_int + 3))  # column l: j = k0 − 1 + l
    for s in range(4):
        local[:, s : s + n_int] += contrib[:, :, s]
    j = (k[:, :1] - 1) + np.arange(n_int + 3)[None, :]
    axis_rows = np.nonzero(j[:, 0] <= -1)[0]  # fold I(−δ) = I(δ)
    local[axis_rows, 2 - k[axis_rows, 0]] += local[axis_rows, -k[axis_rows, 0]]
    keep = (j >= np.maximum(j_lo, 0)[:, None]) & (j <= j_hi[:, None])  # each row's columns, ascending
    indptr, indices, data = np.concatenate([[0], np.cumsum(keep.sum(axis=1))]), j[keep], local[keep]
    if start is not None:
        old = start.matrix.csr
        indptr, indices, data = (
            np.concatenate([old.indptr, old.nnz + indptr[1:]]),
            np.concatenate([old.indices, indices]),
            np.concatenate([old.data, data]),
        )
    rows = (m + 1) * (m + 2) // 2
    return RadialSensor(
        step_m,
        n_radii,
        n_pixels,
        pixel_pitch_m,
        rows,
        _octant_index(n_pixels),
        SparseRows(indptr, indices, data, (rows, n_radii)),
    )


def _octant_index(n_pixels: int) -> torch.Tensor:
    """(N, N) index of each pixel's octant row (``np.tril_indices`` order of the offsets)."""
    off = np.abs(np.arange(n_pixels) - n_pixels // 2)
    a, b = np.maximum(off[:, None], off[None, :]), np.minimum(off[:, None], off[None, :])
    return torch.from_numpy(a * (a + 1) // 2 + b)
