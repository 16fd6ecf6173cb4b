"""Fast RCWA of the rectangular nanofin (optics.nanofin's meta-atom) using its two mirror symmetries.

Same geometry, inputs and outputs as :func:`metalens_cli.optics.nanofin.fin_response`: a fin of
complex index n + ik, width w along x, length l along y, height h, in a square cell of period p,
lit at normal incidence from a lossless substrate (its real index) into air.

Units and conventions. Lengths in metres at the interface; inside, coordinates are scaled by
k0 = 2π/λ (transverse wave numbers kx = m·λ/p, the height as k0·h) and H by the vacuum impedance,
so that ∇×E = iH and ∇×H = −iεE. Fields vary as e^{−iωt}: a loss is n + ik, an upward wave
(substrate → air, +z) is e^{+i·kz·z} with Im kz ≥ 0. Orders m, n = −(N−1)/2 … (N−1)/2 along x
and y. Jones coefficients, η = |t_xx − t_yy|²/4, T and R: as in optics.nanofin.

Factorisation (Li 1997, JOSA A 14, 2758). The fin is a rectangle of ε in air: along y two bands
(the fin's x-profile for |y| < l/2, air elsewhere), along x likewise. The matrix for εE_x uses the
inverse rule along x (the inverse of the Toeplitz matrix of 1/ε of the x-profile) and the
Laurent rule along y; the one for εE_y the converse; E_z, continuous across every wall, is the
inverse of the 2-D Laurent (Toeplitz) matrix of ε applied to D_z. The construction treats x and y
alike: a square fin converts nothing and a fin turned by 90° swaps t_xx and t_yy, to rounding.
The choice for E_z matters: with the Toeplitz matrix of 1/ε instead, η of the paper's fin at
530 nm is still 1.1e-2 high at N = 31; with this one it is within 1.3e-3 of its limit from N = 13.

Layer. The transverse E field obeys d²E/dz² = −Ω²E, Ω² = P·Q; its eigenvectors are the modes
e^{±i·kz·z}. Up-going amplitudes are referenced at the layer's bottom face and down-going ones at
its top face, so only the factors e^{i·kz·k0h} (|·| ≤ 1) appear and a thick layer with evanescent
modes stays stable; matching tangential E and H on both faces gives one linear system (2 × the
modes) for the mode amplitudes, whence the reflected and transmitted orders.

Symmetry reduction. The mirrors x → −x and y → −y map the structure onto itself. x-polarised
light excites only fields with E_x even in x and in y and E_y odd in both (Fourier coefficients
E_x[m, n] = E_x[−m, n] = E_x[m, −n], E_y[m, n] = −E_y[−m, n] = −E_y[m, −n]; then H_x has E_y's
parity, H_y E_x's, E_z is odd in x and even in y). Keeping E_x for m, n ≥ 0 and E_y for m, n ≥ 1
leaves (N² + 1)/2 unknowns instead of 2N²: two eigenproblems 4x smaller in place of one (~30x
fewer operations). y-polarised light on the fin (w, l) is x-polarised light on the fin (l, w)
mirrored across the diagonal, so every solve is the same kind of problem, batched over
wavelengths, both polarisations and any number of fins. For a lossless fin Ω² is real and its
eigenproblem is solved in real arithmetic (2x faster).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from metalens_cli.optics.fin import Fin, FinResponse, check_harmonics

CHUNK_ELEMENTS = 500_000  # problems per batch × unknowns²: ~8 MB per batched matrix (30% faster than 64 MB)
COMPLEX = torch.complex128


@dataclass(frozen=True)
class _Axis:
    """A Fourier basis along one axis: the kept orders' positions ``keep`` among the N, and
    ``extend`` (N × kept), which maps kept coefficients to all N (mirror images with the parity's
    sign)."""

    keep: torch.Tensor
    extend: torch.Tensor


def _axis(harmonics: int, parity: int, device) -> _Axis:
    """Orders along one axis: parity +1 even (m ≥ 0 kept), −1 odd (m ≥ 1), 0 all (no symmetry)."""
    half = (harmonics - 1) // 2
    if parity == 0:
        return _Axis(torch.arange(harmonics, device=device), torch.eye(harmonics, dtype=COMPLEX, device=device))
    orders = range(0 if parity > 0 else 1, half + 1)
    extend = torch.zeros(harmonics, len(orders), dtype=COMPLEX)
    for j, m in enumerate(orders):
        extend[half + m, j] = 1
        if m:
            extend[half - m, j] = parity
    return _Axis(torch.tensor([half + m for m in orders], dtype=torch.long, device=device), extend.to(device))


@dataclass(frozen=True)
class _Component:
    """A field component's 2-D basis: its ``y`` and ``x`` axes (y outer in the flat order)."""

    y: _Axis
    x: _Axis

    @property
    def size(self) -> int:
        return len(self.y.keep) * len(self.x.keep)

    def extend(self) -> torch.Tensor:
        """(N² × size): the kept coefficients → all N × N orders."""
        return torch.kron(self.y.extend, self.x.extend)

    def sample(self, grid: torch.Tensor) -> torch.Tensor:
        """(..., size): a (..., N, N) grid over orders [n, m] at the kept orders."""
        return grid[..., self.y.keep, :][..., self.x.keep].flatten(-2)


