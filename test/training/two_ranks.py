"""Run a training function as two gloo ranks (what torchrun would set up) and check they end
in step: shared by the data-parallel tests of both model kinds."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
import torch.multiprocessing as mp


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def set_rank_environment(rank: int, world: int, port: int) -> None:
    """The environment torchrun gives rank ``rank`` of ``world`` on this machine."""
    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), RANK=str(rank),
                      WORLD_SIZE=str(world), LOCAL_RANK=str(rank))


def run_two_ranks(rank_main: Callable[[int, int, int, str], None], out: Path
                  ) -> list[dict[str, Any]]:
    """Spawn ``rank_main(rank, 2, port, out)`` on two processes; each must save
    ``{"state": ..., "history": ...}`` to ``out/rank{rank}.pt``. Asserts both ranks end with
    identical parameters and returns what they saved."""
    mp.spawn(rank_main, args=(2, free_port(), str(out)), nprocs=2, join=True)
    ranks = [torch.load(out / f"rank{r}.pt", weights_only=True) for r in range(2)]
    for key, value in ranks[0]["state"].items():
        assert torch.equal(value, ranks[1]["state"][key]), key
    return ranks


def torchrun_cli(args: list[str]) -> subprocess.CompletedProcess:
    """``torchrun --nproc_per_node 2 -m tof_mpd_ros.cli.main ARGS`` on this machine, one
    thread per process, with this checkout on the path (10 min at most)."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": os.pathsep.join(
        [str(Path(__file__).resolve().parents[2]), os.environ.get("PYTHONPATH", "")])}
    cmd = [sys.executable, "-m", "torch.distributed.run", "--nproc_per_node", "2",
           "--master_addr", "127.0.0.1", "--master_port", str(free_port()),
           "-m", "tof_mpd_ros.cli.main", *args]
    return subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
