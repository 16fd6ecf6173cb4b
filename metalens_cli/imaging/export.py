"""Export a trained reconstruction network with ``torch.export`` (a ``.pt2`` file that torch runs
without this package) and check it against :class:`~metalens_cli.imaging.restore.Reconstructor`.

The exported program takes one (3, H, W) float32 linear capture of any size (H, W ≥ 5) and
returns its reconstruction; positions are those of a whole, untiled image (the optical axis at
its centre), exactly as ``reconstruct apply`` uses for images within its memory budget.
"""

from __future__ import annotations

import copy
import errno
import io
import os
import shutil
import time
import warnings
from pathlib import Path

import numpy as np
import torch
from torch import nn

from metalens_cli.imaging.network import ReconstructionNet
from metalens_cli.io.atomic import atomic_write

CHECK_SIZES = ((96, 128), (75, 61))  # (H, W) of the test captures: a multiple of 2^depth and not


class WholeImage(nn.Module):
    """The network on whole images: positions from the image's own size."""

    def __init__(self, net: ReconstructionNet):
        super().__init__()
        self.net = net

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """A (3, H, W) float32 linear capture → its reconstruction (3, H, W), positions from the
        image's own size (the optical axis at its centre)."""
        return self.net(x[None].contiguous(memory_format=torch.channels_last))[0].contiguous()


def _write(path: str | Path, data: memoryview) -> None:
    """``data`` into ``path`` atomically, refused (ENOSPC) before writing when the disk has less
    free space. Python writes it: torch's own file writer aborts the process (a C++ exception
    in its destructor) on a full disk or the file-size limit, where Python raises an OSError."""
    folder = Path(path).parent
    if data.nbytes > shutil.disk_usage(folder).free:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
    with atomic_write(path) as temporary:
        temporary.write_bytes(data)


def export_program(reconstructor, path: str | Path, tolerance: float = 1e-5) -> dict:
    """Write the exported program to ``path`` (atomically), reload it and compare it with the
    reconstructor on seeded random captures of ``CHECK_SIZES``; report sizes, bytes, seconds,
    the largest absolute difference and whether it is within ``tolerance``."""
    start = time.perf_counter()
    # a CPU copy: the caller's network stays on its device (channels-last weights, as in apply)
    module = WholeImage(copy.deepcopy(reconstructor.net).cpu().eval())
    example = torch.rand(3, 64, 64, generator=torch.Generator().manual_seed(0))
    dynamic = torch.export.Dim.DYNAMIC
    with torch.no_grad():
        program = torch.export.export(module, (example,), dynamic_shapes={"x": {1: dynamic, 2: dynamic}})
    serialised = io.BytesIO()
    with warnings.catch_warnings():
        warnings.filterwarnings(
            "ignore", message="No complete tensor found"
        )  # channels-last weights: saved whole all the same
        torch.export.save(program, serialised)
    _write(path, serialised.getbuffer())
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="No complete tensor found")
        loaded = torch.export.load(str(path)).module()
    worst = 0.0
    rng = np.random.default_rng(0)
    for size in CHECK_SIZES:
        capture = rng.uniform(0, 1, size=(3, *size)).astype(np.float32)
        with torch.no_grad():
            exported = loaded(torch.from_numpy(capture)).numpy()
        worst = max(worst, float(np.abs(exported - reconstructor(capture)).max()))
    return {
        "output": str(path),
        "bytes": Path(path).stat().st_size,
        "seconds": time.perf_counter() - start,
        "checked_sizes": [list(s) for s in CHECK_SIZES],
        "max_abs_difference": worst,
        "tolerance": tolerance,
        "passed": worst <= tolerance,
        "torch": torch.__version__,
    }