@dataclass(frozen=True)
class _Fields:
    """Bases of E_x, E_y and E_z; H_x shares E_y's, H_y E_x's (H-space rows: H_x then H_y)."""

    ex: _Component
    ey: _Component
    ez: _Component


def _fields(harmonics: int, symmetric: bool, device) -> _Fields:
    """The x-polarised symmetric subspace (E_x even-even, E_y odd-odd, E_z odd in x, even in y),
    or all orders of every component."""
    even, odd = (_axis(harmonics, parity, device) for parity in ((1, -1) if symmetric else (0, 0)))
    return _Fields(_Component(even, even), _Component(odd, odd), _Component(even, odd))


def _kron(along_y: torch.Tensor, along_x: torch.Tensor) -> torch.Tensor:
    """Batched Kronecker product, y the outer index."""
    rows = along_y.shape[-2] * along_x.shape[-2]
    cols = along_y.shape[-1] * along_x.shape[-1]
    product = along_y[..., :, None, :, None] * along_x[..., None, :, None, :]
    return product.reshape(*product.shape[:-4], rows, cols)


def _convolution(out: _Component, inp: _Component, along_y: torch.Tensor, along_x: torch.Tensor) -> torch.Tensor:
    """The operator along_y ⊗ along_x ((…, N, N) each) from ``inp``'s basis to ``out``'s."""
    return _kron(along_y[..., out.y.keep, :] @ inp.y.extend, along_x[..., out.x.keep, :] @ inp.x.extend)


def _diagonal(out: _Component, inp: _Component, grid: torch.Tensor) -> torch.Tensor:
    """The operator multiplying order (m, n) by grid[..., n, m], from ``inp``'s basis to ``out``'s."""
    select = torch.kron(inp.y.extend[out.y.keep], inp.x.extend[out.x.keep])
    return out.sample(grid)[..., :, None] * select


def _blocks(rows: list[list[torch.Tensor]]) -> torch.Tensor:
    return torch.cat([torch.cat(row, dim=-1) for row in rows], dim=-2)


def _rect(fraction: torch.Tensor, harmonics: int) -> torch.Tensor:
    """(B, N, N) Toeplitz matrices of the Fourier coefficients of a centred rectangle of width
    ``fraction`` (B,) of the period: c_k = fraction·sinc(k·fraction)."""
    orders = torch.arange(harmonics, device=fraction.device, dtype=torch.float64)
    k = orders[:, None] - orders[None, :]
    return (fraction[:, None, None] * torch.sinc(k * fraction[:, None, None])).to(COMPLEX)


def _q_matrix(f: _Fields, kx: torch.Tensor, ky: torch.Tensor, eps_x: torch.Tensor, eps_y: torch.Tensor) -> torch.Tensor:
    """Q with dH/dz = iQ·E (rows H_x, H_y; columns E_x, E_y); ``eps_x`` maps E_x to D_x (into
    H_y's basis), ``eps_y`` E_y to D_y (into H_x's)."""
    hx, hy = f.ey, f.ex
    return _blocks(
        [
            [_diagonal(hx, f.ex, -kx * ky), _diagonal(hx, f.ey, kx**2) - eps_y],
            [eps_x - _diagonal(hy, f.ex, ky**2), _diagonal(hy, f.ey, kx * ky)],
        ]
    )


