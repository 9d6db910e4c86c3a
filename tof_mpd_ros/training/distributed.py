"""Training on several processes or machines: data-parallel SGD with DistributedDataParallel.

Launched by ``torchrun`` (which sets ``RANK``, ``WORLD_SIZE``, ``LOCAL_RANK``, ``MASTER_ADDR``
and ``MASTER_PORT``), e.g. ``torchrun --nproc_per_node 2 -m tof_mpd_ros.cli.main train ...``,
every rank runs the same training script on the same frames:

* the networks start identical (the seeded initialisation; DDP also broadcasts rank 0's);
* each epoch's pixel stream (seeded by ``(seed, epoch)``, the same on every rank) is dealt to
  the ranks, rank r taking every W-th pixel from the r-th (:func:`shard_pixels`), and each rank
  steps on batches of ``batch_size / W``: DDP averages the ranks' gradients, so a step sees
  the same ``batch_size`` pixels as one process would (the same maths, a different summation
  order);
* rank 0 alone writes checkpoints and weights; every rank resumes from the same checkpoint
  (on multi-node runs ``--checkpoint-dir`` must be on storage every node sees).

The backend is gloo on CPUs and NCCL when every rank has a GPU.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass

import torch
import torch.distributed as dist

from ..errors import InputError

log = logging.getLogger(__name__)

CPU = torch.device("cpu")


@dataclass(frozen=True)
class Ranks:
    """This process's place among the training processes.

    Attributes:
        rank: 0-based rank (0 = the one that writes files and shows progress).
        world: number of processes.
        device: where this rank trains (``cpu``, or its GPU under NCCL).
        owns_group: this module started the process group (and ends it).
    """

    rank: int = 0
    world: int = 1
    device: torch.device = CPU
    owns_group: bool = False

    @property
    def main(self) -> bool:
        return self.rank == 0

    @property
    def distributed(self) -> bool:
        return self.world > 1


def launched_by_torchrun() -> bool:
    """Whether the environment asks for more than one training process."""
    return int(os.environ.get("WORLD_SIZE", "1")) > 1


def start(distributed: bool | None = None) -> Ranks:
    """Join the process group when asked (``distributed`` None = when launched by torchrun with
    more than one process); one process otherwise.

    Raises:
        InputError: ``distributed=True`` outside a torchrun launch.
    """
    wanted = launched_by_torchrun() if distributed is None else distributed
    if not wanted:
        return Ranks()
    if not launched_by_torchrun() and not dist.is_initialized():
        raise InputError("distributed training needs a torchrun launch (WORLD_SIZE > 1), e.g. "
                         "torchrun --nproc_per_node 2 -m tof_mpd_ros.cli.main train ...")
    owns = not dist.is_initialized()
    gpu = torch.cuda.is_available()
    if owns:
        dist.init_process_group(backend="nccl" if gpu else "gloo")
    rank, world = dist.get_rank(), dist.get_world_size()
    device = CPU
    if gpu and dist.get_backend() == "nccl":
        device = torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
        torch.cuda.set_device(device)
    log.info("rank %d of %d (%s, %s)", rank, world, dist.get_backend(), device)
    return Ranks(rank, world, device, owns)


def finish(ranks: Ranks) -> None:
    """Leave the process group if :func:`start` began it."""
    if ranks.owns_group and dist.is_initialized():
        dist.barrier()
        dist.destroy_process_group()


def rank_batch_size(batch_size: int, ranks: Ranks) -> int:
    """Each rank's share of a step's ``batch_size`` pixels.

    Raises:
        InputError: a batch that does not divide among the ranks.
    """
    if batch_size % ranks.world:
        raise InputError(f"batch size {batch_size} does not divide among {ranks.world} "
                         "processes; choose a multiple")
    return batch_size // ranks.world


def shard_pixels(flat: torch.Tensor, ranks: Ranks) -> torch.Tensor:
    """This rank's share of an epoch's pixel stream: every W-th from the r-th, cut to the same
    length on every rank (DDP needs the same number of steps everywhere). With the per-rank
    batch of :func:`rank_batch_size`, step s of the ranks together covers the pixels of one
    process's step s."""
    if not ranks.distributed:
        return flat
    n = flat.numel() // ranks.world
    return flat[ranks.rank::ranks.world][:n]


def wrap(module: torch.nn.Module, ranks: Ranks) -> torch.nn.Module:
    """``module`` on this rank's device, inside DDP when distributed (gradients averaged over
    the ranks in the backward pass)."""
    module.to(ranks.device)
    if not ranks.distributed:
        return module
    ids = [ranks.device.index] if ranks.device.type == "cuda" else None
    return torch.nn.parallel.DistributedDataParallel(module, device_ids=ids)


def sum_over_ranks(values: list[float], ranks: Ranks) -> list[float]:
    """Element-wise sum of ``values`` over the ranks (the values themselves in one process)."""
    if not ranks.distributed:
        return values
    t = torch.tensor(values, dtype=torch.float64, device=ranks.device)
    dist.all_reduce(t)
    return t.cpu().tolist()


def barrier(ranks: Ranks) -> None:
    if ranks.distributed:
        dist.barrier()


def check_in_step(module: torch.nn.Module, ranks: Ranks) -> None:
    """Raise unless every rank holds the same parameters (a sum and a position-weighted sum of
    every parameter, in float64, compared across the ranks).

    Raises:
        RuntimeError: the ranks' networks differ: the data-parallel run went wrong.
    """
    if not ranks.distributed:
        return
    total = torch.zeros(2, dtype=torch.float64)
    for p in module.state_dict().values():
        x = p.detach().double().cpu().reshape(-1)
        total += torch.stack([x.sum(), (x * torch.arange(1, x.numel() + 1,
                                                          dtype=torch.float64)).sum()])
    gathered = [torch.zeros_like(total) for _ in range(ranks.world)]
    dist.all_gather(gathered, total.to(ranks.device) if ranks.device.type == "cuda" else total)
    if any(not torch.equal(g.cpu(), gathered[0].cpu()) for g in gathered):
        raise RuntimeError(f"the {ranks.world} ranks ended with different networks")


__all__ = ["Ranks", "barrier", "check_in_step", "finish", "launched_by_torchrun",
           "rank_batch_size", "shard_pixels", "start", "sum_over_ranks", "wrap"]
