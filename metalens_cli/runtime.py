"""Process-wide settings that the command-line app applies once at start-up (never on import),
and the one stopwatch every timed stage report uses (:class:`Stopwatch`).

The core allocates its FFT work arrays afresh on every call (tens of MB for a 512 × 512
capture). glibc's malloc hands blocks that large back to the kernel when they are freed (mmap
threshold, heap trimming), so the next call page-faults all of them in again (what that costs a 512²
capture: docs/benchmarks.md, image formation). :func:`retain_freed_memory` keeps freed blocks in the heap instead. It is
applied by ``metalens`` at start-up and by the benchmarks; a Python caller may call it too.
"""

from __future__ import annotations

import ctypes
import sys
import time

M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_BYTES = 32 << 20  # glibc's largest accepted mmap threshold on 64-bit systems
TRIM_THRESHOLD_BYTES = 1 << 30  # free heap kept before memory is handed back to the kernel


def retain_freed_memory() -> bool:
    """Make glibc keep freed blocks up to 32 MB in the heap, and up to 1 GiB of free heap
    before trimming. Returns whether the setting took (False off glibc, e.g. macOS or musl)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) & bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))


class Stopwatch:
    """Seconds per named stage, summed over laps (``times``: what reports print).

    :meth:`lap` adds the time since the previous lap (or the start, or :meth:`restart`) to a
    stage; with a CUDA ``device`` it first waits for the device, so that queued work counts in
    the stage that queued it. :meth:`add` sums in stages timed elsewhere (a PSF call's
    ``timing_s``), their names after ``prefix``."""

    def __init__(self, device=None):
        self.times: dict[str, float] = {}
        self.device = device
        self._t = time.perf_counter()

    def restart(self) -> None:
        """The next lap starts now."""
        self._t = time.perf_counter()

    def lap(self, name: str) -> None:
        """Add the seconds since the previous lap (or the start, or :meth:`restart`) to stage
        ``name``; with a CUDA ``device``, after waiting for it."""
        if getattr(self.device, "type", None) == "cuda":
            import torch

            torch.cuda.synchronize(self.device)
        now = time.perf_counter()
        self.times[name] = self.times.get(name, 0.0) + now - self._t
        self._t = now

    def add(self, times: dict[str, float], prefix: str = "") -> None:
        """Add ``times`` (seconds by stage) to the stages ``prefix + stage``."""
        for stage, seconds in times.items():
            self.times[prefix + stage] = self.times.get(prefix + stage, 0.0) + seconds