def _p_matrix(f: _Fields, kx: torch.Tensor, ky: torch.Tensor, ez_inverse: torch.Tensor) -> torch.Tensor:
    """P with dE/dz = iP·H (rows E_x, E_y; columns H_x, H_y), E_z = ez_inverse·(k_y H_x − k_x H_y)."""
    hx, hy = f.ey, f.ex
    ones, zeros = torch.ones_like(kx), torch.zeros_like(kx)
    ez_from_h = ez_inverse @ torch.cat([_diagonal(f.ez, hx, ky), -_diagonal(f.ez, hy, kx)], dim=-1)
    e_from_ez = torch.cat([_diagonal(f.ex, f.ez, kx), _diagonal(f.ey, f.ez, ky)], dim=-2)
    turn = _blocks(
        [
            [_diagonal(f.ex, hx, zeros), _diagonal(f.ex, hy, ones)],
            [-_diagonal(f.ey, hx, ones), _diagonal(f.ey, hy, zeros)],
        ]
    )
    return turn + e_from_ez @ ez_from_h


def _batched(function, *arrays: torch.Tensor) -> torch.Tensor:
    """``function`` (``torch.linalg.inv`` or ``solve``) over a batch of problems. On the CPU one
    problem at a time: torch's batched LU there calls LAPACK's getrf from several threads at
    once, which MKL does not allow (pytorch/pytorch#142815: after ``torch.set_num_threads``,
    invalid pivots, errors or wrong results; tests/optics/test_fin_modes.py)."""
    if arrays[0].device.type != "cpu":
        return function(*arrays)
    return torch.stack([function(*(a[i] for a in arrays)) for i in range(arrays[0].shape[0])])


def _layer_matrices(f: _Fields, kx, ky, eps, width, length, harmonics):
    """P and Q of the fin layer (``eps`` (B,) the fin's permittivity, ``width``, ``length`` (B,)
    fractions of the period), with Li's rules (module docstring)."""
    eye = torch.eye(harmonics, dtype=COMPLEX, device=eps.device)
    ones = torch.ones_like(kx)
    tx, ty = _rect(width, harmonics), _rect(length, harmonics)
    contrast = (1 / eps - 1)[:, None, None]
    inverse_x = _batched(torch.linalg.inv, eye + contrast * tx) - eye  # inverse rule along x, less air's
    inverse_y = _batched(torch.linalg.inv, eye + contrast * ty) - eye
    eps_x = _diagonal(f.ex, f.ex, ones) + _convolution(f.ex, f.ex, ty, inverse_x)
    eps_y = _diagonal(f.ey, f.ey, ones) + _convolution(f.ey, f.ey, inverse_y, tx)
    laurent = _diagonal(f.ez, f.ez, ones) + (eps - 1)[:, None, None] * _convolution(f.ez, f.ez, ty, tx)
    return _p_matrix(f, kx, ky, _batched(torch.linalg.inv, laurent)), _q_matrix(f, kx, ky, eps_x, eps_y)


def _half_space(f: _Fields, kx, ky, eps):
    """A homogeneous half-space of real permittivity ``eps`` (B,): the admittance V (H = V·E of
    the up-going orders) and which orders propagate (B, N, N)."""
    kz2 = eps[:, None, None] - kx**2 - ky**2
    kz = torch.sqrt(kz2.to(COMPLEX))  # i·|kz| where evanescent
    kz = torch.where(kz.abs() < 1e-9, 1e-9j, kz)  # a grazing order (Rayleigh anomaly): its limit, not 1/0
    ones = torch.ones_like(kx)
    e = eps.to(COMPLEX)[:, None, None]
    q = _q_matrix(f, kx, ky, e * _diagonal(f.ex, f.ex, ones), e * _diagonal(f.ey, f.ey, ones))
    kz_e = torch.cat([f.ex.sample(kz), f.ey.sample(kz)], dim=-1)
    return q / kz_e[..., None, :], kz2 > 0


