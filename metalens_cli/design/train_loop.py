"""The training loop shared by ``metalens optimize`` (``design.training``, the lens θ) and
``metalens reconstruct train`` (``design.reconstruct_training``, the network).

A run resumes from its newest checkpoint (checked by ``RunDirectory.latest_checkpoint``) or
starts at step 0; it saves a checkpoint (``step``, the run's own states, ``history`` with one row
per step done, ``rng``) and loss.csv every ``checkpoint_every`` steps and a checkpoint at the
end. Ctrl-C (KeyboardInterrupt) or SIGTERM (``errors.Terminated``) saves both for the steps
done and raises :class:`TrainingInterrupted`. Only rank 0 writes and reports progress; under
torchrun every rank runs every step, and :func:`update` sums gradients over ranks.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import torch

from metalens_cli.design import distributed
from metalens_cli.design.rundir import Checkpoint, RunDirectory
from metalens_cli.errors import MetalensError, Terminated

RNG_NOTE = "stateless: every draw is a function of (seed, step)"


class TrainingInterrupted(MetalensError):
    """Ctrl-C or SIGTERM during training: a checkpoint of ``step`` completed steps was written."""

    def __init__(self, step: int, checkpoint: Path | None):
        self.step, self.checkpoint = step, checkpoint
        super().__init__(f"interrupted after step {step}; checkpoint {checkpoint}")


def overrides(steps: int | None, seed: int | None) -> dict:
    """The ``steps`` and ``seed`` given on the command line (None: the preset's)."""
    return {k: v for k, v in (("steps", steps), ("seed", seed)) if v is not None}


def checkpoint_to_resume(run: RunDirectory, resume: bool, steps: int, lists: tuple[str, ...] = ()) -> Checkpoint | None:
    """--resume: the run's newest checkpoint, checked (``RunDirectory.latest_checkpoint``; None
    when there is none yet); a fresh run: None, after refusing a folder that holds a run."""
    if not resume:
        run.check_fresh()
        return None
    return run.latest_checkpoint(steps, lists)


def update(optimizer: torch.optim.Optimizer, scheduler, reported: torch.Tensor, ctx: distributed.Context) -> None:
    """Sum the gradients of ``optimizer``'s parameters and the ``reported`` loss terms over ranks
    (each rank's pre-scaled by its share of the batch, so the sums are the whole batch's; in
    place), then step ``optimizer`` and ``scheduler``."""
    if ctx.world > 1:
        for group in optimizer.param_groups:
            for p in group["params"]:
                distributed.all_reduce_sum(p.grad, ctx)
        distributed.all_reduce_sum(reported, ctx)
    optimizer.step()
    scheduler.step()


class TrainLoop:
    """``steps`` steps of one run in ``run``. A checkpoint holds the state dicts of ``modules``
    (name → model, optimizer, scheduler, …) and the entries ``extra()`` returns, which
    ``load_extra(state)`` reads back from a checkpoint's state. ``history`` holds one row per step
    done, ``start`` the steps done before this process."""

    def __init__(
        self,
        run: RunDirectory,
        ctx: distributed.Context,
        steps: int,
        checkpoint_every: int,
        modules: dict[str, object],
        extra: Callable[[], dict],
        load_extra: Callable[[dict], None],
    ):
        self.run, self.ctx, self.steps, self.checkpoint_every = run, ctx, steps, checkpoint_every
        self.modules, self.extra, self.load_extra = modules, extra, load_extra
        self.history: list[dict] = []
        self.start = 0

    def resume(self, checkpoint: Checkpoint | None, preset_text: str | None = None) -> None:
        """Continue from ``checkpoint`` (None: step 0); then rank 0 rewrites the run's preset file
        with ``preset_text`` (--steps or --seed on --resume): only now, so that a checkpoint that
        ``Checkpoint.restore`` refuses changes no file. Every rank waits for the others."""
        if checkpoint is not None:
            checkpoint.restore(**self.modules)
            self.load_extra(checkpoint.state)
            self.history, self.start = checkpoint.state["history"], checkpoint.step
        if self.ctx.is_main and preset_text is not None:
            self.run.write_text(self.run.preset_name, preset_text)
        distributed.barrier(self.ctx)

    def state(self, done: int) -> dict:
        """The checkpoint after ``done`` steps."""
        states = {name: module.state_dict() for name, module in self.modules.items()}
        return {"step": done, **states, **self.extra(), "history": self.history, "rng": RNG_NOTE}

    def train(
        self,
        step: Callable[[int], dict],
        on_step: Callable[[int, int, dict], None] | None = None,
        after_step: Callable[[int], None] | None = None,
    ) -> None:
        """Steps ``start`` … ``steps`` − 1 (0-based): ``step(s)`` runs step s on every rank and
        returns its row, to which ``seconds`` (wall time of the step) is added; rank 0 then calls
        ``on_step(done, steps, row)`` and ``after_step(done)`` (done = s + 1) before any checkpoint."""
        is_main, run = self.ctx.is_main, self.run
        try:
            for s in range(self.start, self.steps):
                t0 = time.perf_counter()
                row = step(s)
                row["seconds"] = time.perf_counter() - t0
                self.history.append(row)
                if not is_main:
                    continue
                if on_step is not None:
                    on_step(s + 1, self.steps, row)
                if after_step is not None:
                    after_step(s + 1)
                if (s + 1) % self.checkpoint_every == 0:
                    run.save_checkpoint(self.state(s + 1))
                    run.write_loss_csv(self.history)
        except (KeyboardInterrupt, Terminated):
            done = len(self.history)
            path = run.save_checkpoint(self.state(done)) if is_main else None
            if is_main:
                run.write_loss_csv(self.history)
            raise TrainingInterrupted(done, path) from None
        if is_main and self.steps > self.start:
            run.save_checkpoint(self.state(self.steps))
