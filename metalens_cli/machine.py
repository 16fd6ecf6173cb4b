"""What this machine has free for a job: host RAM (capped by a container's limit) and a CUDA
device's own memory. Read by the CLI's resource checks (``io.resources``) and by the public
API's argument checks (``metalens_cli.arguments``), which refuse a job before it allocates.
"""

from __future__ import annotations

from pathlib import Path

MEMORY_SHARE = 0.9  # of the available memory a job may plan to use


def available_memory() -> int | None:
    """Bytes this process can still allocate: the kernel's MemAvailable, capped by the cgroup
    (container) limit less its usage; None where neither can be read (not Linux)."""
    values = []
    try:
        with open("/proc/meminfo", encoding="ascii") as handle:
            for line in handle:
                if line.startswith("MemAvailable:"):
                    values.append(int(line.split()[1]) * 1024)
    except (OSError, ValueError, IndexError):
        pass
    try:
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        if limit != "max":
            used = int(Path("/sys/fs/cgroup/memory.current").read_text())
            values.append(max(int(limit) - used, 0))
    except (OSError, ValueError):
        pass
    return min(values) if values else None


def device_memory(device=None) -> tuple[int | None, str]:
    """(bytes free, which memory that is) for a job on ``device`` (a torch.device, a device name
    or None): a CUDA device's own free memory (``torch.cuda.mem_get_info``, plus what torch's
    caching allocator holds reserved but unused, which it hands out again), else the host's
    (:func:`available_memory`; mps shares it). torch is imported only for a CUDA device."""
    if device is not None and str(device).startswith("cuda"):
        import torch

        device = torch.device(device)
        if device.index is None:  # plain "cuda": the current device
            device = torch.device("cuda", torch.cuda.current_device())
        free, _total = torch.cuda.mem_get_info(device)
        cached = torch.cuda.memory_reserved(device) - torch.cuda.memory_allocated(device)
        return int(free + cached), f"the free memory of GPU {device}"
    return available_memory(), "the host RAM available on this machine"


def format_bytes(size: float) -> str:
    """``size`` bytes in binary units, three significant digits: "7.45 GiB"."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if size < 1024 or unit == "PiB":
            return f"{size:.3g} {unit}"
        size /= 1024
    raise AssertionError