def _flux(f: _Fields, e: torch.Tensor, h: torch.Tensor, propagating: torch.Tensor) -> torch.Tensor:
    """(B, r): the z-flux Σ Re(E_x H_y* − E_y H_x*) over the propagating orders, of fields e, h
    (B, unknowns, r) in the reduced bases."""
    nx = f.ex.size
    ex, ey = f.ex.extend() @ e[:, :nx], f.ey.extend() @ e[:, nx:]
    hx, hy = f.ey.extend() @ h[:, : f.ey.size], f.ex.extend() @ h[:, f.ey.size :]
    density = (ex * hy.conj() - ey * hx.conj()).real
    return (density * propagating.flatten(-2)[..., None]).sum(dim=-2)


def _solve(f: _Fields, harmonics: int, period_wl, thickness_k0, width, length, eps, eps_sub, incident):
    """Zeroth transmitted order (B, r, 2: E_x, E_y), T and R (B, r) of B problems (each argument
    (B,): p/λ, k0·h, w/p, l/p, fin and substrate permittivities) for the r incident fields
    ``incident`` (unknowns, r) of unit amplitude."""
    orders = torch.arange(harmonics, device=eps.device, dtype=torch.float64) - (harmonics - 1) // 2
    kx = (orders[None, None, :] / period_wl[:, None, None]).expand(-1, harmonics, -1)
    ky = kx.transpose(-1, -2)
    p, q = _layer_matrices(f, kx, ky, eps, width, length, harmonics)
    omega2 = p @ q
    kz2, w = torch.linalg.eig(omega2 if omega2.imag.any() else omega2.real)  # real for a lossless fin: 2x faster
    kz = torch.sqrt(kz2)
    kz = torch.where(kz.imag < 0, -kz, kz)  # up-going: decaying or propagating upwards
    v = q @ w / kz[:, None, :]
    x = torch.exp(1j * kz * thickness_k0[:, None])[:, None, :]
    v_sub, up_sub = _half_space(f, kx, ky, eps_sub)
    v_air, up_air = _half_space(f, kx, ky, torch.ones_like(eps_sub))
    system = _blocks([[v_sub @ w + v, v_sub @ (w * x) - v * x], [v_air @ (w * x) - v * x, v_air @ w + v]])
    inc = incident.expand(len(eps), -1, -1)
    amplitudes = _batched(torch.linalg.solve, system, torch.cat([2 * v_sub @ inc, torch.zeros_like(inc)], dim=-2))
    up, down = amplitudes.split(w.shape[-1], dim=-2)
    t = (w * x) @ up + w @ down
    r = w @ up + (w * x) @ down - inc
    zeroth = (harmonics * harmonics - 1) // 2
    t0 = torch.stack(
        [(f.ex.extend() @ t[:, : f.ex.size])[:, zeroth], (f.ey.extend() @ t[:, f.ex.size :])[:, zeroth]], dim=-1
    )
    power = _flux(f, inc, v_sub @ inc, up_sub)
    return t0, _flux(f, t, v_air @ t, up_air) / power, _flux(f, r, v_sub @ r, up_sub) / power


