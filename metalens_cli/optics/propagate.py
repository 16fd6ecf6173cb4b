"""Scalar propagators from the lens plane (z = 0) to a plane at distance d > 0 (SI metres).

Pure functions of tensors and floats; the only state is the explicit caches passed in and out
(transfer functions, Hankel kernels). Field convention exp(+i(kz − ωt)); all three propagators are
exact within scalar diffraction theory (no Fresnel approximation):

- ``asm_*``: band-limited angular spectrum (Matsushima & Shimobaba 2009) on a square 2-D grid,
  H(u, v) = exp(i·2π·d·√(1/λ² − u² − v²)) restricted to |u|, |v| ≤ u_lim.
- ``hankel_*``/``radial_propagate``: the same transfer function for rotationally symmetric fields
  in Hankel form, via the quasi-discrete Hankel transform of order 0 (Guizar-Sicairos &
  Gutiérrez-Vega 2004), evaluated only at the output radii asked for.
- ``rayleigh_sommerfeld``: direct first Rayleigh-Sommerfeld integral with the exact kernel, over
  any quadrature of the input plane: the slow reference, sharing no code with the two above.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import scipy.special as sps
import torch

from metalens_cli import arguments

# --------------------------------------------------------------------------------------- FFT sizes


def fft_size(n: int) -> int:
    """The smallest integer ≥ n whose prime factors are 2, 3, 5 and 7 (cheap FFT lengths)."""
    best = 1 << max(int(n) - 1, 0).bit_length()
    p7 = 1
    while p7 < best:
        p5 = p7
        while p5 < best:
            p3 = p5
            while p3 < best:
                p2 = p3
                while p2 < n:
                    p2 *= 2
                best = min(best, p2)
                p3 *= 3
            p5 *= 5
        p7 *= 7
    return best


# ------------------------------------------------------------------------------ angular spectrum


def bandlimit_frequency(wavelength_m: float, distance_m: float, extent_m: float) -> float:
    """Matsushima-Shimobaba limit u_lim = 1/(λ·√((2·d/S)² + 1)) (cycles/m) for a padded grid of
    side S (m): frequencies beyond it would travel more than S/2 sideways and wrap around."""
    return 1.0 / (wavelength_m * math.hypot(2 * distance_m / extent_m, 1.0))


@dataclass
class AsmGrid:
    """Padded FFT grid of the 2-D angular spectrum: ``size`` samples of ``pitch_m`` per side,
    input array of ``input_size`` samples with the axis at its index input_size//2, and the
    output window: positions (i − half)·pitch/upsample for i = 0..2·half (m)."""

    size: int
    pitch_m: float
    input_size: int
    window_half: int
    upsample: int = 2

    @property
    def extent_m(self) -> float:
        """Side S = size·pitch of the padded grid (m)."""
        return self.size * self.pitch_m

    @property
    def upsampled_size(self) -> int:
        """Length of the finer (output) grid's inverse transforms."""
        return self.size * self.upsample

    @property
    def window_start(self) -> int:
        """Index of the window's first sample on the finer grid (axis at (input_size//2)·upsample)."""
        return (self.input_size // 2) * self.upsample - self.window_half

    @property
    def window_samples(self) -> int:
        """Samples along each side of the output window: 2·window_half + 1."""
        return 2 * self.window_half + 1

    def window_coords(self, dtype: torch.dtype = torch.float64) -> torch.Tensor:
        """Output sample positions along x (and y) in m."""
        n = torch.arange(-self.window_half, self.window_half + 1, dtype=dtype)
        return n * (self.pitch_m / self.upsample)


def _band_halfwidth(size: int, pitch_m: float, u_lim: float) -> int:
    """Largest K with K/(size·pitch) ≤ u_lim: the kept frequencies are k = −K..K."""
    return min(math.floor(u_lim * size * pitch_m), (size - 1) // 2)


def asm_transfer(
    grid: AsmGrid,
    wavelength_m: float,
    distance_m: float,
    dtype: torch.dtype = torch.complex64,
    device: str | torch.device = "cpu",
):
    """Band-limited transfer function on the kept band and the band's half-width K.

    Returns (H, K): H[a, b] = exp(i·2π·d·√(1/λ² − v_a² − u_b²)) with u_b = (b − K)/(size·pitch)
    (frequencies −K..K in increasing order, same along both axes), zero where evanescent.
    Computed on one quadrant in float64 and mirrored. Reusable for every field on ``grid``.
    """
    u_lim = bandlimit_frequency(wavelength_m, distance_m, grid.extent_m)
    k_max = _band_halfwidth(grid.size, grid.pitch_m, u_lim)
    u = torch.arange(k_max + 1, dtype=torch.float64, device=device) / grid.extent_m
    arg = 1.0 / wavelength_m**2 - u[:, None] ** 2 - u[None, :] ** 2
    phase = torch.remainder(2 * math.pi * distance_m * torch.sqrt(arg.clamp(min=0)), 2 * math.pi)
    real_dtype = torch.float32 if dtype == torch.complex64 else torch.float64
    quadrant = torch.polar((arg > 0).to(real_dtype), phase.to(real_dtype))
    return mirror_quadrant(quadrant), k_max


def asm_transfer_shifted(
    grid: AsmGrid,
    wavelength_m: float,
    distance_m: float,
    k_max: int,
    carrier: tuple[float, float],
    centre_m: tuple[float, float],
    dtype: torch.dtype = torch.complex64,
    device: str | torch.device = "cpu",
    nonnegative_v: bool = False,
):
    """Transfer function of the shifted angular spectrum for a field g = U·exp(−i·2π(u0·x + v0·y))
    whose carrier (u0, v0) = ``carrier`` (cycles/m) was taken out, onto the window centred at
    ``centre_m`` = (xc, yc) (m) instead of the axis (Matsushima 2010, shifted-window form).

    Returns (H, K): H[a, b] = exp(i·2π·d·w)·exp(i·2π·(u_b·xc + v_a·yc)), w = √(1/λ² − (u_b + u0)² −
    (v_a + v0)²), at u_b = (b − K)/S, v_a = (a − K)/S (rows v, columns u, as ``_asm_apply`` lays out
    the band): |U|² on the window is then |g propagated|², and window sample i sits at xc + its
    on-axis position. Kept where the wave propagates and its lateral travel d·(u + u0)/w lies within
    S/2 of xc (and likewise in y), the band limit of the recentred kernel: its sampling in
    frequency then resolves it, and rays from the pupil to the window all pass (the grid's side S
    is at least 2a + W). Built in float64 a block of rows at a time (its transient memory is one
    block's, not five float64 arrays of the band's size). ``nonnegative_v``: the rows v ≥ 0 alone,
    (K + 1, 2K + 1), for ``asm_propagate_even_y`` (H is even in v when v0 = yc = 0).
    """
    u0, v0 = carrier
    xc, yc = centre_m
    f = torch.arange(-k_max, k_max + 1, dtype=torch.float64, device=device) / grid.extent_m
    u = f + u0
    half = grid.extent_m / 2
    column = (1.0 / wavelength_m**2 - u**2)[None, :]
    ramp_x = (2 * math.pi * xc) * f[None, :]
    real_dtype = torch.float32 if dtype == torch.complex64 else torch.float64
    if nonnegative_v and (v0 != 0 or yc != 0):
        raise ValueError("the transfer function is even in v only without a carrier or window offset in y")
    f_rows = f[k_max:] if nonnegative_v else f
    out = torch.empty(f_rows.numel(), f.numel(), dtype=dtype, device=device)
    step = max(1, BLOCK_BYTES // (8 * f.numel()))
    for a in range(0, f_rows.numel(), step):  # a block of rows (v) at a time: float64 work of one block
        fv = f_rows[a : a + step, None]
        v = fv + v0
        w = column - v**2  # w² first, reused in place
        keep = w > 0
        w.clamp_(min=0).sqrt_()
        # lateral travel d·(u, v)/w within S/2 of the window's centre, multiplied through by w ≥ 0
        keep &= (distance_m * u[None, :] - xc * w).abs_() <= half * w
        keep &= (distance_m * v - yc * w).abs_() <= half * w
        phase = w.mul_(2 * math.pi * distance_m).add_(ramp_x).add_((2 * math.pi * yc) * fv)
        out[a : a + step] = torch.polar(keep.to(real_dtype), phase.remainder_(2 * math.pi).to(real_dtype))
    return out, k_max


def mirror_quadrant(q: torch.Tensor) -> torch.Tensor:
    """Full (2n−1)² array, even in both axes, from its quadrant q[..., i, j] at offsets i, j ≥ 0."""
    q = torch.cat([q.flip(-1)[..., :-1], q], dim=-1)
    return torch.cat([q.flip(-2)[..., :-1, :], q], dim=-2)


@dataclass
class TransferCache:
    """The ``capacity`` most recently used transfer functions, keyed on (λ, d, grid size, pitch,
    dtype, device). One is (2K+1)² complex, 2.6 GB at the paper's training grid, so only a few are
    kept: callers go wavelength by wavelength and reuse each one for every depth."""

    capacity: int = 1
    store: OrderedDict = field(default_factory=OrderedDict)

    def get(self, grid: AsmGrid, wavelength_m: float, distance_m: float, dtype, device):
        """:func:`asm_transfer`'s (H, K) for this grid, wavelength (m), distance (m), dtype and
        device: the held one (made the most recent), else built after dropping the oldest to stay
        within ``capacity``."""
        key = (float(wavelength_m), float(distance_m), grid.size, grid.pitch_m, dtype, str(device))
        if key in self.store:
            self.store.move_to_end(key)
            return self.store[key]
        while len(self.store) >= self.capacity:
            self.store.popitem(last=False)  # free the oldest before building the next
        self.store[key] = asm_transfer(grid, wavelength_m, distance_m, dtype, device)
        return self.store[key]


BLOCK_BYTES = 1 << 24
"""Rows of a 1-D FFT pass are transformed this many bytes of output at a time, each block
written into the pass's output: the transient memory of a pass is one block, not a full array."""


def _blocks(rows: int, length: int, itemsize: int) -> list[slice]:
    step = max(1, BLOCK_BYTES // (length * itemsize))
    return [slice(a, min(a + step, rows)) for a in range(0, rows, step)]


def _band_fft(x: torch.Tensor, size: int, k_max: int, nonnegative: bool = False, mirror: bool = False) -> torch.Tensor:
    """DFT of length ``size`` (zero padded) along the last axis, keeping frequencies −K..K in
    increasing order (0..K with ``nonnegative``); returned transposed in its last two axes:
    (..., r, n) → (..., 2K+1, r). ``mirror``: the rows are those at offsets 0..r−1 of a set even
    about its first row, returned whole: (..., 2K+1, 2r−1), row j at columns r−1 ± j."""
    low, r = (0 if nonnegative else k_max), x.shape[-2]
    axis = r - 1 if mirror else 0
    out = x.new_empty(*x.shape[:-2], low + k_max + 1, axis + r)
    for rows in _blocks(r, size, x.element_size()):
        spec = torch.fft.fft(x[..., rows, :], n=size, dim=-1)
        placed = [(slice(axis + rows.start, axis + rows.stop), spec)]
        if mirror and rows.stop > 1:
            first = max(rows.start, 1)
            placed.append((slice(axis - rows.stop + 1, axis - first + 1), spec[..., first - rows.start :, :].flip(-2)))
        for columns, block in placed:
            if low:
                out[..., :low, columns] = block[..., size - low :].transpose(-1, -2)
            out[..., low:, columns] = block[..., : k_max + 1].transpose(-1, -2)
    return out


def _band_fft_adjoint(y: torch.Tensor, size: int, k_max: int, n: int) -> torch.Tensor:
    """Adjoint of ``_band_fft``: (..., 2K+1, r) → (..., r, n), x_j = Σ_k y_k·exp(+i·2π·k·j/size)."""
    rows_total = y.shape[-1]
    out = y.new_empty(*y.shape[:-2], rows_total, n)
    yt = y.transpose(-1, -2)
    for rows in _blocks(rows_total, size, y.element_size()):
        full = y.new_zeros(*y.shape[:-2], rows.stop - rows.start, size)
        full[..., : k_max + 1] = yt[..., rows, k_max:]
        full[..., size - k_max :] = yt[..., rows, :k_max]
        out[..., rows, :] = torch.fft.ifft(full, dim=-1, norm="forward")[..., :n]
    return out


def _turns(k: torch.Tensor, x: torch.Tensor | int, size: int, sign: float, dtype) -> torch.Tensor:
    """exp(sign·i·2π·k·x/size) with k·x reduced mod size in integers (exact phase)."""
    turns = torch.remainder(k * x, size).to(dtype)
    return torch.polar(torch.ones_like(turns), turns * (sign * 2 * math.pi / size))


def _window_ifft(
    band: torch.Tensor, size: int, k_max: int, start: int, count: int, twist: torch.Tensor | None = None
) -> torch.Tensor:
    """Inverse DFT of length ``size`` along the last axis of coefficients for k = −K..K,
    at outputs x = start..start+count−1 (mod size), transposed: (..., r, 2K+1) → (..., count, r).
    ``twist`` (r − 1 factors t_j): the rows are those at offsets j = 0..r−1 of a set whose row −j
    is t_j times row j, returned whole: (..., count, 2r−1), row j at column r−1 + j.

    The band is fed as k + K = 0..2K (zero padding at the end, native to the FFT) and the
    resulting shift is undone by the ramp exp(−i·2π·K·x/size) on the kept outputs only.
    """
    x = torch.remainder(torch.arange(start, start + count, device=band.device), size)
    ramp = _turns(torch.tensor(k_max, device=band.device), x, size, -1.0, band.real.dtype)
    r = band.shape[-2]
    axis = 0 if twist is None else r - 1
    out = band.new_empty(*band.shape[:-2], count, axis + r)
    for rows in _blocks(r, size, band.element_size()):
        kept = torch.fft.ifft(band[..., rows, :], n=size, dim=-1).index_select(-1, x) * ramp
        out[..., :, axis + rows.start : axis + rows.stop] = kept.transpose(-1, -2)
        if twist is not None and rows.stop > 1:
            first = max(rows.start, 1)
            mirrored = kept[..., first - rows.start :, :] * twist[first - 1 : rows.stop - 1, None]
            out[..., :, axis - rows.stop + 1 : axis - first + 1] = mirrored.flip(-2).transpose(-1, -2)
    return out


def _window_ifft_adjoint(window: torch.Tensor, size: int, k_max: int, start: int) -> torch.Tensor:
    """Adjoint of ``_window_ifft``: (..., count, r) → (..., r, 2K+1),
    b_k = (1/size)·Σ_x w_x·exp(−i·2π·k·(start + x)/size) for k = −K..K."""
    count, rows_total = window.shape[-2:]
    dev, real = window.device, window.real.dtype
    pre = _turns(torch.arange(count, device=dev), k_max, size, 1.0, real)  # exp(+i2πKx/size)
    post = _turns(torch.arange(-k_max, k_max + 1, device=dev), start, size, -1.0, real) / size
    g = window.transpose(-1, -2)
    out = window.new_empty(*window.shape[:-2], rows_total, 2 * k_max + 1)
    for rows in _blocks(rows_total, size, window.element_size()):
        out[..., rows, :] = torch.fft.fft(g[..., rows, :] * pre, n=size, dim=-1)[..., : 2 * k_max + 1] * post
    return out


def _asm_apply(field: torch.Tensor, grid: AsmGrid, h: torch.Tensor, k_max: int) -> torch.Tensor:
    n_up, start, count = grid.upsampled_size, grid.window_start, grid.window_samples
    spec = _band_fft(_band_fft(field, grid.size, k_max), grid.size, k_max).mul_(h)
    out = _window_ifft(_window_ifft(spec, n_up, k_max, start, count), n_up, k_max, start, count)
    return out.mul_(grid.upsample**2)


def _asm_adjoint(window: torch.Tensor, grid: AsmGrid, h: torch.Tensor, k_max: int) -> torch.Tensor:
    n_up, start = grid.upsampled_size, grid.window_start
    spec = _window_ifft_adjoint(_window_ifft_adjoint(window, n_up, k_max, start), n_up, k_max, start)
    spec = spec.mul_(h.conj())
    field = _band_fft_adjoint(
        _band_fft_adjoint(spec, grid.size, k_max, grid.input_size), grid.size, k_max, grid.input_size
    )
    return field.mul_(grid.upsample**2)


def asm_propagate_even_y(half: torch.Tensor, grid: AsmGrid, transfer: Callable[[], tuple]) -> torch.Tensor:
    """``asm_propagate`` of a field even in y (rows), given by its rows y ≥ 0 (..., n//2 + 1, n)
    (n = ``grid.input_size``, odd: row 0 is the axis), through a transfer function even in v,
    given by its rows v ≥ 0: ``transfer()`` returns (H, K), H of shape (K + 1, 2K + 1) (e.g.
    ``asm_transfer_shifted(..., nonnegative_v=True)``, no carrier or window offset in y).

    The window of ``asm_propagate`` of the whole field, for about three quarters of its FFT work:
    the first forward and the first inverse pass run over half the rows. The spectrum of the
    zero-padded even field obeys X(−v) = exp(i·4π·v·c/S)·X(v) (c = n//2 the axis row, S the grid
    size), and so does each column of the first inverse pass, which so fills its rows v < 0.
    Differentiable in ``half`` through its adjoint, like ``asm_propagate``.
    """
    return _AsmPropagate.apply(half, grid, transfer, _asm_apply_even_y, _asm_adjoint_even_y)


def asm_propagate_even_y_adjoint(window: torch.Tensor, grid: AsmGrid, transfer: Callable[[], tuple]) -> torch.Tensor:
    """Adjoint of ``asm_propagate_even_y``: window field (..., w, w) → rows y ≥ 0 (..., n//2 + 1, n)."""
    return _asm_adjoint_even_y(window, grid, *transfer())


def _mirror_twist(grid: AsmGrid, k_max: int, device, dtype) -> torch.Tensor:
    """exp(i·4π·k·c/S), k = 1..K: X(−k) = twist_k·X(k) for an even field whose axis is input row c."""
    k = torch.arange(1, k_max + 1, device=device)
    return _turns(k, 2 * (grid.input_size // 2), grid.size, 1.0, dtype)


def _asm_apply_even_y(half: torch.Tensor, grid: AsmGrid, h: torch.Tensor, k_max: int) -> torch.Tensor:
    if grid.input_size % 2 == 0 or half.shape[-2] != grid.input_size // 2 + 1:
        raise ValueError("an even field needs an odd input size and its rows from the axis on")
    n_up, start, count = grid.upsampled_size, grid.window_start, grid.window_samples
    columns = _band_fft(half, grid.size, k_max, mirror=True)  # (..., 2K+1 [u], n [y = −c..c])
    spec = _band_fft(columns, grid.size, k_max, nonnegative=True).mul_(h)  # (..., K+1 [v ≥ 0], 2K+1 [u])
    del columns
    twist = _mirror_twist(grid, k_max, spec.device, spec.real.dtype)
    rows = _window_ifft(spec, n_up, k_max, start, count, twist)  # (..., w [x], 2K+1 [v = −K..K])
    del spec
    return _window_ifft(rows, n_up, k_max, start, count).mul_(grid.upsample**2)


def _asm_adjoint_even_y(window: torch.Tensor, grid: AsmGrid, h: torch.Tensor, k_max: int) -> torch.Tensor:
    n_up, start, c = grid.upsampled_size, grid.window_start, grid.input_size // 2
    rows = _window_ifft_adjoint(window, n_up, k_max, start)  # (..., w, 2K+1)
    twist = _mirror_twist(grid, k_max, rows.device, rows.real.dtype)
    folded = rows[..., k_max:].clone()
    folded[..., 1:] += rows[..., :k_max].flip(-1) * twist.conj()
    del rows
    spec = _window_ifft_adjoint(folded, n_up, k_max, start).mul_(h.conj())  # (..., K+1, 2K+1)
    spec = torch.cat([spec.new_zeros(*spec.shape[:-2], k_max, spec.shape[-1]), spec], dim=-2)
    columns = _band_fft_adjoint(spec, grid.size, k_max, grid.input_size)  # (..., 2K+1, n)
    del spec
    folded = columns[..., c:].clone()
    folded[..., 1:] += columns[..., :c].flip(-1)
    del columns
    return _band_fft_adjoint(folded, grid.size, k_max, grid.input_size).mul_(grid.upsample**2)


class _AsmPropagate(torch.autograd.Function):
    """A propagation ``apply(field, grid, H, K)`` is linear in the field: its gradient is the
    adjoint propagation ``adjoint(grad, grid, H, K)`` of the output gradient, so nothing is saved
    between the passes (the transfer function is fetched again through ``transfer``)."""

    @staticmethod
    def forward(ctx, field, grid, transfer, apply, adjoint):
        ctx.grid, ctx.transfer, ctx.adjoint = grid, transfer, adjoint
        return apply(field, grid, *transfer())

    @staticmethod
    def backward(ctx, grad):
        return ctx.adjoint(grad, ctx.grid, *ctx.transfer()), None, None, None, None


def asm_propagate(field: torch.Tensor, grid: AsmGrid, transfer: Callable[[], tuple]) -> torch.Tensor:
    """Propagate ``field`` by the band-limited angular spectrum onto ``grid``'s output window.

    Zero padding, band selection, upsampling (zero padding of the spectrum) and the window crop
    happen inside 1-D passes along the last axis, a block of rows at a time, so no padded
    full-size 2-D array is formed. Differentiable: the backward pass runs the adjoint propagation.

    Args:
        field: complex input field, sampled at ``grid.pitch_m`` (m), the axis at index n//2.
        grid: the padded FFT grid and output window (``optics.sampling.plan_asm``).
        transfer: returns (H, K) from ``asm_transfer`` (e.g. through a ``TransferCache``); it is
            called in the forward pass and again in the backward pass, so H need not be held in
            between.

    Returns:
        The complex field on the output window, sampled ``grid.upsample`` times finer than the
        input: positions (i − half)·pitch/upsample (m), i = 0 … 2·half.

    Shape:
        - Input: :math:`(..., n, n)`, n = ``grid.input_size``.
        - Output: :math:`(..., w, w)`, w = 2·half + 1 (half = ``grid.window_half``).
    """
    arguments.instance(field, "field", torch.Tensor, "a complex field tensor (..., n, n)")
    arguments.instance(grid, "grid", AsmGrid, "an AsmGrid (optics.sampling.plan_asm)")
    if not callable(transfer):
        raise TypeError(f"transfer: expected a callable returning (H, K), got {type(transfer).__name__}")
    return _AsmPropagate.apply(field, grid, transfer, _asm_apply, _asm_adjoint)


def asm_propagate_adjoint(window: torch.Tensor, grid: AsmGrid, transfer: Callable[[], tuple]) -> torch.Tensor:
    """Adjoint (conjugate transpose) of ``asm_propagate``: window field (..., w, w) → input
    field (..., n, n), with ⟨asm_propagate(x), y⟩ = ⟨x, asm_propagate_adjoint(y)⟩."""
    return _asm_adjoint(window, grid, *transfer())


def asm_propagate_plain(
    field: torch.Tensor, pitch_m: float, wavelength_m: float, distance_m: float, band_limit: bool = True
) -> torch.Tensor:
    """Reference ASM on the field's own (already padded) periodic grid, same size out.

    ``band_limit=False`` is the plain angular spectrum method, prone to wrap-around aliasing.
    """
    size = field.shape[-1]
    u = torch.fft.fftfreq(size, d=pitch_m, dtype=torch.float64)
    arg = 1.0 / wavelength_m**2 - u[:, None] ** 2 - u[None, :] ** 2
    h = torch.polar((arg > 0).double(), 2 * math.pi * distance_m * torch.sqrt(arg.clamp(min=0)))
    if band_limit:
        u_lim = bandlimit_frequency(wavelength_m, distance_m, size * pitch_m)
        h = h * ((u[:, None].abs() <= u_lim) & (u[None, :].abs() <= u_lim))
    return torch.fft.ifft2(torch.fft.fft2(field) * h.to(field.dtype))


# ------------------------------------------------------------------------------ Hankel (radial)


def bessel_j0_zeros(n: int) -> np.ndarray:
    """First n positive zeros of J0 (McMahon's expansion refined by Newton steps), float64."""
    beta = (np.arange(1, n + 1) - 0.25) * np.pi
    j = beta + 1 / (8 * beta) - 31 / (384 * beta**3) + 3779 / (15360 * beta**5)
    for _ in range(3):
        j = j + sps.j0(j) / sps.j1(j)
    return j


def gauss_legendre_panels(length_m: float, n_nodes: int, per_panel: int = 16):
    """Nodes and weights (m) of composite Gauss-Legendre quadrature on [0, length_m]."""
    x, w = np.polynomial.legendre.leggauss(per_panel)
    edges = np.linspace(0.0, length_m, max(1, math.ceil(n_nodes / per_panel)) + 1)
    half = (edges[1:] - edges[:-1])[:, None] / 2
    return ((edges[:-1, None] + half) + half * x).ravel(), (half * w).ravel()


@dataclass(frozen=True)
class HankelKernel:
    """Hankel transform of order 0 of a field that vanishes beyond the pupil radius a (m).

    Spectrum at the quasi-discrete Hankel frequencies ν_m = j_m/(2πR), m < n, of a support
    radius R ≥ a (j_m: zeros of J0), computed from Gauss-Legendre nodes r_q on [0, a] so that the
    hard pupil edge is integrated exactly: F(ν_m) = Σ_q J0(2πν_m r_q)·w_q·f(r_q), w_q = 2πr_q·dr_q
    (``weight``, also the quadrature of ∫|f|² dA). Inverse at any ρ ≤ R by the Fourier-Bessel
    series f(ρ) = Σ_m J0(2πν_m ρ)·c_m·F(ν_m), c_m = 1/(πR²·J1(j_m)²) (Guizar-Sicairos &
    Gutiérrez-Vega 2004). Depends on neither λ nor z. ``nu`` is float64 whatever the kernel's
    dtype: phases 2πν·ρ and 2πd·√(1/λ² − ν²) reach 10⁴-10⁵ rad, where float32 would be off by
    10⁻³ rad.
    """

    radius_m: float
    aperture_radius_m: float
    r: torch.Tensor
    weight: torch.Tensor
    nu: torch.Tensor
    coef_out: torch.Tensor
    forward: torch.Tensor


HANKEL_CACHE_ENTRIES = 8
HANKEL_CACHE_BYTES = 2 << 30  # beyond this the oldest entries go (the newest two, a plan's kernel and rows, stay)
ROW_GROWTH = 1.25  # output rows are extended at least this much at a time
_HANKEL_CACHE: OrderedDict = OrderedDict()


def _entry_bytes(entry) -> int:
    tensors = [getattr(entry, f) for f in entry.__dataclass_fields__] if isinstance(entry, HankelKernel) else [entry]
    return sum(t.numel() * t.element_size() for t in tensors if isinstance(t, torch.Tensor))


def _cached(key, build):
    """LRU cache of kernels and output matrices, at most ``HANKEL_CACHE_ENTRIES`` and
    ``HANKEL_CACHE_BYTES``: an optimiser whose plan moves does not pile up stale ones."""
    if key in _HANKEL_CACHE:
        _HANKEL_CACHE.move_to_end(key)
    else:
        _HANKEL_CACHE[key] = build()
        while len(_HANKEL_CACHE) > 2 and (
            len(_HANKEL_CACHE) > HANKEL_CACHE_ENTRIES
            or sum(map(_entry_bytes, _HANKEL_CACHE.values())) > HANKEL_CACHE_BYTES
        ):
            _HANKEL_CACHE.popitem(last=False)
    return _HANKEL_CACHE[key]


def hankel_kernel(
    n: int,
    radius_m: float,
    aperture_radius_m: float,
    n_nodes: int,
    dtype: torch.dtype = torch.float64,
    device: str | torch.device = "cpu",
) -> HankelKernel:
    """The cached kernel for (n frequencies, R, a, n_nodes, dtype, device)."""
    key = ("kernel", n, float(radius_m), float(aperture_radius_m), n_nodes, dtype, str(device))

    def build() -> HankelKernel:
        j = bessel_j0_zeros(n)
        nu = j / (2 * math.pi * radius_m)
        r, dr = gauss_legendre_panels(aperture_radius_m, n_nodes)
        forward = _bessel_rows(torch.from_numpy(2 * math.pi * nu), torch.from_numpy(r), None, dtype, device)
        return HankelKernel(
            radius_m=float(radius_m),
            aperture_radius_m=float(aperture_radius_m),
            r=torch.from_numpy(r).to(device, dtype),
            weight=torch.from_numpy(2 * math.pi * r * dr).to(device, dtype),
            nu=torch.from_numpy(nu).to(device),
            coef_out=torch.from_numpy(1 / (math.pi * radius_m**2 * sps.j1(j) ** 2)).to(device, dtype),
            forward=forward,
        )

    return _cached(key, build)


def hankel_output_matrix(kernel: HankelKernel, radii_m: torch.Tensor) -> torch.Tensor:
    """The (len(radii) × n) matrix J0(2πν_m ρ)·c_m: the inverse transform at ``radii_m`` (m)."""
    return _bessel_rows(
        radii_m.double().cpu(),
        2 * math.pi * kernel.nu.cpu(),
        kernel.coef_out.double().cpu(),
        kernel.r.dtype,
        kernel.r.device,
    )


BESSEL_BLOCK = 1 << 22  # elements per block of J0 evaluations (32 MiB of float64 arguments)


def _bessel_rows(rows: torch.Tensor, cols: torch.Tensor, scale: torch.Tensor | None, dtype, device) -> torch.Tensor:
    """J0(rows[i]·cols[j])·scale[j] (float64 arguments) as a ``dtype`` matrix, built a block of
    rows at a time so that the float64 temporaries stay small beside the result."""
    out = torch.empty(len(rows), len(cols), dtype=dtype, device=device)
    block = max(1, BESSEL_BLOCK // max(len(cols), 1))
    for i in range(0, len(rows), block):
        values = torch.special.bessel_j0(rows[i : i + block, None] * cols[None, :])
        out[i : i + block] = (values if scale is None else values * scale).to(device, dtype)
    return out


def hankel_output_rows(kernel: HankelKernel, step_m: float, n_rows: int) -> torch.Tensor:
    """Cached :func:`hankel_output_matrix` at the radii k·``step_m``, k < ``n_rows``.

    The rows for fewer radii are a prefix of those for more, so one entry per (kernel, step)
    serves every window: a request within it is a view, a larger one builds only the missing
    rows, ``ROW_GROWTH`` times more than it has (a window that grows a little at every training
    step then costs a few extensions, not one per step).
    """
    key = ("rows", kernel.radius_m, kernel.nu.shape[0], kernel.r.dtype, str(kernel.r.device), float(step_m))
    have = _HANKEL_CACHE.get(key)
    if have is None or have.shape[0] < n_rows:
        start = 0 if have is None else have.shape[0]
        end = max(n_rows, math.ceil(ROW_GROWTH * start))
        new = hankel_output_matrix(kernel, torch.arange(start, end, dtype=torch.float64) * step_m)
        have = new if have is None else torch.cat([have, new])
        _HANKEL_CACHE.pop(key, None)
    return _cached(key, lambda: have)[:n_rows]


def clear_caches() -> None:
    """Drop every cached Hankel kernel and output-row matrix."""
    _HANKEL_CACHE.clear()


def real_matmul(mat: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
    """mat (a × b, real) @ z (b × c, complex) as one real product."""
    zr = torch.view_as_real(z).reshape(z.shape[0], -1)
    return torch.view_as_complex((mat @ zr).reshape(mat.shape[0], -1, 2).contiguous())


def radial_transfer(
    kernel: HankelKernel, wavelengths_m: torch.Tensor, distance_m: float, sin_limit: float | torch.Tensor
) -> torch.Tensor:
    """H(ν_m, λ) = exp(i·2π·d·√(1/λ² − ν_m²)) for ν_m ≤ sin_limit/λ, else 0; shape (n, len(λ)).
    ``sin_limit``: one value or one per wavelength.

    The limit plays the role of Matsushima's band limit: waves at larger angles would leave the
    support radius R and come back (the Fourier-Bessel series reflects them at R).
    """
    nu = kernel.nu.double()[:, None]
    lam = wavelengths_m.double().to(nu.device)[None, :]
    arg = (1.0 / lam**2 - nu**2).clamp(min=0)
    phase = torch.remainder(2 * math.pi * distance_m * torch.sqrt(arg), 2 * math.pi)
    limit = torch.as_tensor(sin_limit, dtype=torch.float64, device=nu.device)
    amp = (nu * lam <= limit).to(kernel.r.dtype)
    return torch.polar(amp, phase.to(kernel.r.dtype))


def radial_propagate(
    field_r: torch.Tensor, kernel: HankelKernel, transfer: torch.Tensor, out_matrix: torch.Tensor
) -> torch.Tensor:
    """Propagate radial fields by the quasi-discrete Hankel transform of order 0.

    All columns (wavelengths × depths) go through one matrix product per stage: the forward
    transform (quadrature weights applied), the transfer function, and the Fourier-Bessel
    series at the output radii.

    Args:
        field_r: complex radial fields, one column per (wavelength, depth), sampled at the nodes
            ``kernel.r`` (m).
        kernel: the Hankel kernel (``hankel_kernel``).
        transfer: H(ν_m, λ) from ``radial_transfer``, one column per field.
        out_matrix: the Fourier-Bessel series at the output radii, one row per radius.

    Returns:
        The complex fields at the radii of ``out_matrix``'s rows.

    Shape:
        - Input: ``field_r`` :math:`(Q, B)`, ``transfer`` :math:`(n, B)`, ``out_matrix`` :math:`(J, n)`
        - Output: :math:`(J, B)`
    """
    for name, value in (("field_r", field_r), ("transfer", transfer), ("out_matrix", out_matrix)):
        arguments.instance(value, name, torch.Tensor, "a tensor")
    arguments.instance(kernel, "kernel", HankelKernel, "a HankelKernel (hankel_kernel)")
    spec = real_matmul(kernel.forward, field_r * kernel.weight[:, None])
    return real_matmul(out_matrix, spec * transfer)


# ------------------------------------------------------------------------- Rayleigh-Sommerfeld


def rayleigh_sommerfeld(
    points_xy: torch.Tensor,
    values: torch.Tensor,
    wavelength_m: float,
    distance_m: float,
    out_xy: torch.Tensor,
    *,
    chunk: int = 1 << 22,
) -> torch.Tensor:
    """First Rayleigh-Sommerfeld solution by direct summation (exact kernel).

    U(P) = Σ_q values_q · (1/2π)·(d/r)·(1/r − ik)·exp(ikr)/r, r = |P − Q_q| with P at height d.

    Args:
        points_xy: input nodes (x, y) in m.
        values: complex field × quadrature weight (m²) at each node.
        wavelength_m: wavelength λ (m); k = 2π/λ.
        distance_m: propagation distance d (m).
        out_xy: output points (x, y) in m, on the plane at distance d.
        chunk: node-point pairs computed at a time (memory bound).

    Returns:
        The complex field U at each output point.

    Shape:
        - Input: ``points_xy`` :math:`(Q, 2)`, ``values`` :math:`(Q,)`, ``out_xy`` :math:`(P, 2)`
        - Output: :math:`(P,)`
    """
    for name, value in (("points_xy", points_xy), ("values", values), ("out_xy", out_xy)):
        arguments.instance(value, name, torch.Tensor, "a tensor")
    arguments.positive(wavelength_m, "wavelength_m")
    arguments.positive(distance_m, "distance_m")
    arguments.count(chunk, "chunk")
    k = 2 * math.pi / wavelength_m
    out = []
    step = max(1, chunk // max(points_xy.shape[0], 1))
    for start in range(0, out_xy.shape[0], step):
        p = out_xy[start : start + step]
        dx = p[:, None, 0] - points_xy[None, :, 0]
        dy = p[:, None, 1] - points_xy[None, :, 1]
        r = torch.sqrt(dx**2 + dy**2 + distance_m**2)
        kernel = (distance_m / (2 * math.pi)) / r**2 * torch.complex(1 / r, -k * torch.ones_like(r))
        kernel = kernel * torch.polar(torch.ones_like(r), torch.remainder(k * r, 2 * math.pi))
        out.append(kernel @ values)
    return torch.cat(out)
