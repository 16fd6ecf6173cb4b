"""Image formation with PSFs that vary over the field of a rotationally symmetric lens.

The field model. A :class:`FieldPsfSet` holds the PSFs P_k of the image points at heights h_k
(pixels) along the sensor's +x axis from the optical-axis pixel; rows are y (down), columns x,
and the axis is the sensor's centre pixel (H//2, W//2). The unit-sum PSF of the image point at
x = ρ(cos ψ, sin ψ) from the axis is (:func:`field_psf`)

    P_x = P̂(c·P_0 + R_ψ[P_ρ − c·P_0]),   c = ⟨P_ρ, P_0⟩ / ⟨P_0, P_0⟩ (per channel)

with P_ρ linear in ρ between the two nearest heights (the last one beyond them: the sensor's
corners if the set stops short), P̂ the division by the sum and R_ψ the rotation by ψ about the
window's centre pixel, Q ↦ Q(R(−ψ)·), by bicubic resampling (Keys, a = −0.75; zero outside the
window; exact at multiples of 90°, within 2-4 % (relative L2) of a rotated Gaussian of σ ≈ 1 px
elsewhere, slightly negative beside sharp detail). The part of P_ρ along the on-axis PSF P_0
(rotationally symmetric for such a lens) is not resampled: the sharp core at the chief ray stays
sharp, the field is continuous at the axis, and identical symmetric PSFs at every height give
that PSF everywhere.

Gather form. A capture is out(x) = Σ_s P_x(x − s)·in(s), the PSF of the image point at the
*output* pixel: a uniform scene stays uniform, full opaque coverage gives α = 1, and a uniform
field is :func:`formation.form_image` exactly, whatever the PSFs. The scatter form
Σ_s P_s(x − s)·in(s) (the PSF of the source point, which keeps energy instead) differs from it at
first order in the PSF's change across its own width. Measured once on a stand-in for the paper's
f/1.6 lens (geometric ray trace, f = 4 mm, D = 2.516 mm, 512² sensor of 1.85 µm pixels; far coma
up to ~80 px at the corners, its centroid drifting 0.05 px per px of height): the far blurs of a
dead-leaves scene differ by 8.7 % (relative L2), and the scatter form darkens a grey wall by up to
11 % at the edges, 2 × 0.05 from the drift, which acts as a distortion there.

Fast method: a tiled eigen-PSF (low-rank) expansion in gather form. The sensor is cut into square
tiles (:func:`tile_side`: about 0.6·N, 64 px for N = 101, 128 for N = 201) and each pixel takes
the expansion of its own tile t (a hard partition: the gather form needs no blending),

    P_x ≈ P̄_t + Σ_r a_tr(x)·e_tr,   out = P̄_t ∗ in + Σ_r a_tr ⊙ (e_tr ∗ in)   on tile t,

per colour channel, each convolution on the tile's own canvas (FFTs of about its side + N for
P̄_t, its side + S for the e_tr). P̄_t is the mean of P_x over ``SUPPORT_NODES``² nodes of the
tile (whole N × N windows), e_tr the principal components of P_x − P̄_t over the tile's pixels,
restricted to the central S × S pixels (:func:`eigen_support`: the smallest window that leaves
out at most ``SUPPORT_SHARE`` of the tolerance). A learned lens's PSF is ~1000 px wide for its
halo, but its field dependence lies within a few hundred: on the quick split-spectrum lens at
5 m, a 401-px window leaves out 0.16 % (relative L2) of it, so the eigen-PSFs' FFTs and memory
shrink ~8×. Each e_tr is even or odd under y → −y (a mirror-symmetric set gives
mirror-symmetric captures exactly on a tile symmetric about the axis row) and of zero sum (the
invariants above hold exactly at any rank). Kept are the components of largest pixel energy
(below) over all tiles and channels (the least error per FFT), as many as ``tolerance`` needs.

Windows (:func:`_windows`). S holds the widest eigen-PSF, but most are compact (on the paper's
hyperbolic lens at 45 mm half hold all but 10⁻³ of their squared norm within 157 of the 333
px). Each one is cut to its own central
window, one of a few sides whose FFT grids (:func:`_basis_grid`, tile + side, lengths with a
factor of 8) shrink in area by ``WINDOW_STEP``, less its mean there (zero sum and parity kept),
chosen for the least FFT work whose cuts cost the PSF field at most ``WINDOW_SHARE`` of the
tolerance; each window's eigen-PSFs go through FFTs of their own size. Their spectra are stored
transposed, so the inverse transform's first pass runs along contiguous memory and its second
only over the tile's rows (their cost against one window: docs/benchmarks.md).

Nodes (:func:`_tile_nodes`). The field model is linear in height between the set's heights, so
P_x = (1 − w)·P(h_{k−1}, ψ) + w·P(h_k, ψ) exactly (before the sum's normalisation): the
principal components are taken over the PSFs of the on-axis point and of azimuths ψ_j on each
height the tile uses, weighed by the pixels each stands for, and a_tr(x) = ⟨P_x − P̄_t, e_tr⟩ is
linear along the radius and Keys-cubic in azimuth between them. The azimuths are as close as
turns the support's rim (S//2 px from the chief ray) by ``NODE_STEP`` px. A grid of nodes in x,
y cannot follow a wide PSF near the axis, where a step of a few pixels turns it by many degrees:
on the quick split-spectrum lens's near set (45 mm, S = 481), nodes 8 px apart left 2.5 % of
interpolation error against a 1 % tolerance. The tiles are halved where a channel's node PSFs
would pass ``NODE_VALUES``.

The error is the relative L2 error of the PSF field over the sensor's pixels,
(Σ_x ‖P̃_x − P_x‖² / Σ_x ‖P_x‖²)^½ over all channels: that of the capture of a zero-mean
white-noise scene, an upper bound for smoother ones. It is estimated from the components left
out, each by its squared norm summed over the tile's pixels through the interpolation of its
coefficients (:func:`_pixel_energies`; kept are the largest of these), then measured at
``CHECK_PIXELS`` random pixels (:attr:`FieldTransform.error`), adding components or halving the
azimuth step until it is within ``CHECK_MARGIN`` of the tolerance. Each component costs one
inverse FFT of its tile on its window's grid per plane: twice for the near PSF (the obstruction
light and the mask).

Why tiles: over the whole sensor the coma turns through every azimuth and its spectrum spreads;
on the paper's lens one expansion for the sensor needed 3× the FFT work of tiles at the same error,
and interpolating node PSFs (overlap-add) needs nodes 5 px apart for 1 % on the far PSFs, 3× the
work again. The measurements behind these choices (eigen-PSF counts, errors, preparation and
capture times on a stand-in, the hyperbolic and the split-spectrum lens) are in docs/benchmarks.md.

Every function here is pure torch (batched, differentiable in the images, any device); the field
transforms are fixed once made (no gradient to the PSFs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from metalens_cli import arguments
from metalens_cli.errors import InputError
from metalens_cli.imaging.formation import (
    Capture,
    PsfTransform,
    _canvas_spectrum,
    _composite,
    _kept,
    _obstruction_canvases,
    _placed,
    _sensor_hw,
    canvas_margin,
    check_capture_inputs,
    psf_transform,
    unit_sum,
)
from metalens_cli.optics.propagate import fft_size

DEFAULT_TOLERANCE = 0.01  # relative L2 of the PSF field
NODE_STEP = 1.0  # at most this many pixels the eigen-PSFs' support rim turns between azimuth nodes
MIN_NODE_STEP = 0.25  # the finest azimuth step (pixels at the rim) a refinement goes to
KEYS = -0.5  # the cubic convolution kernel's a: Keys' third-order accurate one
CHECK_PIXELS = 256  # random pixels at which the error is measured
CHECK_MARGIN = 0.95  # accept at this fraction of the tolerance: the check's estimate scatters by a few %
TARGET_SHARE = 0.85  # of the tolerance, the error aimed at: the first truncation's; support, windows beside it
MAX_REFINEMENTS = 4  # rank or azimuth-node refinements after the first try
CHUNK_VALUES = 2**19  # spectrum values per batched inverse FFT of eigen-PSF terms
NODE_CHUNK_VALUES = 2**25  # PSF values of the nodes resampled at a time
SUPPORT_SHARE = 0.3  # of the tolerance, the most the eigen-PSFs' support may leave out (relative L2)
SUPPORT_NODES = 5  # nodes per tile side on which the support is chosen
WINDOW_SHARE = 0.25  # of the tolerance, the most the eigen-PSFs' own smaller windows may leave out (relative L2)
WINDOW_STEP = 0.7  # each smaller window's FFT grid has at most this share of the next larger one's area
KEEP_SHARE = 0.4  # of the tolerance: a tile's analysis keeps the components each channel needs for its share of this
ROW_BLOCK_VALUES = 2**24  # residual values per block of rows in a Gram product
NODE_VALUES = 2**28  # node PSF values of one channel a tile's analysis holds (1 GiB in float32), else smaller tiles


@dataclass(frozen=True)
class FieldPsfSet:
    """PSFs of a rotationally symmetric lens at one depth, sampled along the sensor's +x axis.

    Other azimuths are rotations of these (module docstring). Checked when built.

    Attributes:
        heights_px: chief-ray positions, pixels from the optical-axis pixel along +x, ascending,
            the first 0.
        psfs: (K, C, N, N), one per height, N odd, the chief-ray pixel at (N//2, N//2); any
            normalisation (each is divided by its sum).
    """

    heights_px: tuple[int, ...]
    psfs: torch.Tensor

    def __post_init__(self):
        listed = arguments.instance(self.heights_px, "heights_px", (tuple, list), "pixel heights, e.g. (0, 40, 80)")
        heights = tuple(arguments.count(h, "heights_px", lo=0) for h in listed)
        arguments.instance(self.psfs, "psfs", torch.Tensor, "a (K, C, N, N) tensor of PSFs")
        arguments.array(self.psfs, "psfs", form="PSFs (K, C, N, N)")
        if (
            not heights
            or heights[0] != 0
            or any(b <= a for a, b in zip(heights, heights[1:]))
            or any(h != int(h) for h in self.heights_px)
        ):
            raise InputError("heights_px", f"{self.heights_px!r}", "ascending pixel heights starting at 0")
        shape = tuple(self.psfs.shape)
        if len(shape) != 4 or shape[0] != len(heights) or shape[-1] != shape[-2] or shape[-1] % 2 == 0:
            raise InputError("psfs", f"shape {shape} for {len(heights)} heights", "(K, C, N, N) PSFs, N odd")
        object.__setattr__(self, "heights_px", heights)


def field_psf(psf_set: FieldPsfSet, x: torch.Tensor, y: torch.Tensor, support: int | None = None) -> torch.Tensor:
    """Unit-sum PSFs (..., C, N, N) of the image points at offsets ``x``, ``y`` (...) pixels from
    the optical-axis pixel (x right, y down), by the field model of the module docstring.

    ``support``: only their central S × S pixels (S odd), resampled there alone; the sum that
    normalises them is then taken before the rotation, which keeps it to the resampling's error."""
    p = unit_sum(psf_set.psfs)
    x = torch.as_tensor(x, dtype=p.dtype, device=p.device)
    y = torch.as_tensor(y, dtype=p.dtype, device=p.device)
    x, y = torch.broadcast_tensors(x, y)
    shape = x.shape
    x, y = x.reshape(-1), y.reshape(-1)
    axis = p[0]
    size = axis.shape[-1] if support is None else support
    out_shape = (*shape, axis.shape[0], size, size)
    if len(psf_set.heights_px) == 1:
        return _cropped(axis, size).expand(len(x), *axis.shape[:-2], size, size).reshape(out_shape).clone()
    heights = torch.tensor(psf_set.heights_px, dtype=p.dtype, device=p.device)
    rho = torch.hypot(x, y).clamp(max=heights[-1])
    i = torch.searchsorted(heights, rho, right=True).clamp(1, len(heights) - 1)
    w = ((rho - heights[i - 1]) / (heights[i] - heights[i - 1])).clamp(0, 1)[:, None, None, None]
    if support is None:
        radial = p[i - 1] * (1 - w) + p[i] * w
        along = (radial * axis).sum((-2, -1), keepdim=True) / (axis * axis).sum((-2, -1), keepdim=True)
        rotated = _rotated(radial - along * axis, torch.atan2(y, x))
        return unit_sum(along * axis + rotated).reshape(out_shape)
    # on the support alone: the same sum, each height's part rotated separately (R_ψ is linear),
    # so no whole N × N window is made per point; the unit-sum heights keep the sum at 1
    a = (p * axis).sum((-2, -1), keepdim=True) / (axis * axis).sum((-2, -1), keepdim=True)  # (K, C, 1, 1)
    varying, w = p - a * axis, w[:, 0, 0, 0]
    grid = _rotation_grid(torch.atan2(y, x), size, axis.shape[-1])
    out = (a[i - 1] * (1 - w[:, None, None, None]) + a[i] * w[:, None, None, None]) * _cropped(axis, size)
    for k in torch.unique(torch.cat([i - 1, i])).tolist():
        weight = torch.where(i - 1 == k, 1 - w, 0) + torch.where(i == k, w, 0)
        at = (weight != 0).nonzero()[:, 0]
        if k == 0 or not len(at):  # the axis's own part along itself is all of it
            continue
        folded = grid[at].reshape(1, -1, size, 2)  # every point's grid, one after another
        sampled = F.grid_sample(varying[k][None], folded, mode="bicubic", padding_mode="zeros", align_corners=True)
        sampled = sampled[0].unflatten(1, (len(at), size)).transpose(0, 1)  # (points, C, S, S)
        out[at] += weight[at, None, None, None] * sampled
    return out.reshape(out_shape)


def height_check(psf_set: FieldPsfSet) -> dict:
    """How well the model interpolates between the set's heights, from the set alone: each interior
    height left out, its unit-sum PSFs against :func:`field_psf` of the set without it there (an
    interpolation across twice the step). ``error``: per interior height (``heights_px``) the
    relative L2 per channel, a white-noise scene's (the metric of the tolerance). Where the PSFs
    change smoothly with height this is about 4× the model's error midway between heights; where
    their detail moves by more than its own width, about that error. On the paper's hyperbolic lens
    (512², 5 m) it gave 35/45/77 % (R/G/B) at 91 px and 40/43/47 % at 272 px, against 9/54/53 % and
    46/29/41 % measured midway in the first and last intervals (docs/field.md, "Between the
    heights"): 0.8-1.5×, 3.9× in the red of the first, where the PSF changes smoothly."""
    heights, errors = psf_set.heights_px, []
    for k in range(1, len(heights) - 1):
        rest = FieldPsfSet(heights[:k] + heights[k + 1 :], torch.cat([psf_set.psfs[:k], psf_set.psfs[k + 1 :]]))
        model = field_psf(rest, torch.tensor(float(heights[k])), torch.tensor(0.0)).double()
        true = unit_sum(psf_set.psfs[k]).double()
        errors.append(((model - true).norm(dim=(-2, -1)) / true.norm(dim=(-2, -1))).tolist())
    return {"heights_px": list(heights[1:-1]), "error": errors}


def _cropped(psfs: torch.Tensor, support: int) -> torch.Tensor:
    """The central ``support`` × ``support`` pixels of (..., N, N) windows (N, support odd)."""
    a = (psfs.shape[-1] - support) // 2
    return psfs[..., a : a + support, a : a + support]


def _rotation_grid(psi: torch.Tensor, size: int, n: int) -> torch.Tensor:
    """grid_sample's grid (B, S, S, 2) that samples an N × N window at the central S × S pixels
    rotated by ψ (B,) about pixel (N//2, N//2)."""
    c, s = torch.cos(psi)[:, None, None], torch.sin(psi)[:, None, None]
    k = torch.arange(size, dtype=psi.dtype, device=psi.device) - size // 2
    dy, dx = torch.meshgrid(k, k, indexing="ij")
    half = n // 2  # odd N: pixel i of the window sits at −1 + i/half in grid_sample's coordinates
    return torch.stack([c * dx + s * dy, c * dy - s * dx], dim=-1) / half


def _rotated(q: torch.Tensor, psi: torch.Tensor) -> torch.Tensor:
    """R_ψ q: q (B, C, N, N) rotated by ψ (B,) about pixel (N//2, N//2), sampled bicubically."""
    grid = _rotation_grid(psi.to(q.dtype), q.shape[-1], q.shape[-1])
    return F.grid_sample(q, grid, mode="bicubic", padding_mode="zeros", align_corners=True)


@dataclass(frozen=True)
class EigenBasis:
    """Eigen-PSFs of one window side S = 2·``margin`` + 1 transformed for tiles of ``sensor_hw``:
    ``spectrum`` (terms, L1 // 2 + 1, L0), the rfft2 of each kernel placed on the FFT grid
    ``fft_shape`` (L0, L1) with its centre pixel at (0, 0), stored transposed
    (the inverse transform's first, pruned pass then runs along contiguous memory)."""

    spectrum: torch.Tensor
    sensor_hw: tuple[int, int]
    margin: int
    fft_shape: tuple[int, int]


@dataclass(frozen=True)
class FieldTransform:
    """A field PSF set prepared for H × W sensor images (:func:`field_transform`).

    The sensor is cut into tiles of ``mean.sensor_hw`` whose top-left pixels are every
    combination of ``tile_rows`` and ``tile_cols`` (the last ones moved inwards to end at the
    sensor's edge); each pixel takes the expansion of the first tile holding it. ``mean``: the
    tiles' P̄ (tiles, C, N, N) transformed; ``bases``: the eigen-PSFs by window side, largest
    first, each group on its own FFT grid; term k (counting through ``bases`` in order) belongs
    to tile ``term_tile[k]`` (row-major) and channel ``term_channel[k]``, with coefficients
    ``maps[k]`` over its tile; ``error``: the measured relative L2 error of the PSF field.
    """

    mean: PsfTransform
    bases: tuple[EigenBasis, ...]
    maps: torch.Tensor
    term_tile: torch.Tensor
    term_channel: torch.Tensor
    tile_rows: tuple[int, ...]
    tile_cols: tuple[int, ...]
    sensor_hw: tuple[int, int]
    error: float
    tolerance: float

    @property
    def support(self) -> int:
        """Side (pixels) of the largest eigen-PSF window, centred in the PSFs' (0 without any)."""
        return max((2 * b.margin + 1 for b in self.bases), default=0)

    @property
    def windows(self) -> dict[int, int]:
        """Eigen-PSFs per window side (pixels), largest first."""
        return {2 * b.margin + 1: len(b.spectrum) for b in self.bases}

    @property
    def ranks(self) -> torch.Tensor:
        """Eigen-PSFs per tile and channel (tiles, C)."""
        tiles, channels = self.mean.spectrum.shape[:2]
        index = (self.term_tile * channels + self.term_channel).cpu()
        return torch.bincount(index, minlength=tiles * channels).reshape(tiles, channels)


def tile_side(n: int) -> int:
    """Side (pixels) of the sensor tiles for N × N PSF windows: the power of two nearest 0.6·N,
    32..256 (each tile costs FFTs of about its side + N; smaller tiles need fewer eigen-PSFs)."""
    return min(256, max(32, 2 ** round(math.log2(0.6 * n))))


def _starts(n: int, tile: int) -> tuple[int, ...]:
    """Tile starts along a side of ``n`` pixels: every ``tile``, the last one ending at n."""
    starts = list(range(0, n - tile + 1, tile))
    if starts[-1] + tile < n:
        starts.append(n - tile)
    return tuple(starts)


def _firsts(starts: tuple[int, ...], tile: int) -> list[int]:
    """Index within each tile of its first pixel not held by the tile before."""
    return [0] + [max(0, a + tile - b) for a, b in zip(starts, starts[1:])]


def _assembled(tiles: torch.Tensor, rows: tuple[int, ...], cols: tuple[int, ...]) -> torch.Tensor:
    """(..., tiles, C, T0, T1) → (..., C, H, W), each pixel from the first tile holding it."""
    t0, t1 = tiles.shape[-2:]
    tiles = tiles.unflatten(-4, (len(rows), len(cols)))
    lo0, lo1 = _firsts(rows, t0), _firsts(cols, t1)
    return torch.cat(
        [torch.cat([tiles[..., i, j, :, a:, b:] for j, b in enumerate(lo1)], dim=-1) for i, a in enumerate(lo0)],
        dim=-2,
    )


def _tile_of(pixels: torch.Tensor, starts: tuple[int, ...], tile: int) -> torch.Tensor:
    """Index of the tile holding each pixel (row or column numbers)."""
    firsts = torch.tensor([s + lo for s, lo in zip(starts, _firsts(starts, tile))], device=pixels.device)
    return torch.searchsorted(firsts, pixels.long(), right=True) - 1


def _keys_weights(t: torch.Tensor) -> torch.Tensor:
    """Cubic convolution weights (..., 4) of the samples at −1, 0, 1, 2 for offsets t ∈ [0, 1)."""
    a = KEYS
    near = torch.stack([t, 1 - t], dim=-1)
    far = torch.stack([t + 1, 2 - t], dim=-1)
    inner = ((a + 2) * near - (a + 3)) * near * near + 1
    outer = ((a * far - 5 * a) * far + 8 * a) * far - 4 * a
    return torch.stack([outer[..., 0], inner[..., 0], inner[..., 1], outer[..., 1]], dim=-1)


def _tile_nodes(heights_px, origin, tile_hw, sensor_hw, step: float, support: int):
    """The nodes of a tile's eigen-analysis and the interpolation of their coefficients.

    The field model is linear in height between the set's heights h_k (:func:`field_psf`), so a
    pixel's PSF is (1 − w)·P(h_{k−1}, ψ) + w·P(h_k, ψ) exactly: the nodes are the on-axis point
    and, on each height the tile's pixels use, azimuths ψ_j whose spacing turns the support's rim
    (S//2 px from the chief ray) by at most ``step`` px, over the tile's azimuths (all of them
    where the tile surrounds the axis). A coefficient map is then linear along the radius, the
    field model's own interpolation, and Keys-cubic in azimuth, so it follows the fast turning
    of a wide PSF near the axis that a grid of nodes in x, y cannot. Returns the node offsets
    (ys, xs) from the axis pixel, float64, and the sparse (T0·T1, nodes) float64 matrix whose row
    p holds pixel p's weights on the nodes (row-major pixels; each row sums to 1)."""
    heights = torch.tensor(heights_px, dtype=torch.float64)
    rows, cols = (torch.arange(o, o + t, dtype=torch.float64) - n // 2 for o, t, n in zip(origin, tile_hw, sensor_hw))
    y, x = (g.flatten() for g in torch.meshgrid(rows, cols, indexing="ij"))
    rho = torch.hypot(x, y).clamp(max=heights[-1])
    if len(heights) == 1:  # one PSF everywhere: the axis node alone
        return (
            torch.zeros(1, dtype=torch.float64),
            torch.zeros(1, dtype=torch.float64),
            _sparse(torch.arange(len(x)), torch.zeros(len(x), dtype=torch.long), torch.ones(len(x)), (len(x), 1)),
        )
    i = torch.searchsorted(heights, rho, right=True).clamp(1, len(heights) - 1)
    w = ((rho - heights[i - 1]) / (heights[i] - heights[i - 1])).clamp(0, 1)
    used = torch.unique(torch.cat([(i - 1)[w < 1], i[w > 0]])).tolist()
    psi = torch.atan2(y, x)
    off = rho > 0
    centre = float(torch.atan2(y[off].mean(), x[off].mean())) if off.any() else 0.0
    rel = torch.remainder(psi - centre + math.pi, 2 * math.pi) - math.pi  # azimuth from the tile's centre
    lo, hi = (float(rel[off].min()), float(rel[off].max())) if off.any() else (0.0, 0.0)
    largest = step / max(1, support // 2)  # radians
    if hi - lo > math.pi:  # the tile surrounds the axis: every azimuth, periodic
        count = max(4, math.ceil(2 * math.pi / largest))
        spacing = 2 * math.pi / count
        u = (rel + math.pi) / spacing
        j0 = u.floor().clamp(max=count - 1)
        taps = (j0[:, None].long() - 1 + torch.arange(4)) % count
        angles = centre - math.pi + spacing * torch.arange(count, dtype=torch.float64)
    else:  # one sample below and two above the range, for the cubic's taps
        steps = max(1, math.ceil((hi - lo) / largest))
        spacing = (hi - lo) / steps if hi > lo else largest
        count = steps + 3
        u = ((rel - lo) / spacing).clamp(0, steps)
        j0 = u.floor().clamp(max=steps - 1)
        taps = j0[:, None].long() + torch.arange(4)
        angles = centre + lo + spacing * (torch.arange(count, dtype=torch.float64) - 1)
    cubic = _keys_weights(u - j0)  # (P, 4)
    ring = [k for k in used if k > 0]
    first = {k: (1 if 0 in used else 0) + n * count for n, k in enumerate(ring)}
    pixels, nodes, values = [], [], []
    for k_of, weight in ((i - 1, 1 - w), (i, w)):
        for k in used:
            at = ((k_of == k) & (weight > 0)).nonzero()[:, 0]
            if not len(at):
                continue
            if k == 0:
                pixels.append(at), nodes.append(torch.zeros_like(at)), values.append(weight[at])
            else:
                pixels.append(at.repeat_interleave(4))
                nodes.append((first[k] + taps[at]).flatten())
                values.append((weight[at, None] * cubic[at]).flatten())
    ys = [torch.zeros(1, dtype=torch.float64)] if 0 in used else []
    xs = list(ys)
    for k in ring:
        ys.append(heights[k] * torch.sin(angles))
        xs.append(heights[k] * torch.cos(angles))
    ys, xs = torch.cat(ys), torch.cat(xs)
    return ys, xs, _sparse(torch.cat(pixels), torch.cat(nodes), torch.cat(values), (len(x), len(xs)))


def _sparse(rows: torch.Tensor, cols: torch.Tensor, values: torch.Tensor, shape) -> torch.Tensor:
    """The sparse float64 matrix of ``shape`` with ``values`` at (``rows``, ``cols``), summed where repeated."""
    return torch.sparse_coo_tensor(torch.stack([rows, cols]), values.double(), shape, check_invariants=True).coalesce()


def _node_weights(interpolation: torch.Tensor) -> torch.Tensor:
    """The pixels each node stands for (nodes,): the sum of |weights| it gets over the tile (the
    eigen-analysis weighs the nodes by them, so that its error is one over the tile's pixels)."""
    i = interpolation.indices()[1]
    return torch.zeros(interpolation.shape[1], dtype=torch.float64).index_add_(0, i, interpolation.values().abs())


def _node_chunk(psf_shape) -> int:
    """Nodes per batch of field PSFs (C, N, N): about ``NODE_CHUNK_VALUES`` values a batch."""
    return max(1, NODE_CHUNK_VALUES // math.prod(psf_shape))


def _node_psfs(
    psf_set: FieldPsfSet, ys: torch.Tensor, xs: torch.Tensor, support: int, mean: torch.Tensor, channel: int
) -> torch.Tensor:
    """Channel ``channel``'s field PSFs at offsets ``ys``, ``xs`` (K,) less ``mean`` (C, N, N),
    on their central ``support`` pixels, flattened (K, S·S); a batch of nodes at a time (one
    channel at a time, so a tile's analysis holds a third of the values)."""
    one = FieldPsfSet(psf_set.heights_px, psf_set.psfs[:, channel : channel + 1])
    out = psf_set.psfs.new_empty(len(xs), support * support)
    step = _node_chunk((support, support))
    for i in range(0, len(xs), step):
        out[i : i + step] = field_psf(one, xs[i : i + step], ys[i : i + step], support).flatten(-3)
    out -= _cropped(mean[channel], support).flatten()
    return out


def _flip_gram(x: torch.Tensor, n: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Gram matrices (K, K), float64, of residuals ``x`` (K, N·N) with themselves, G = X·Xᵀ, and
    with their mirror images under y → −y, G_F = X·(FX)ᵀ, a block of rows at a time (no copy of
    X). The even parts (x + Fx)/2 have the Gram matrix (G + G_F)/2, the odd ones (G − G_F)/2."""
    full = x.unflatten(-1, (n, n))
    gram = torch.zeros(len(x), len(x), dtype=torch.float64, device=x.device)
    mirrored = torch.zeros_like(gram)
    rows = max(1, ROW_BLOCK_VALUES // max(1, len(x) * n))
    for r0 in range(0, n, rows):
        r1 = min(n, r0 + rows)
        block = full[:, r0:r1].flatten(1)
        gram += (block @ block.T).double()
        mirrored += (block @ full[:, n - r1 : n - r0].flip(1).flatten(1).T).double()
    return gram, mirrored


def _eigh(matrix: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """torch.linalg.eigh on one CPU thread: for matrices this small more threads only wait on
    each other (up to 100× slower on a busy 2-core machine)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return torch.linalg.eigh(matrix)
    finally:
        torch.set_num_threads(threads)


def _principal(residual: torch.Tensor, n: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Eigenvalues (descending, float64), node vectors (K, M) and parities (M,) (+1: even under
    y → −y, −1: odd) of the principal components of one channel's residuals (K, N·N)."""
    gram, mirrored = _flip_gram(residual, n)
    values, vectors, parities = [], [], []
    for sign in (1, -1):
        val, vec = _eigh((gram + sign * mirrored) / 2)
        keep = val > val[-1].clamp_min(0) * 1e-12
        values.append(val[keep].flip(0))
        vectors.append(vec[:, keep].flip(1))
        parities.append(torch.full((int(keep.sum()),), sign, device=val.device))
    values = torch.cat(values)
    order = values.argsort(descending=True)
    return values[order], torch.cat(vectors, dim=1)[:, order], torch.cat(parities)[order]


def _components(residual: torch.Tensor, n: int, values, vectors, parities) -> torch.Tensor:
    """The principal components (M, N·N) of residuals (K, N·N), unit L2 norm and zero sum: each
    the combination of the residuals its node vector gives, made even or odd under y → −y (the
    mirror commutes with the combination, so this is the combination of the even or odd parts)."""
    scaled = (vectors / values.sqrt()).to(residual.dtype)
    comp = (scaled.T @ residual).unflatten(-1, (n, n))
    sign = parities.to(device=residual.device, dtype=residual.dtype)[:, None, None]
    comp = ((comp + sign * comp.flip(-2)) / 2).flatten(1)
    return comp - comp.mean(-1, keepdim=True)  # zero sum to rounding already: the residuals sum to 0


@dataclass
class _Tile:
    """A tile's eigen-analysis: its origin, azimuth step (:func:`_tile_nodes`) and node
    offsets, the mean (C, N, N), the total squared norm of its pixels' PSFs and per channel the
    output of :func:`_principal` of their node-weighted residuals on the central ``support`` ×
    ``support`` pixels with the components' pixel energies (:func:`_pixel_energies`), all in
    descending order of these, and the leading components made while those residuals were at
    hand (``KEEP_SHARE``: what each channel alone would need for its share)."""

    origin: tuple[int, int]
    step: float
    ys: torch.Tensor
    xs: torch.Tensor
    mean: torch.Tensor
    total: float
    spectra: list
    kept: list  # per channel, the leading eigen-PSFs (M, S·S) and their values at the nodes (M, K)
    root: torch.Tensor  # (K, 1): the square roots of the node weights (:func:`_node_weights`)


@dataclass
class _Coarse:
    """A tile's field PSFs on ``SUPPORT_NODES``² nodes: their mean (C, N, N), mean squared norm
    and the squared norm of their variation about the mean at each Chebyshev radius (N//2 + 1,)."""

    mean: torch.Tensor
    energy: float
    rings: torch.Tensor


def _rings(n: int, device) -> torch.Tensor:
    """The Chebyshev radius (pixels from the centre pixel, max of |row|, |col|) of each pixel of
    an n × n window (n odd), flattened row-major."""
    k = torch.arange(n, device=device) - n // 2
    return torch.maximum(k[:, None].abs(), k[None, :].abs()).flatten()


def _coarse(psf_set: FieldPsfSet, origin, tile_hw, sensor_hw) -> _Coarse:
    p = psf_set.psfs
    rows, cols = (
        torch.linspace(start, start + size - 1, SUPPORT_NODES, dtype=p.dtype, device=p.device) - n // 2
        for start, size, n in zip(origin, tile_hw, sensor_hw)
    )
    ys, xs = (g.flatten() for g in torch.meshgrid(rows, cols, indexing="ij"))
    full = field_psf(psf_set, xs, ys)
    mean = full.mean(0)
    n = full.shape[-1]
    ring = _rings(n, full.device)
    varying = ((full - mean).double() ** 2).sum((0, 1)).flatten()
    rings = torch.bincount(ring, varying, minlength=n // 2 + 1).cpu()
    return _Coarse(mean, float((full.double() ** 2).sum()) / len(xs), rings)


def eigen_support(coarse: list[_Coarse], share: float) -> int:
    """Side S (odd, pixels) of the central window the eigen-PSFs keep: the smallest whose
    leaving out of the field PSFs' variation about their tiles' means costs at most ``share``
    (relative L2 of the PSF field), judged on the tiles' coarse nodes. A PSF's sharp,
    field-dependent part is compact; its wide halo varies slowly and stays in the tiles' means."""
    n = 2 * (len(coarse[0].rings) - 1) + 1
    beyond = sum(c.rings for c in coarse).flip(0).cumsum(0).flip(0)  # beyond[r]: variation at radius ≥ r
    total = sum(c.energy for c in coarse) * SUPPORT_NODES**2
    fits = (beyond <= share**2 * total).nonzero()
    return min(n, max(1, 2 * int(fits[0]) - 1)) if len(fits) else n


def _tile_spectra(
    psf_set: FieldPsfSet, origin, tile_hw, sensor_hw, step: float, support: int, coarse, keep_share: float
) -> _Tile:
    p = psf_set.psfs
    ys, xs, interpolation = _tile_nodes(psf_set.heights_px, origin, tile_hw, sensor_hw, step, support)
    ys, xs = ys.to(p), xs.to(p)
    weight = _node_weights(interpolation)
    root = weight.clamp_min(1e-6 * float(weight.max())).sqrt().to(p)[:, None]
    overlap = _overlap(interpolation)
    total = coarse.energy * math.prod(tile_hw)
    channels = p.shape[1]
    spectra, kept = [], []
    for c in range(channels):
        residual = _node_psfs(psf_set, ys, xs, support, coarse.mean, c)
        residual *= root  # each node weighed by the pixels it stands for
        values, vectors, parities = _principal(residual, support)
        energies = _pixel_energies(values, vectors, root, overlap)
        order = energies.argsort(descending=True)
        values, vectors, parities, energies = values[order], vectors[:, order], parities[order], energies[order]
        # the fewest leading components that leave out at most the channel's share of keep_share²
        keep = float(energies.sum()) - keep_share**2 * total / channels
        m = min(len(values), int((energies.cumsum(0) < keep).sum()) + 1) if keep > 0 else 0
        e = _components(residual, support, values[:m], vectors[:, :m], parities[:m])
        spectra.append((values, vectors, parities, energies))
        kept.append((e, (e @ residual.T) / root.T))  # ⟨P_node − P̄, e⟩
        residual = None  # before the next channel's
    return _Tile(origin, step, ys, xs, coarse.mean, total, spectra, kept, root)


def _overlap(interpolation: torch.Tensor) -> torch.Tensor:
    """WᵀW (K, K), sparse float64, of the interpolation W (pixels, K) of :func:`_tile_nodes`:
    Σ_p W_pn·W_pm, from the pairs of each pixel's few nodes (≤ 8)."""
    w = interpolation.coalesce()
    pixel, node = w.indices()
    counts = torch.bincount(pixel, minlength=w.shape[0])
    rank = torch.arange(len(pixel)) - (counts.cumsum(0) - counts)[pixel]  # a coalesced row's entries are contiguous
    nodes = torch.zeros(w.shape[0], int(counts.max()), dtype=torch.long)
    weights = torch.zeros(nodes.shape, dtype=torch.float64)
    nodes[pixel, rank], weights[pixel, rank] = node, w.values()
    pairs = torch.stack(torch.broadcast_tensors(nodes[:, :, None], nodes[:, None, :])).flatten(1)
    products = (weights[:, :, None] * weights[:, None, :]).flatten()
    return torch.sparse_coo_tensor(pairs, products, w.shape[1:] * 2, check_invariants=True)


def _pixel_energies(values, vectors, root, overlap) -> torch.Tensor:
    """Each principal component's squared norm summed over the tile's pixels, (M,) float64 on the
    host: Σ_p a_pm² with a_m = W·c_m its coefficients interpolated from the nodes', c_m =
    √λ_m·v_m / root (the components are orthonormal, so leaving out a set costs the pixels the
    sum of theirs). The eigenvalues λ_m weigh each node by the pixels it stands for but not how
    the pixels mix neighbouring nodes, whose errors partly cancel: they overstated the error by
    1.2-1.35× (0.74-0.82 of the estimate measured on ten sets), and on the paper's three designs
    the expansions kept 14-27 % more eigen-PSFs than these need. ``overlap``: WᵀW (K, K), sparse."""
    scaled = (vectors / root.double()).cpu()  # c_m / √λ_m
    return values.cpu() * (scaled * torch.sparse.mm(overlap, scaled)).sum(0)


def _selected(tiles: list[_Tile], target: float) -> list[list[int]]:
    """Eigen-PSFs to keep per tile and channel: the largest pixel energies
    (:func:`_pixel_energies`) over all tiles and channels until what is left is at most
    ``target``² of the field's squared norm."""
    values = torch.cat([v for t in tiles for _, _, _, v in t.spectra])
    owner = torch.cat([torch.full((len(v),), k) for k, v in enumerate(v for t in tiles for _, _, _, v in t.spectra)])
    order = values.argsort(descending=True)
    left = values[order].flip(0).cumsum(0).flip(0)  # left[i]: the sum of values[order][i:]
    limit = target**2 * sum(t.total for t in tiles)
    keep = int((left > limit).sum())
    channels = len(tiles[0].spectra)
    counts = torch.bincount(owner[order[:keep]], minlength=len(tiles) * channels).tolist()
    return [counts[i * channels : (i + 1) * channels] for i in range(len(tiles))]


def field_transform(
    psf_set: FieldPsfSet,
    sensor_hw: tuple[int, int],
    *,
    tolerance: float = DEFAULT_TOLERANCE,
    max_bytes: int | None = None,
) -> FieldTransform:
    """Prepare ``psf_set`` for H × W sensor images: the tiled eigen-PSF expansion of the module
    docstring with the fewest eigen-PSFs whose measured PSF-field error meets ``tolerance``.

    Precompute once per PSF set and reuse (:func:`form_image_field`).

    Args:
        psf_set: the PSFs along +x (:class:`FieldPsfSet`).
        sensor_hw: (H, W) of the sensor images (pixels); the optical axis at (H//2, W//2).
        tolerance: the PSF-field error to meet (relative L2, e.g. 0.01).
        max_bytes: refuse (:class:`InputError` on ``--field-tolerance``) before building eigen-PSFs,
            their coefficient maps and spectra that would hold more (:func:`expansion_bytes`);
            None: no limit.

    Returns:
        The ``FieldTransform``: tiles, the tiles' mean PSFs and eigen-PSFs transformed, and their
        coefficient maps.
    """
    arguments.instance(psf_set, "psf_set", FieldPsfSet, "a FieldPsfSet")
    arguments.number(
        tolerance, "tolerance", lo=0.0, hi=1.0, open_lo=True, open_hi=True, form="a relative L2 error in (0, 1)"
    )
    hw = arguments.instance(sensor_hw, "sensor_hw", (tuple, list), "(height, width) in pixels")
    if len(hw) != 2:
        raise InputError("sensor_hw", f"{hw!r}", "(height, width) in pixels")
    h, w = (arguments.count(n, "sensor_hw") for n in hw)
    with torch.no_grad():
        psf_set = FieldPsfSet(psf_set.heights_px, psf_set.psfs.detach())
        p = psf_set.psfs
        n = p.shape[-1]
        side = tile_side(n)
        while True:  # halve the tiles while a channel's node PSFs of one would pass NODE_VALUES
            tile_hw = (min(side, h), min(side, w))
            rows, cols = _starts(h, tile_hw[0]), _starts(w, tile_hw[1])
            origins = [(r, c) for r in rows for c in cols]
            coarse = [_coarse(psf_set, o, tile_hw, (h, w)) for o in origins]
            support = eigen_support(coarse, SUPPORT_SHARE * tolerance)
            heights = psf_set.heights_px
            nodes = max(len(_tile_nodes(heights, o, tile_hw, (h, w), NODE_STEP, support)[0]) for o in origins)
            if nodes * support**2 <= NODE_VALUES or side <= 16:
                break
            side //= 2
        check = torch.Generator().manual_seed(0)
        check_r, check_c = (torch.randint(0, m, (CHECK_PIXELS,), generator=check).to(p.device) for m in (h, w))
        at_pixels = (check_r - h // 2).to(p.dtype), (check_c - w // 2).to(p.dtype)
        check_tile = _tile_of(check_r, rows, tile_hw[0]) * len(cols) + _tile_of(check_c, cols, tile_hw[1])
        check_r = check_r - torch.tensor(rows, device=p.device)[_tile_of(check_r, rows, tile_hw[0])]
        check_c = check_c - torch.tensor(cols, device=p.device)[_tile_of(check_c, cols, tile_hw[1])]
        step = NODE_STEP
        tiles = [
            _tile_spectra(psf_set, o, tile_hw, (h, w), step, support, c, KEEP_SHARE * tolerance)
            for o, c in zip(origins, coarse)
        ]
        target = TARGET_SHARE * tolerance
        for _ in range(MAX_REFINEMENTS + 1):
            built = None  # the last try's expansion goes before the next one is built
            counts = _selected(tiles, target)
            needed = expansion_bytes(sum(map(sum, counts)), support, tile_hw)
            if max_bytes is not None and needed > max_bytes:
                raise InputError(
                    "--field-tolerance",
                    f"{tolerance:g}: {sum(map(sum, counts))} eigen-PSFs of {support}² px would hold "
                    f"{needed / 2**30:.1f} GiB, over the limit of {max_bytes / 2**30:.1f} GiB",
                    "a larger tolerance (e.g. 0.03) or a smaller sensor",
                )
            built = _built(psf_set, tiles, counts, tile_hw, (h, w), step, support)
            kernels, maps, term_tile, term_channel, means = built
            total = sum(t.total for t in tiles)
            sides, cut = _windows(kernels, maps, support, tile_hw, (WINDOW_SHARE * tolerance) ** 2 * total)
            kernels = _windowed(kernels, sides, support)
            built = kernels, maps, term_tile, term_channel, means
            error = _check_error(psf_set, at_pixels, (check_tile, check_r, check_c), built)
            if error <= CHECK_MARGIN * tolerance:
                break
            truncation = math.sqrt(
                sum(float(v[k:].sum()) for t, ks in zip(tiles, counts) for (_, _, _, v), k in zip(t.spectra, ks))
                / total
            )
            rest = error**2 - truncation**2  # what the eigen-PSFs left out does not explain: windows, azimuth nodes
            if rest - cut / total > truncation**2 and step > MIN_NODE_STEP:
                step /= 2  # the coefficients' interpolation dominates: azimuth nodes twice as close
            else:  # leave out as much as the aim has room for beside the rest, at least halving it
                target = math.sqrt(max((TARGET_SHARE * tolerance) ** 2 - rest, truncation**2 / 4))
        order = torch.sort(sides, descending=True, stable=True).indices.to(term_tile.device)
        return FieldTransform(
            psf_transform(means, tile_hw),
            _bases(kernels[order], sides[order.cpu()], support, tile_hw),
            maps[order],
            term_tile[order],
            term_channel[order],
            rows,
            cols,
            (h, w),
            error,
            tolerance,
        )


def expansion_bytes(terms: int, support: int, tile_hw: tuple[int, int]) -> int:
    """Bytes that ``terms`` eigen-PSFs of ``support``² pixels on tiles ``tile_hw`` hold in a
    :class:`FieldTransform` being built: the kernels and coefficient maps (float32) and the
    spectra (complex64) on the tiles' FFT grid."""
    l0, l1 = _basis_grid(support, tile_hw)
    return terms * 4 * (support**2 + math.prod(tile_hw) + 2 * l0 * (l1 // 2 + 1))


def _check_error(psf_set: FieldPsfSet, at_pixels, where, built) -> float:
    """Relative L2 error of the expansion ``built`` (:func:`_built`) against the field PSFs at
    the check pixels ``at_pixels`` (ys, xs from the axis), which lie at ``where`` (tile index,
    row and column within it); a chunk of pixels at a time."""
    kernels, maps, term_tile, term_channel, means = built
    tile, r, c = where
    ys, xs = at_pixels
    error = norm = 0.0
    step = _node_chunk(psf_set.psfs.shape[1:])
    for start in range(0, len(xs), step):
        chunk = slice(start, start + step)
        exact = field_psf(psf_set, xs[chunk], ys[chunk])
        approx = means[tile[chunk]].clone()
        on = term_tile[None, :] == tile[chunk, None]  # (P, terms)
        at = maps[:, r[chunk], c[chunk]].T * on  # coefficients of each term at each check pixel
        support = math.isqrt(kernels.shape[-1])
        centre = _cropped(approx, support)
        for channel in range(approx.shape[1]):
            sel = term_channel == channel
            centre[:, channel] += (at[:, sel] @ kernels[sel]).unflatten(-1, (support, support))
        error += float(((approx - exact).double() ** 2).sum())
        norm += float((exact.double() ** 2).sum())
    return math.sqrt(error / norm)


def _basis_grid(side: int, tile_hw: tuple[int, int]) -> tuple[int, int]:
    """The FFT grid (L0, L1) of eigen-PSFs of ``side`` pixels on tiles ``tile_hw``: at least
    tile + side − 1 a side (no wrap-around on the tile), each 8 times a 7-smooth number. On 2
    cores MKL's inverse transforms (4 of the first pass and 4 of the second's 256 rows) of
    odd or singly even lengths took 1.4-2.4× the time per sample of such lengths: 405 and 525
    6.7 and 5.8 ns, 450 and 490 4.0 and 4.1 ns, against 2.8 ns for 448, 480 and 560."""
    margin = canvas_margin(side)
    return tuple(8 * fft_size(-(-(t + 2 * margin) // 8)) for t in tile_hw)


def _window_sides(support: int, tile_hw: tuple[int, int]) -> list[int]:
    """Window sides an eigen-PSF may take, ``support`` first, descending: for each FFT grid of
    the tiles (:func:`_basis_grid`) the largest side it holds, each grid's area at most
    ``WINDOW_STEP`` of the one before (a few grids, each one more set of canvas transforms per
    capture)."""

    def area(side: int) -> int:
        return math.prod(_basis_grid(side, tile_hw))

    sides = [support]
    for side in range(support - 2, 0, -2):
        if area(side) <= WINDOW_STEP * area(sides[-1]) and (side == 1 or area(side - 2) < area(side)):
            sides.append(side)
    return sides


def _windows(kernels: torch.Tensor, maps: torch.Tensor, support: int, tile_hw, budget: float):
    """Each eigen-PSF's window side (terms,) on the host, from :func:`_window_sides`, and the
    squared error the windows add, at most ``budget`` (squared PSF-field norm): the least FFT
    work whose cuts sum within it (a Lagrangian search over one price of error). Cutting a
    kernel (unit norm) to its central s × s pixels and taking its mean there (zero sum kept)
    costs the pixels its coefficients' squared norm over the tile times the squared norm of
    the part left out plus s² times that mean squared; the cuts of different eigen-PSFs add
    (their coefficient maps are nearly orthogonal over the tile)."""
    sides = _window_sides(support, tile_hw)
    if not len(kernels) or len(sides) == 1 or budget <= 0:
        return torch.full((len(kernels),), support, dtype=torch.long), 0.0
    ring = _rings(support, kernels.device)
    rings = torch.zeros(len(kernels), support // 2 + 1, dtype=torch.float64, device=kernels.device)
    sums = torch.zeros_like(rings)
    rings.index_add_(1, ring, kernels.double() ** 2)
    sums.index_add_(1, ring, kernels.double())
    radii = torch.tensor([s // 2 for s in sides], device=kernels.device)
    inside, held = sums.cumsum(1)[:, radii], rings.cumsum(1)[:, radii]  # (terms, sides)
    side = torch.tensor(sides, dtype=torch.float64, device=kernels.device)
    left = (rings.sum(1, keepdim=True) - held + inside**2 / side**2).clamp_min(0)
    left[:, 0] = 0  # the whole support: nothing cut
    cost = (left * (maps.double() ** 2).sum((1, 2))[:, None]).cpu()
    work = torch.tensor([math.prod(_basis_grid(s, tile_hw)) for s in sides], dtype=torch.float64)
    terms = torch.arange(len(cost))

    def chosen(price: float) -> tuple[torch.Tensor, float]:
        pick = (work + price * cost).argmin(1)
        return pick, float(cost[terms, pick].sum())

    positive = cost[cost > 0]
    lo = 0.0
    hi = float(work[0]) / (float(positive.min()) if len(positive) else 1.0)  # every cut costs more than it saves
    if chosen(lo)[1] > budget:
        for _ in range(60):  # the lowest price of error whose cuts fit the budget
            mid = math.sqrt(max(lo, hi * 1e-18) * hi)
            lo, hi = (mid, hi) if chosen(mid)[1] > budget else (lo, mid)
        lo = hi
    pick, cut = chosen(lo)
    return torch.tensor(sides)[pick], cut


def _windowed(kernels: torch.Tensor, sides: torch.Tensor, support: int) -> torch.Tensor:
    """Eigen-PSFs (terms, S·S) cut to their central ``sides`` × ``sides`` pixels (zero outside)
    less their mean there: zero sum and each one's parity under y → −y kept."""
    ring = _rings(support, kernels.device)
    inside = (ring[None, :] <= (sides.to(kernels.device)[:, None] // 2)).to(kernels.dtype)
    cut = kernels * inside
    return cut - inside * cut.sum(1, keepdim=True) / inside.sum(1, keepdim=True)


def _bases(kernels: torch.Tensor, sides: torch.Tensor, support: int, tile_hw) -> tuple[EigenBasis, ...]:
    """:class:`EigenBasis` groups of eigen-PSFs (terms, S·S) by their window ``sides`` (host,
    descending, grouped), each transformed a chunk at a time (the padded kernels of one chunk
    are the only transient)."""
    bases, start = [], 0
    for side, count in zip(*(x.tolist() for x in torch.unique_consecutive(sides, return_counts=True))):
        group = _cropped(kernels[start : start + count].unflatten(-1, (support, support)), side)
        start += count
        shape = _basis_grid(side, tile_hw)
        step = max(1, CHUNK_VALUES * 8 // (shape[0] * (shape[1] // 2 + 1)))
        spectrum = torch.cat(
            [torch.fft.rfft2(_placed(group[k : k + step], shape)).transpose(-1, -2).contiguous()
             for k in range(0, count, step)]
        )  # fmt: skip
        bases.append(EigenBasis(spectrum, tuple(tile_hw), canvas_margin(side), shape))
    return tuple(bases)


def _append_terms(basis, grids, interpolation, tile: int, tile_hw, terms) -> None:
    """Add one tile's eigen-PSFs (per channel, (M, S·S) or None) with their coefficient maps,
    interpolated by ``interpolation`` (:func:`_tile_nodes`) from their values at the nodes
    (M, K), to ``terms`` (lists of kernels, maps, tile and channel indices)."""
    kernels, maps, term_tile, term_channel = terms
    for c, (e, grid) in enumerate(zip(basis, grids)):
        if e is None or not len(e):
            continue
        at = torch.sparse.mm(interpolation.to(grid.dtype), grid.T.contiguous().cpu()).to(grid.device)
        maps.append(at.T.reshape(len(e), *tile_hw))
        kernels.append(e)
        term_tile.append(torch.full((len(e),), tile))
        term_channel.append(torch.full((len(e),), c))


def _built(psf_set: FieldPsfSet, tiles: list[_Tile], counts, tile_hw, sensor_hw, step: float, support: int):
    """Eigen-PSFs (terms, S·S), their coefficient maps (terms, T0, T1) from azimuth nodes
    ``step`` apart (:func:`_tile_nodes`), tile and channel of each, and the tiles' means
    (tiles, C, N, N), for the ``counts`` kept per tile and channel."""
    kernels, maps, term_tile, term_channel = [], [], [], []
    for i, (tile, kept) in enumerate(zip(tiles, counts)):
        if not any(kept):
            continue
        ys, xs, interpolation = _tile_nodes(psf_set.heights_px, tile.origin, tile_hw, sensor_hw, step, support)
        ys, xs = ys.to(psf_set.psfs), xs.to(psf_set.psfs)
        basis, grids = [], []
        for c, ((e, at), (values, vectors, parities, _), k) in enumerate(zip(tile.kept, tile.spectra, kept)):
            residual = None
            if k > len(e):  # more than the tile's analysis made: its residuals again
                residual = _node_psfs(psf_set, tile.ys, tile.xs, support, tile.mean, c) * tile.root
                e = _components(residual, support, values[:k], vectors[:, :k], parities[:k])
            e = e[:k] if k else None
            if e is None:
                grid = None
            elif step != tile.step:  # ⟨P_node − P̄, e⟩ on the finer nodes, a batch of them at a time
                chunk = _node_chunk((support, support))
                nodes = (
                    _node_psfs(psf_set, ys[j : j + chunk], xs[j : j + chunk], support, tile.mean, c)
                    for j in range(0, len(xs), chunk)
                )
                grid = torch.cat([e @ batch.T for batch in nodes], dim=1)
            else:
                grid = at[:k] if residual is None else (e @ residual.T) / tile.root.T
            basis.append(e)
            grids.append(grid)
        _append_terms(basis, grids, interpolation, i, tile_hw, (kernels, maps, term_tile, term_channel))
    p = psf_set.psfs
    means = torch.stack([t.mean for t in tiles])
    if not kernels:
        empty = torch.zeros(0, dtype=torch.long, device=p.device)
        return p.new_zeros(0, support * support), p.new_zeros(0, *tile_hw), empty, empty, means
    return (
        torch.cat(kernels),
        torch.cat(maps),
        torch.cat(term_tile).to(p.device),
        torch.cat(term_channel).to(p.device),
        means,
    )


def _field_transform(psfs, sensor_hw: tuple[int, int], tolerance: float) -> FieldTransform:
    if isinstance(psfs, FieldTransform):
        if psfs.sensor_hw != tuple(sensor_hw):
            raise InputError(
                "psf",
                f"field transform made for {psfs.sensor_hw} images, sensor is {tuple(sensor_hw)}",
                "field_transform(psf set, sensor size)",
            )
        return psfs
    if not isinstance(psfs, FieldPsfSet):
        raise InputError("psf", f"a {type(psfs).__name__}", "a FieldPsfSet or FieldTransform")
    return field_transform(psfs, sensor_hw, tolerance=tolerance)


def _tile_canvases(canvas: torch.Tensor, margin: int, t: FieldTransform) -> torch.Tensor:
    """Each tile's canvas (..., tiles, C, T0 + 2M, T1 + 2M) cut from ``canvas`` of margin M."""
    t0, t1 = t.mean.sensor_hw
    tiles = [canvas[..., r : r + t0 + 2 * margin, c : c + t1 + 2 * margin] for r in t.tile_rows for c in t.tile_cols]
    return torch.stack(tiles, dim=-4)


def _kept_transposed(product: torch.Tensor, basis: EigenBasis) -> torch.Tensor:
    """:func:`formation._kept` of a transposed spectrum (..., L1 // 2 + 1, L0): the tile (..., T0, T1)."""
    h, w = basis.sensor_hw
    rows = torch.fft.ifft(product, dim=-1)[..., basis.margin : basis.margin + h]
    return torch.fft.irfft(rows.transpose(-1, -2), n=basis.fft_shape[1], dim=-1)[..., basis.margin : basis.margin + w]


def _gather(spectrum_of, t: FieldTransform) -> torch.Tensor:
    """P̄ ∗ in + Σ a ⊙ (e ∗ in) on the sensor; ``spectrum_of(transform)``: the tiles' spectra
    (..., tiles, C or 1, L0, L1 // 2 + 1) on the FFT grid of ``t.mean`` or of one of ``t.bases``."""
    out = _kept(spectrum_of(t.mean) * t.mean.spectrum, t.mean)  # (..., tiles, C, T0, T1)
    channels = out.shape[-3]
    out = out.flatten(-4, -3)
    index = (t.term_tile * channels + t.term_channel).tolist()
    first = 0  # the basis's first term
    for basis in t.bases:
        fine = spectrum_of(basis).transpose(-1, -2).contiguous()  # (..., tiles, C or 1, L1 // 2 + 1, L0)
        step = max(1, CHUNK_VALUES // fine[..., :1, :1, :, :].numel())
        end, k = first + len(basis.spectrum), first
        while k < end:  # a run of terms of one tile and channel, a chunk at a time
            g, stop = index[k], k + 1
            while stop < end and stop - k < step and index[stop] == g:
                stop += 1
            plane = fine[..., g // channels, g % channels if fine.shape[-3] > 1 else 0, None, :, :]
            planes = _kept_transposed(plane * basis.spectrum[k - first : stop - first], basis)
            out[..., g, :, :] += (planes * t.maps[k:stop].to(planes.dtype)).sum(-3)
            k = stop
        first = end
    return _assembled(out.unflatten(-3, (-1, channels)), t.tile_rows, t.tile_cols)


def field_convolve(canvas: torch.Tensor, psfs, margin: int, *, tolerance: float = DEFAULT_TOLERANCE) -> torch.Tensor:
    """The sensor crop of ``canvas`` (..., C, H + 2M, W + 2M) blurred in gather form by the field
    PSFs ``psfs`` (:class:`FieldPsfSet` or :class:`FieldTransform`); C broadcasts as in
    :func:`formation.convolve`."""
    t = _field_transform(psfs, _sensor_hw(canvas, margin), tolerance)
    tiles = _tile_canvases(canvas, margin, t)
    return _gather(lambda grid: _canvas_spectrum(tiles, margin, grid), t)


def form_image_field(
    clean: torch.Tensor,
    obstruction: torch.Tensor,
    mask: torch.Tensor,
    near,
    far,
    margin: int,
    *,
    formation: str = "physical",
    alpha_gain: float | None = None,
    tolerance: float = DEFAULT_TOLERANCE,
) -> Capture:
    """:func:`formation.form_image` with field PSFs, each PSF the one of the output pixel.

    The optical axis is the sensor's centre pixel (H//2, W//2); α = m ∗ P̂_near and both forms
    as in ``imaging.formation``.

    Args:
        clean: the far scene's linear radiance on a canvas with margin M.
        obstruction: the obstruction's linear radiance on the same canvas.
        mask: its coverage m in 0..1, one or three channels.
        near: the PSFs at the obstruction's depth: a :class:`FieldPsfSet` (prepared here at
            ``tolerance``) or a :class:`FieldTransform` (precomputed, reused; it carries its own
            tolerance).
        far: likewise at the scene's depth.
        margin: M, pixels of canvas on every side of the sensor's H × W.
        formation: "physical" or "paper".
        alpha_gain: as in :func:`formation.form_image`.
        tolerance: the expansion's PSF-field error (relative L2) for PSF sets prepared here.

    Returns:
        The ``Capture`` on the sensor's H × W.

    Shape:
        - Input: ``clean``, ``obstruction`` :math:`(..., 3, H + 2M, W + 2M)`, ``mask``
          :math:`(..., 1, H + 2M, W + 2M)` or :math:`(..., 3, H + 2M, W + 2M)`
        - Output: each :math:`(..., 3, H, W)`
    """
    check_capture_inputs(clean, obstruction, mask, margin, formation, alpha_gain)
    for name, psfs in (("near", near), ("far", far)):
        arguments.instance(psfs, name, (FieldPsfSet, FieldTransform), "a FieldPsfSet or a FieldTransform")
    emitted, mask = _obstruction_canvases(obstruction, mask, formation)
    sensor = _sensor_hw(clean, margin)
    near, far = _field_transform(near, sensor, tolerance), _field_transform(far, sensor, tolerance)
    channels = obstruction.shape[-3]
    # one batched transform of [I_obs or m ⊙ I_obs, m] per grid; the mask's spectrum meets each channel's PSF
    tiles = _tile_canvases(torch.cat([emitted, mask], dim=-3), margin, near)

    def pairs(grid) -> torch.Tensor:
        f = _canvas_spectrum(tiles, margin, grid)
        return torch.stack(torch.broadcast_tensors(f[..., :channels, :, :], f[..., channels:, :, :]), dim=-5)

    near_light, blurred_mask = _gather(pairs, near).unbind(-4)
    unobstructed = field_convolve(clean, far, margin)
    return _composite(near_light, blurred_mask, unobstructed, formation, alpha_gain)
