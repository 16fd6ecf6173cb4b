"""--device auto (cuda if available, then mps, then cpu) and the memory check of a job on a CUDA
device against that device's own free memory. No GPU here: torch's CUDA queries are replaced."""

import pytest
import torch

from metalens_cli.cli.main import run
from metalens_cli.cli.options import Device, auto_device, torch_device
from metalens_cli.errors import InputError

SCAN = ["psf-scan", "--design", "hyperbolic:532nm", "--f", "4mm", "--aperture", "0.3mm", "--pixels", "33"]


def fake_gpu(monkeypatch, free_bytes: int = 80 * 2**30) -> list:
    """This machine seen as having one CUDA device with ``free_bytes`` free; returns the devices
    whose free memory was asked for."""
    asked = []

    def mem_get_info(device=None):
        asked.append(device)
        return free_bytes, 80 * 2**30

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    monkeypatch.setattr(torch.cuda, "current_device", lambda: 0)
    monkeypatch.setattr(torch.cuda, "mem_get_info", mem_get_info)
    return asked


def test_auto_is_the_cpu_on_this_machine():
    if torch.cuda.is_available() or torch.backends.mps.is_available():
        pytest.skip("this machine has an accelerator")
    assert auto_device() == "cpu" and torch_device("auto") == torch.device("cpu")


def test_auto_prefers_cuda_then_mps(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    monkeypatch.setattr(torch.backends.mps, "is_available", lambda: True)
    assert auto_device() == "mps" and torch_device("auto") == torch.device("mps")
    fake_gpu(monkeypatch)
    assert auto_device() == "cuda" and torch_device("auto") == torch.device("cuda")


def test_device_names_are_checked_for_form_without_torch():
    for name in ("auto", "cpu", "cuda", "cuda:1", "mps"):
        assert Device().convert(name, None, None) == name
    with pytest.raises(InputError, match="--device: unknown device 'gpu' .*expected auto, cpu, cuda, cuda:N or mps"):
        torch_device("gpu")


def test_bad_device_is_one_line_naming_the_accepted_form(capsys):
    assert run([*SCAN, "-o", "x.exr", "--device", "gpu"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--device" in err and "auto, cpu, cuda, cuda:N or mps" in err


def test_a_cuda_job_over_the_gpu_s_free_memory_is_refused_naming_it(monkeypatch, capsys, tmp_path):
    """--device auto resolves to the (fake) GPU, whose 1 MiB free refuses the scan before any work."""
    asked = fake_gpu(monkeypatch, free_bytes=2**20)
    out = tmp_path / "psf.exr"
    assert run([*SCAN, "--device", "auto", "-o", str(out), "--json"]) == 2
    stdout, err = capsys.readouterr()
    assert stdout == "" and err.count("\n") == 1 and not out.exists()
    assert "--pixels" in err and "over the free memory of GPU cuda:0 (922 KiB)" in err
    assert asked == [torch.device("cuda", 0)]


def test_a_cpu_job_is_checked_against_the_host_ram_not_the_gpu(monkeypatch, capsys, tmp_path):
    asked = fake_gpu(monkeypatch, free_bytes=2**20)
    assert run([*SCAN, "--device", "cpu", "-o", str(tmp_path / "psf.exr"), "--json", "--quiet"]) == 0
    assert asked == []
