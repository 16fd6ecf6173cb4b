"""Sample grids (imaging.sample_grid): cells that tile the canvas once, blocks on the halo's
lattice (aligned on the field's corner), the fine band around the field, and canvases filled
cell by cell."""

import numpy as np
import pytest

from metalens_cli.imaging.sample_grid import SampleGrid


@pytest.mark.parametrize(("field", "margin", "block", "fine"), [(48, 109, 5, 56), (37, 20, 5, 12), (16, 30, 3, 100)])
def test_cells_tile_the_canvas_on_the_halo_lattice(field, margin, block, fine):
    n = field + 2 * margin
    grid = SampleGrid.blocks((n, n), margin, block, fine)
    for coords, (starts, sizes) in ((grid.rows, grid.row_cells), (grid.cols, grid.col_cells)):
        assert starts[0] == 0 and np.all(starts[1:] == starts[:-1] + sizes[:-1]) and starts[-1] + sizes[-1] == n
        assert np.all((starts <= coords) & (coords < starts + sizes))
        whole = sizes == block
        assert np.all((starts[whole] - margin) % block == 0)  # the halo's blocks start at the field's corner
        band = np.arange(max(margin - fine, 0), min(margin + field + fine, n))
        assert np.all(sizes[np.searchsorted(starts, band, side="right") - 1] == 1)  # the fine band: pixels
    pad = block * -(-fine // block)
    assert grid.weights().sum() == n * n and grid.footprint().max() == (block if margin >= pad + block else 1)


def test_canvas_fills_each_cell_with_its_sample():
    grid = SampleGrid.blocks((60, 60), 20, 5, 4)
    values = np.arange(np.prod(grid.samples), dtype=np.float32).reshape(grid.samples)
    canvas = grid.canvas(values[None])[0]
    rows = np.repeat(np.arange(grid.samples[0]), grid.row_cells[1])
    cols = np.repeat(np.arange(grid.samples[1]), grid.col_cells[1])
    np.testing.assert_array_equal(canvas, values[rows][:, cols])
    assert canvas.shape == (60, 60)


def test_the_pixel_grid_is_every_pixel_drawn_whole():
    grid = SampleGrid.pixels((7, 9))
    assert grid.whole and grid.at is None and grid.samples == (7, 9)
    values = np.random.default_rng(0).random((7, 9))
    assert grid.canvas(values) is values
    assert grid.span(-3, 4, 0) == (0, 4) and grid.span(5, 20, 1) == (5, 9)
    one = SampleGrid.blocks((7, 9), 2, 1, 0)
    assert not one.whole and one.samples == (7, 9) and one.footprint().max() == 1


@pytest.mark.parametrize("grid", [SampleGrid.blocks((57, 43), 12, 5, 6), SampleGrid.pixels((20, 30))])
def test_span_tables_give_every_span(grid):
    """``span_table(axis)[p]`` is the first sample at or past pixel p: every (start, stop) of the
    canvas gets the samples ``span`` finds by search."""
    for axis in (0, 1):
        table, n = grid.span_table(axis), grid.shape[axis]
        assert len(table) == n + 1
        for start in range(n + 1):
            for stop in range(start, n + 1):
                assert (table[start], table[stop]) == grid.span(start, stop, axis)
