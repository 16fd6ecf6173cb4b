"""A training step reads tensors on the host only where ``design.step.HOST_READS`` says (issue 56).

On CUDA every such read (``.item()``, ``.tolist()``, ``.cpu()``, ``bool(t)``, ...) makes the host
wait for the device. The tests run on the CPU, where no read waits, so the reads are counted as
calls: a ``TorchFunctionMode`` records every call of the reading methods during the steps with the
code that made it (the innermost frame outside torch and ``metalens_cli.arguments``' shared
checks), and the set of readers must be within the allow-list. A ``.to(device)`` is not counted:
on a CPU run the host and the run's device are one, and a copy to the host must be spelt
``.cpu()`` for the audit to see it. Also: a step's batch is the same whether the scenes are drawn
ahead on the pool's thread or in the step (``design.scene_pool``).
"""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

import pytest
import torch
from torch.overrides import TorchFunctionMode

import metalens_cli
from metalens_cli.design import distributed, step
from metalens_cli.design.training import _session
from metalens_cli.io.presets import load_preset
from metalens_cli.runtime import Stopwatch

TINY = Path(__file__).with_name("tiny.toml")
PACKAGE = Path(metalens_cli.__file__).parent
PASSED_THROUGH = (str(Path(torch.__file__).parent), str(PACKAGE / "arguments.py"))
READS = {
    torch.Tensor.item,
    torch.Tensor.tolist,
    torch.Tensor.numpy,
    torch.Tensor.cpu,
    torch.Tensor.__array__,
    torch.Tensor.__bool__,
    torch.Tensor.__float__,
    torch.Tensor.__int__,
    torch.Tensor.__index__,
}


class HostReads(TorchFunctionMode):
    """Records ``sites``: {(reader, method)}, the reader "path:function" (path in the package,
    else the file's name) of each host read made in this thread while the mode is on."""

    def __init__(self):
        super().__init__()
        self.sites: set[tuple[str, str]] = set()

    def __torch_function__(self, func, types, args=(), kwargs=None):
        if func in READS:
            frame = sys._getframe(1)
            while frame.f_back is not None and frame.f_code.co_filename.startswith(PASSED_THROUGH):
                frame = frame.f_back
            path = Path(frame.f_code.co_filename)
            where = path.relative_to(PACKAGE).as_posix() if path.is_relative_to(PACKAGE) else path.name
            self.sites.add((f"{where}:{frame.f_code.co_name}", func.__name__))
        return func(*args, **(kwargs or {}))


@pytest.fixture(scope="module")
def tiny():
    return load_preset(TINY)


def _with(preset, section: str, **changes):
    return dataclasses.replace(preset, **{section: dataclasses.replace(getattr(preset, section), **changes)})


def _recorded_steps(preset, steps: range, prefetch: bool = True) -> tuple[set, list[dict], torch.Tensor, dict]:
    """Steps 0 … max(steps) of ``preset``, those in ``steps`` under :class:`HostReads`: the
    sites, every step's loss.csv row, the final θ and the seconds by stage."""
    recorder, watch = HostReads(), Stopwatch()
    with distributed.session(torch.device("cpu")) as ctx:
        session = _session(preset, ctx, prefetch, max(steps) + 1)
        rows = []
        with session.scenes:
            for s in range(max(steps) + 1):
                if s in steps:
                    with recorder:
                        rows.append(step.one_step(session, preset, s, ctx, watch)[0])
                else:
                    rows.append(step.one_step(session, preset, s, ctx, watch)[0])
        return recorder.sites, rows, session.model.full_theta().detach(), watch.times


@pytest.mark.parametrize(
    "case", ["on axis", "camera", "scenes on the device", pytest.param("off axis", marks=pytest.mark.slow)]
)
def test_a_step_reads_the_host_only_where_logged(tiny, case):
    """Steps 1-2 (after the first, which builds the kernels; off axis, 18 s a step, the first
    alone): every reader is in the allow-list, also where the scenes and obstructions are drawn
    with torch (``design.device_scenes``)."""
    preset = {
        "on axis": tiny,
        "camera": _with(tiny, "optimize", light=2000.0),  # noise and its photon counts
        "off axis": _with(tiny, "optimize", field_angles_rad=(math.radians(4.0),)),  # every step at 4°
        "scenes on the device": _with(tiny, "optimize", scene_generator="torch", obstructions=("dirt", "fence")),
    }[case]
    sites, rows, *_ = _recorded_steps(preset, range(0, 1) if case == "off axis" else range(1, 3))
    assert sites, "the recorder saw nothing: it no longer sees the reads"
    readers = {reader for reader, _ in sites}
    assert readers <= set(step.HOST_READS), sorted(readers - set(step.HOST_READS))
    assert all(math.isfinite(row["total"]) for row in rows)


def test_the_recorder_catches_a_read_outside_the_allow_list(tiny, monkeypatch):
    """An ``.item()`` added to the step (here inside the PSF crop of the loss) is found, by name."""
    crop = step.sensor_psf

    def reading_crop(psf, preset):
        psf.sum().item()
        return crop(psf, preset)

    monkeypatch.setattr(step, "sensor_psf", reading_crop)
    sites, *_ = _recorded_steps(tiny, range(1, 2))
    assert ("test_step_sync.py:reading_crop", "item") in sites
    assert not {reader for reader, _ in sites} <= set(step.HOST_READS)


def test_the_allow_list_gives_a_reason_for_each_reader():
    assert all(":" in site and len(reason) > 20 for site, reason in step.HOST_READS.items())


def test_scenes_drawn_ahead_train_the_same_every_time(tiny):
    """Drawn ahead, a step's batch is a function of (seed, step, index, the margin of the
    capacities the step starts from), cropped to its PSFs' margin, whatever the worker's timing:
    two runs give the same loss rows and θ, bit for bit (with the doubled radial margin the first
    step's windows grow past the planned capacities: its batch is drawn again in the step). Drawn
    in the step, the batch is drawn on the margin the step's PSFs need."""
    wide = _with(tiny, "optimize", radial_margin=0.2)
    _, ahead, theta_ahead, times = _recorded_steps(wide, range(3, 4), prefetch=True)
    _, again, theta_again, _ = _recorded_steps(wide, range(3, 4), prefetch=True)
    _, inline, _, times_inline = _recorded_steps(wide, range(3, 4), prefetch=False)
    assert ahead == again and torch.equal(theta_ahead, theta_again)
    assert {"scenes", "scenes_redrawn"} <= set(times)
    assert "scenes" in times_inline and "scenes_redrawn" not in times_inline
