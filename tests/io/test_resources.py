"""Resource estimates: what a long job says before it starts, and the memory refusal."""

import pytest

from metalens_cli import machine
from metalens_cli.errors import InputError
from metalens_cli.io.resources import LONG_JOB_SECONDS, Estimate, check, is_long
from metalens_cli.machine import device_memory


def test_a_range_is_said_only_when_the_longest_differs_and_counts_as_long():
    converge = Estimate("η by convergence", 2**20, "--harmonics", 12.0, seconds_max=79.0)
    assert converge.describe() == "η by convergence: about 1 MiB of memory, about 12 s (up to 79 s)"
    assert is_long(converge)  # 79 s can be long though 12 s is typical
    assert not is_long(Estimate("short", 1, "--x", 12.0, seconds_max=LONG_JOB_SECONDS))
    assert (
        Estimate("fixed", 1, "--x", 200.0, seconds_max=250.0).describe().endswith("about 3 min")
    )  # within 1.5×: one figure
    assert not is_long(Estimate("unknown", 1, "--x"))


def test_memory_over_the_limit_is_refused_naming_the_option_and_the_estimate():
    with pytest.raises(InputError, match=r"--harmonics.*about 2 MiB of memory.*--max-memory limit \(1 MiB\)"):
        check(Estimate("η", 2 * 2**20, "--harmonics", 1.0), max_memory=2**20)
    check(Estimate("η", 2**19, "--harmonics", 1.0), max_memory=2**20)


def test_max_memory_given_replaces_the_free_memory_default(monkeypatch):
    """The refusal's advice works: a --max-memory above what is free lets a cautious estimate run."""
    monkeypatch.setattr(machine, "available_memory", lambda: 2**30)
    job = Estimate("evaluate", 2 * 2**30, "--pixels", 1.0)
    with pytest.raises(InputError, match=r"over the host RAM available on this machine \(922 MiB\)"):
        check(job)
    check(job, max_memory=3 * 2**30)


def test_a_job_longer_than_max_time_is_refused_by_its_longest_estimate():
    converge = Estimate("η", 1, "--harmonics", 600.0, seconds_max=7200.0)
    with pytest.raises(InputError, match=r"--harmonics.*up to 2.0 h.*--max-time limit \(60 min\)"):
        check(converge, max_seconds=3600.0)
    check(converge, max_seconds=7200.0)
    check(Estimate("days", 1, "--x", 1e7), max_seconds=float("inf"))
    with pytest.raises(InputError, match="--max-time"):  # the default refuses more than a day
        check(Estimate("days", 1, "--x", 1e7))
    check(Estimate("unknown", 1, "--x"), max_seconds=1.0)  # no estimate, nothing to refuse


def test_a_cuda_job_is_checked_against_the_gpu_s_free_memory(monkeypatch):
    """No GPU here: torch.cuda.mem_get_info is replaced by a device with 1 GiB free (of 80), and
    torch's caching allocator by one that holds nothing unused."""
    import torch

    asked = []

    def mem_get_info(device=None):
        asked.append(device)
        return 2**30, 80 * 2**30

    monkeypatch.setattr(torch.cuda, "mem_get_info", mem_get_info)
    monkeypatch.setattr(torch.cuda, "current_device", lambda: 0)
    monkeypatch.setattr(torch.cuda, "memory_reserved", lambda device=None: 3 * 2**30)
    monkeypatch.setattr(torch.cuda, "memory_allocated", lambda device=None: 3 * 2**30)
    job = Estimate("psf-scan", 2 * 2**30, "--pixels", 1.0)
    assert device_memory(torch.device("cuda", 1)) == (2**30, "the free memory of GPU cuda:1")
    with pytest.raises(InputError, match=r"--pixels.*about 2 GiB of memory.*over the free memory of GPU cuda:0"):
        check(job, device="cuda")  # plain cuda: the current device
    assert asked[-1] == torch.device("cuda", 0)
    check(Estimate("psf-scan", 2**29, "--pixels", 1.0), device=torch.device("cuda", 0))  # 0.5 GiB fits 90 % of 1
    monkeypatch.setattr(machine, "available_memory", lambda: 64 * 2**30)
    check(job, device="cpu")  # the host's 64 GiB of RAM, not the GPU's 1 GiB
    assert len(asked) == 3


def test_memory_torch_holds_cached_but_unused_counts_as_free_on_a_gpu(monkeypatch):
    """Found on an H200: after a field PSF set's FFTs the caching allocator held ~120 GiB it no
    longer used, which mem_get_info counts as taken; a job may use it (torch hands it out again)."""
    import torch

    monkeypatch.setattr(torch.cuda, "mem_get_info", lambda device=None: (19 * 2**30, 140 * 2**30))
    monkeypatch.setattr(torch.cuda, "memory_reserved", lambda device=None: 121 * 2**30)
    monkeypatch.setattr(torch.cuda, "memory_allocated", lambda device=None: 1 * 2**30)
    assert device_memory(torch.device("cuda", 0))[0] == 139 * 2**30


def test_a_host_job_is_checked_against_the_host_ram_and_says_so(monkeypatch):
    monkeypatch.setattr(machine, "available_memory", lambda: 2**30)
    for device in (None, "cpu", "mps"):
        assert device_memory(device) == (2**30, "the host RAM available on this machine")
        with pytest.raises(InputError, match=r"over the host RAM available on this machine \(922 MiB\)"):
            check(Estimate("simulate", 2**30, "--pixels", 1.0), device=device)