def _incident(f: _Fields, harmonics: int, polarisations: str, device) -> torch.Tensor:
    """(unknowns, r): unit zeroth-order E_x (polarisation "x") or E_y ("y") fields."""
    zeroth = torch.zeros(harmonics, harmonics, dtype=COMPLEX, device=device)
    zeroth[(harmonics - 1) // 2, (harmonics - 1) // 2] = 1
    columns = []
    for pol in polarisations:
        ex, ey = (zeroth if pol == axis else torch.zeros_like(zeroth) for axis in "xy")
        columns.append(torch.cat([f.ex.sample(ex), f.ey.sample(ey)]))
    return torch.stack(columns, dim=-1)


def _sides(fin: Fin, turned: bool) -> tuple[float, float]:
    """The fin's extents along x and y as fractions of the period, swapped if ``turned``."""
    sides = (fin.width_m / fin.period_m, fin.length_m / fin.period_m)
    return sides[::-1] if turned else sides


def fin_responses_symmetric(
    fins: Sequence[Fin],
    fin_index: np.ndarray,
    substrate_index: np.ndarray,
    wavelengths_m,
    harmonics: int,
    device=None,
    symmetric: bool = True,
) -> list[FinResponse]:
    """:func:`fin_response_symmetric` for several fins at once (all wavelengths and fins in one
    batch); ``seconds`` is the whole wall time over fins × wavelengths."""
    start = time.perf_counter()
    check_harmonics(harmonics)
    wavelengths = np.atleast_1d(np.asarray(wavelengths_m, dtype=float))
    n_fin = np.broadcast_to(np.asarray(fin_index, dtype=complex), wavelengths.shape)
    n_sub = np.broadcast_to(np.asarray(substrate_index, dtype=complex).real, wavelengths.shape)
    turns = (False, True) if symmetric else (False,)  # y-polarised = x-polarised on the fin turned
    rows = [
        (fin.period_m / lam, 2 * np.pi * fin.height_m / lam, *_sides(fin, turned), n_fin[k] ** 2, n_sub[k] ** 2)
        for fin in fins
        for turned in turns
        for k, lam in enumerate(wavelengths)
    ]
    f = _fields(harmonics, symmetric, device)
    incident = _incident(f, harmonics, "x" if symmetric else "xy", device)
    columns = [torch.tensor(np.array(column), device=device) for column in zip(*rows)]
    chunk = max(1, CHUNK_ELEMENTS // (f.ex.size + f.ey.size) ** 2)
    parts = [
        _solve(f, harmonics, *(c[first : first + chunk] for c in columns), incident=incident)
        for first in range(0, len(rows), chunk)
    ]
    shape = (len(fins), len(turns), len(wavelengths), incident.shape[-1])
    t0, trans, refl = (torch.cat(part).cpu().numpy().reshape(*shape, -1) for part in zip(*parts))
    if symmetric:  # x incidence on the fin, then on the turned fin (y incidence)
        t_xx, t_yy = t0[:, 0, :, 0, 0], t0[:, 1, :, 0, 0]
    else:  # x and y incidence on the fin
        t_xx, t_yy = t0[:, 0, :, 0, 0], t0[:, 0, :, 1, 1]
    trans, refl = (power.mean(axis=(1, 3, 4)) for power in (trans, refl))  # unpolarised: mean over x and y
    scale = np.sqrt(1.0 / n_sub)  # √(n_out/n_in): field ratio → power amplitude
    t_xx, t_yy = t_xx * scale, t_yy * scale
    seconds = np.full(wavelengths.shape, (time.perf_counter() - start) / (len(fins) * len(wavelengths)))
    return [
        FinResponse(
            wavelengths,
            t_xx[i],
            t_yy[i],
            np.abs(t_xx[i] - t_yy[i]) ** 2 / 4,
            np.abs(t_xx[i] + t_yy[i]) ** 2 / 4,
            trans[i],
            refl[i],
            harmonics,
            seconds,
        )
        for i in range(len(fins))
    ]


def fin_response_symmetric(
    fin: Fin,
    fin_index: np.ndarray,
    substrate_index: np.ndarray,
    wavelengths_m,
    harmonics: int,
    device=None,
    symmetric: bool = True,
) -> FinResponse:
    """The Jones coefficients and efficiencies of ``fin`` at each wavelength (metres), with complex
    indices ``fin_index`` and ``substrate_index`` (one per wavelength, n + ik, k ≥ 0 for loss;
    the substrate's real part is used) and N = ``harmonics`` Fourier orders per axis: the meaning
    of :func:`metalens_cli.optics.nanofin.fin_response`. ``device``: a torch device (None: cpu).
    ``symmetric=False`` solves the full 2N² eigenproblem instead of the two symmetric subspaces
    (for checking; ~12x slower at N = 17)."""
    return fin_responses_symmetric([fin], fin_index, substrate_index, wavelengths_m, harmonics, device, symmetric)[0]
