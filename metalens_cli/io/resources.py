"""What a job will cost, checked before it starts: memory against what its device has free (a
CUDA device's own memory, else this machine's, or its container's, RAM), disk against the output
folder's free space, and time for jobs that can take hours.

The estimates themselves come from the core (each knows its own arrays: ``optics.psf``,
``io.layout``, ...); this module reads the machine and decides. A job over the limit is refused
with its estimate and the option that changes it; ``--max-memory`` sets a stricter limit, and
``--max-time`` a limit on the estimated run time (a day unless told otherwise).
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass
from pathlib import Path

from metalens_cli.errors import InputError
from metalens_cli.machine import MEMORY_SHARE, device_memory, format_bytes

LONG_JOB_SECONDS = 60.0  # jobs estimated above this announce their estimate on stderr
MAX_SECONDS = 86400.0  # default --max-time: jobs whose longest estimate exceeds a day are refused


@dataclass(frozen=True)
class Estimate:
    """A job's planned peak memory (bytes), output size on disk (bytes) and run time (s; None when
    it cannot be long; ``seconds_max`` where the work depends on what it finds, e.g. a convergence
    loop, is the longest it can take). ``what`` says what is computed; ``option`` names what
    shrinks it."""

    what: str
    memory_bytes: int
    option: str
    seconds: float | None = None
    disk_bytes: int = 0
    seconds_max: float | None = None

    def describe(self) -> str:
        """One line for the user, ``WHAT: about MEMORY of memory, DISK on disk, about TIME (up to
        LONGEST)``: the disk only when non-zero, the time only when estimated, the longest only
        above 1.5× the time."""
        parts = [f"about {format_bytes(self.memory_bytes)} of memory"]
        if self.disk_bytes:
            parts.append(f"{format_bytes(self.disk_bytes)} on disk")
        if self.seconds is not None:
            parts.append(f"about {_duration(self.seconds)}")
            if self.seconds_max is not None and self.seconds_max > 1.5 * self.seconds:
                parts[-1] += f" (up to {_duration(self.seconds_max)})"
        return f"{self.what}: " + ", ".join(parts)


def check(
    estimate: Estimate,
    max_memory: int | None = None,
    output: str | os.PathLike[str] | None = None,
    max_seconds: float = MAX_SECONDS,
    device=None,
) -> None:
    """Refuse ``estimate`` (an :class:`InputError` naming its option, with the estimate) when its
    memory exceeds ``max_memory`` (default: 90 % of the free memory of ``device``,
    :func:`device_memory`: a CUDA device's own, else the host's RAM; a ``max_memory`` given
    replaces it, for an estimate the user knows to be too cautious), its disk bytes exceed the
    free space of ``output``'s folder, or its longest run time exceeds ``max_seconds`` (inf: no
    limit)."""
    if max_memory is not None:
        limits = [(max_memory, "the --max-memory limit")]
    else:
        available, which = device_memory(device)
        limits = [] if available is None else [(int(available * MEMORY_SHARE), which)]
    for limit, name in limits:
        if estimate.memory_bytes > limit:
            raise InputError(
                estimate.option,
                f"{estimate.describe()}, over {name} ({format_bytes(limit)})",
                f"a smaller {estimate.option}, or --max-memory if the estimate is too cautious",
            )
    if output is not None and estimate.disk_bytes:
        folder = Path(output).parent if not Path(output).is_dir() else Path(output)
        free = shutil.disk_usage(folder).free
        if estimate.disk_bytes > free:
            raise InputError(
                estimate.option,
                f"{estimate.describe()}, over the {format_bytes(free)} free in {str(folder)!r}",
                f"a smaller {estimate.option} or another disk",
            )
    longest = longest_seconds(estimate)
    if longest is not None and longest > max_seconds:
        raise InputError(
            estimate.option,
            f"{estimate.describe()}, over the --max-time limit ({_duration(max_seconds)})",
            f"a smaller {estimate.option}, or a longer --max-time (inf for none)",
        )


def longest_seconds(estimate: Estimate) -> float | None:
    """The longest the job may take (s): ``seconds_max`` where it has a range, else ``seconds``."""
    return estimate.seconds if estimate.seconds_max is None else estimate.seconds_max


def is_long(estimate: Estimate) -> bool:
    """Whether the job may take over LONG_JOB_SECONDS (its longest, where it has a range)."""
    longest = longest_seconds(estimate)
    return longest is not None and longest > LONG_JOB_SECONDS


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    if seconds < 172800:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 86400:.0f} days"
