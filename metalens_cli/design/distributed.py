"""Data-parallel training with torch.distributed, as started by ``torchrun``.

Every rank computes the same PSFs (same seed, same step) and its share of the global image
batch; gradients are summed over ranks, each rank's loss being pre-scaled by its share, so the
update equals a single process's on the whole batch up to floating-point summation order.
Backend: gloo on CPU, NCCL on CUDA. Without torchrun (WORLD_SIZE unset or 1) nothing is set up.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import torch


@dataclass(frozen=True)
class Context:
    """This process's rank among ``world`` processes and the device it computes on."""

    rank: int
    world: int
    device: torch.device
    owns_group: bool

    @property
    def is_main(self) -> bool:
        """Rank 0 writes the run directory and reports progress."""
        return self.rank == 0

    def shard(self, count: int) -> list[int]:
        """The indices of a global batch of ``count`` that this rank computes (round robin)."""
        return list(range(self.rank, count, self.world))


def setup(device: torch.device) -> Context:
    """Join the process group torchrun describes (env WORLD_SIZE, RANK, LOCAL_RANK, MASTER_*)."""
    import torch.distributed as dist

    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return Context(0, 1, device, False)
    if device.type == "cuda":
        device = torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
        torch.cuda.set_device(device)
    owns = not dist.is_initialized()
    if owns:
        dist.init_process_group("nccl" if device.type == "cuda" else "gloo")
    return Context(dist.get_rank(), dist.get_world_size(), device, owns)


def all_reduce_sum(tensor: torch.Tensor, ctx: Context) -> torch.Tensor:
    """Sum ``tensor`` over ranks in place (no-op for one process); returns it. A tensor kept
    off the run's device (the learned filter lives on the host) is reduced through a copy on
    it, which NCCL needs."""
    if ctx.world > 1:
        import torch.distributed as dist

        staged = tensor if tensor.device == ctx.device else tensor.to(ctx.device)
        dist.all_reduce(staged, op=dist.ReduceOp.SUM)
        if staged is not tensor:
            tensor.copy_(staged)
    return tensor


def barrier(ctx: Context) -> None:
    """Wait until every rank reaches this point (a no-op for one process)."""
    if ctx.world > 1:
        import torch.distributed as dist

        dist.barrier()


def teardown(ctx: Context, finished: bool = True) -> None:
    """Leave the process group if :func:`setup` created it. After ``finished`` work every rank
    first waits for the others: a rank that tears its connections down while another still
    works makes gloo abort at exit ("terminate called without an active exception", 1 run in 3
    here). After an error there is no barrier: another rank may be inside a collective."""
    if ctx.owns_group:
        import torch.distributed as dist

        if finished:
            dist.barrier()
        dist.destroy_process_group()


@contextmanager
def session(device: torch.device) -> Iterator[Context]:
    """:func:`setup`, then :func:`teardown` (with the barrier only if the body finished)."""
    ctx = setup(device)
    try:
        yield ctx
    except BaseException:
        teardown(ctx, finished=False)
        raise
    teardown(ctx)
