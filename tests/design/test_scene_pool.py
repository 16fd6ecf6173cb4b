"""The pool that draws each step's batch ahead (design.scene_pool): what it hands out, where it
is drawn, what it drops, errors and shutdown."""

from __future__ import annotations

import threading

import pytest
import torch

from metalens_cli.design.scene_pool import ScenePool


class Draws:
    """A stand-in for ``step_batch``: a batch that names its (step, margin), and the thread of each draw."""

    def __init__(self, gate: threading.Event | None = None):
        self.calls: list[tuple[int, int, str]] = []
        self.gate = gate

    def __call__(self, step: int, margin: int):
        if self.gate is not None:
            self.gate.wait(5)
        self.calls.append((step, margin, threading.current_thread().name))
        if margin < 0:
            raise RuntimeError(f"no canvas of margin {margin}")
        return (torch.full((1, 3, 4 + 2 * margin, 4 + 2 * margin), float(step)), torch.zeros(1, 1, 2, 2))


def test_a_batch_asked_for_ahead_is_drawn_on_the_worker_and_taken_once():
    draws = Draws()
    with ScenePool(draws, "cpu", end=10) as pool:
        pool.prefetch(3, 5)
        pool.prefetch(3, 5)  # asked for twice: drawn once
        clean, _ = pool.take(3, 5)
        assert clean.shape == (1, 3, 14, 14) and clean[0, 0, 0, 0] == 3
        assert [c[:2] for c in draws.calls] == [(3, 5)] and draws.calls[0][2].startswith("metalens-scenes")
        pool.take(3, 5)  # taken again: nothing ahead, drawn in the caller's thread
        assert draws.calls[-1][2] == threading.current_thread().name


def test_another_margin_is_drawn_now_and_stale_batches_dropped():
    gate = threading.Event()
    draws = Draws(gate)
    with ScenePool(draws, "cpu", end=10) as pool:
        pool.prefetch(1, 5)  # the worker waits at the gate with it
        pool.prefetch(2, 5)  # queued behind it
        gate.set()
        clean, _ = pool.take(2, 7)  # the step needs more: drawn now, the step's other batch dropped
        assert clean.shape[-1] == 18 and (2, 7, threading.current_thread().name) in draws.calls
        assert pool._ahead == {}


def test_no_batch_is_drawn_ahead_past_the_end_or_without_a_worker():
    draws = Draws()
    with ScenePool(draws, "cpu", end=2) as pool:
        pool.prefetch(2, 5)
        assert pool._ahead == {}
    with ScenePool(draws, "cpu", end=10, background=False) as pool:
        pool.prefetch(0, 5)
        assert pool._ahead == {} and draws.calls == []
        pool.take(0, 5)
        assert draws.calls == [(0, 5, threading.current_thread().name)]


def test_a_failed_draw_raises_in_the_step_that_takes_it_and_close_stops_the_worker():
    draws = Draws()
    pool = ScenePool(draws, "cpu", end=10)
    pool.prefetch(0, -1)
    with pytest.raises(RuntimeError, match="no canvas of margin -1"):
        pool.take(0, -1)
    pool.prefetch(1, 2)
    pool.close()
    assert not any(t.name.startswith("metalens-scenes") for t in threading.enumerate())
    with pytest.raises(RuntimeError):
        pool._workers.submit(draws, 2, 2)  # shut down
