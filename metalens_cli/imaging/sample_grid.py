"""Where a scene generator evaluates its canvas: every pixel, or pixels near the field and blocks beyond.

A training canvas (``imaging.canvas``) is the sensor's field with a margin of hundreds of pixels,
and with two-scale PSFs (``optics.two_scale``) the margin reaches the sensor only through the
halos, which see the canvas averaged over s × s blocks aligned on the sensor's corner
(``imaging.formation``); only the field grown by the core's reach is seen pixel by pixel. A
:class:`SampleGrid` is a tensor-product grid of sorted row and column coordinates (pixels, float32):

- :meth:`SampleGrid.pixels`: every pixel, the fields drawn whole (the exact path: generators draw
  what they always drew);
- :meth:`SampleGrid.blocks`: each row (and column) of the *fine band*, the field grown by ``fine_px``
  rounded out to whole blocks, and the centre of each s-pixel block outside it. A sample stands
  for a cell of its row's height by its column's width: a pixel in the fine region, an s × s
  block far from the field, a 1 × s strip beside the fine region. Noise fields are evaluated at
  the samples themselves (``imaging.noise``; with s = 1 at every pixel, the reference a coarser
  grid is measured against: the same noise, only the cells differ).

Generators evaluate their fields and shapes at the samples (each sample's ``footprint``, the
larger side of its cell, widens their antialiased edges) and :meth:`SampleGrid.canvas` fills each
cell with its sample: for the quick preset's 1328² canvas and s = 5, 424² samples (10× fewer).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SampleGrid:
    """Samples (``rows`` × ``cols``, pixel coordinates) of an H × W canvas; ``row_cells``,
    ``col_cells``: the canvas pixels each row and column stands for (ascending, covering 0..H−1
    and 0..W−1 once); ``block``: s; ``whole``: the fields drawn whole (:meth:`pixels`)."""

    shape: tuple[int, int]
    rows: np.ndarray
    cols: np.ndarray
    row_cells: tuple[np.ndarray, np.ndarray]  # (first pixel, pixels) of each row's cell
    col_cells: tuple[np.ndarray, np.ndarray]
    block: int
    whole: bool = False

    @classmethod
    def pixels(cls, shape: tuple[int, int]) -> SampleGrid:
        """Every pixel of a canvas of ``shape``."""
        axes = [np.arange(n) for n in shape]
        return cls(
            tuple(shape),
            *(a.astype(np.float32) for a in axes),
            *((a, np.ones_like(a)) for a in axes),
            block=1,
            whole=True,
        )

    @classmethod
    def blocks(cls, shape: tuple[int, int], margin: int, block: int, fine_px: int) -> SampleGrid:
        """Pixels within ``fine_px`` of the sensor's field (rounded out to whole blocks) and the
        centres of the ``block`` × ``block`` blocks elsewhere, blocks aligned on the field's
        corner (the halo's blocks); ``block`` = 1: every pixel, sampled as a coarser grid is."""
        pad = block * -(-int(fine_px) // block)
        per_axis = [_axis(n, margin, block, pad) for n in shape]
        return cls(tuple(shape), *(a[0] for a in per_axis), *(a[1] for a in per_axis), block=block)

    @property
    def samples(self) -> tuple[int, int]:
        """(rows, columns) of samples."""
        return len(self.rows), len(self.cols)

    @property
    def at(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(rows, cols) for a field evaluated at the samples; None on a pixel grid (the field
        drawn whole, as without a grid)."""
        return None if self.whole else (self.rows, self.cols)

    def footprint(self) -> np.ndarray:
        """Each sample's cell's longer side (R, C), pixels (float32): the width over which an
        edge is antialiased there."""
        return np.maximum.outer(self.row_cells[1], self.col_cells[1]).astype(np.float32)

    def weights(self) -> np.ndarray:
        """Each sample's cell's area (R, C), pixels: a mean over the canvas is Σ w·v / Σ w."""
        return np.multiply.outer(self.row_cells[1], self.col_cells[1]).astype(np.float32)

    def span(self, start: int, stop: int, axis: int) -> tuple[int, int]:
        """The samples (index range) whose coordinates lie in pixels ``start`` ≤ · < ``stop`` of
        ``axis`` (0 rows, 1 columns); on a pixel grid (start, stop) clipped to the canvas."""
        coords = self.rows if axis == 0 else self.cols
        return int(np.searchsorted(coords, start)), int(np.searchsorted(coords, stop))

    def span_table(self, axis: int) -> list[int]:
        """``span`` of ``axis`` as a table: entry p is the first sample at or past pixel p, for p
        in 0..n, so that span(start, stop, axis) is (table[start], table[stop]) (a list lookup,
        for callers that ask for thousands of spans)."""
        coords = self.rows if axis == 0 else self.cols
        return np.searchsorted(coords, np.arange(self.shape[axis] + 1)).tolist()

    def within(self, top: int, bottom: int, left: int, right: int):
        """The samples in pixels [top, bottom) × [left, right): their index ranges (i0, i1, j0,
        j1) and their coordinates from (top, left), or None on a pixel grid (``at``)."""
        (i0, i1), (j0, j1) = self.span(top, bottom, 0), self.span(left, right, 1)
        at = None if self.whole else (self.rows[i0:i1] - top, self.cols[j0:j1] - left)
        return (i0, i1, j0, j1), at

    def canvas(self, values: np.ndarray) -> np.ndarray:
        """The (..., H, W) canvas of sampled ``values`` (..., R, C): each cell filled with its
        sample (on a pixel grid, ``values`` itself)."""
        if self.whole:
            return values
        return np.repeat(np.repeat(values, self.row_cells[1], axis=-2), self.col_cells[1], axis=-1)


def _axis(n: int, margin: int, block: int, pad: int) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """One axis of :meth:`SampleGrid.blocks`: sample coordinates and (first pixel, pixels) of
    their cells over 0..n−1, the fine band (the field grown by ``pad``, rounded out to the
    blocks' lattice, which starts at the field's first pixel) ∩ the canvas."""
    field = n - 2 * margin
    lo, hi = max(margin - pad, 0), min(margin + block * -(-field // block) + pad, n)  # both on the blocks' lattice
    before = np.arange(lo - block, -block, -block)[::-1]  # block starts left of the band (lo ≡ margin mod s)
    after = np.arange(hi, n, block)
    starts = np.concatenate([before, np.arange(lo, hi), after])
    ends = np.concatenate([before + block, np.arange(lo, hi) + 1, after + block])
    starts, ends = np.maximum(starts, 0), np.minimum(ends, n)
    keep = ends > starts
    starts, ends = starts[keep], ends[keep]
    centres = ((starts + ends - 1) / 2).astype(np.float32)  # a block's middle pixel (s odd)
    return centres, (starts, ends - starts)
