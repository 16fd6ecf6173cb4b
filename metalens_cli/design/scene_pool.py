"""A run's batches of scenes drawn ahead: step s + 1's on a background thread while step s runs.

A step's clean scenes, obstruction colours and masks are numpy work on the host (``design.step.
step_batch``, 0.3-0.4 s of a quick step on 2 cores, and what a GPU step waits for). Each is a
pure function of (seed, step, index, canvas margin), so it can be drawn before the step that
uses it, as soon as its margin is known. :class:`ScenePool` keeps one worker thread (numpy
releases the GIL in its ufuncs) and the batches it was asked for, keyed by (step, margin);
``take`` hands a batch to the step (waiting for it if needed, drawing it in the caller's thread
if it was never asked for) on the run's device. What it draws does not depend on whether it
draws ahead: a pool with ``background=False`` gives the same batches, drawn when taken.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor

import torch

Batch = tuple[torch.Tensor, ...]


def draws_ahead(device) -> bool:
    """Whether a run draws its scenes on a background thread: on an accelerator (the host idles
    while the device runs the step), or on a CPU with a core the step's torch threads leave free.
    On 2 cores with 2 torch threads the background draw stalled the step's parallel regions more
    than it saved (quick preset: 1.57 s a step against 1.49 s drawing in the step;
    docs/benchmarks.md)."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    return torch.device(device).type != "cpu" or cores > torch.get_num_threads()


class ScenePool:
    """Batches ``draw(step, margin)`` (host tensors, or tensors already on ``device``) of steps
    below ``end``, drawn ahead on one background thread (``background``) and handed out on
    ``device``; on CUDA host batches are pinned in the worker and copied without blocking the
    host. Use it as a context manager (or call :meth:`close`): the worker is shut down at the end
    of a run and on errors."""

    def __init__(self, draw: Callable[[int, int], Batch], device, end: int, background: bool = True):
        self.device, self.end = torch.device(device), end
        self._draw = draw
        self._workers = ThreadPoolExecutor(1, thread_name_prefix="metalens-scenes") if background else None
        self._ahead: dict[tuple[int, int], Future] = {}

    @property
    def background(self) -> bool:
        """Whether batches are drawn ahead on the worker thread."""
        return self._workers is not None

    def prefetch(self, step: int, margin: int) -> None:
        """Start drawing the batch of ``step`` on the canvas of ``margin`` (pixels) in the
        background, unless it is already asked for, the run ends before ``step`` or the pool
        draws nothing ahead."""
        if self._workers is None or step >= self.end or (step, margin) in self._ahead:
            return
        self._ahead[(step, margin)] = self._workers.submit(self._host_batch, step, margin)

    def take(self, step: int, margin: int) -> Batch:
        """The batch of ``step`` on the canvas of ``margin`` on the run's device: the one drawn
        ahead (waiting for it to finish), else drawn now. Batches asked for at this step or
        before under another margin are dropped (one already being drawn finishes unused)."""
        future = self._ahead.pop((step, margin), None)
        for key in [key for key in self._ahead if key[0] <= step]:
            self._ahead.pop(key).cancel()
        batch = self._host_batch(step, margin) if future is None else future.result()
        return tuple(x.to(self.device, non_blocking=True) for x in batch)

    def _host_batch(self, step: int, margin: int) -> Batch:
        batch = self._draw(step, margin)
        on_host = self.device.type == "cuda" and batch[0].device.type == "cpu"
        return tuple(x.pin_memory() for x in batch) if on_host else batch

    def close(self) -> None:
        """Drop the batches not yet taken and stop the worker (after the batch it is drawing)."""
        self._ahead.clear()
        if self._workers is not None:
            self._workers.shutdown(wait=True, cancel_futures=True)

    def __enter__(self) -> ScenePool:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
