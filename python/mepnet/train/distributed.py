"""This process's place in a torchrun job (nccl on CUDA, gloo on CPU) and the few collective
operations the training loop needs; all of them are no-ops in a single process."""

from __future__ import annotations

import datetime
import hashlib
import os
from dataclasses import dataclass
from typing import Any

import torch
from torch import nn

from mepnet.train.config import TrainConfig


@dataclass(frozen=True)
class Dist:
    """This process's place in the job."""

    rank: int
    world_size: int
    local_rank: int
    device: torch.device

    @property
    def main(self) -> bool:
        """Rank 0 logs, validates and writes files."""
        return self.rank == 0


def setup_distributed(cfg: TrainConfig) -> Dist:
    """Join the torchrun job if there is one (nccl on CUDA, gloo on CPU) and pick the device."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    local = int(os.environ.get("LOCAL_RANK", "0"))
    cuda = cfg.device == "cuda" or (cfg.device == "auto" and torch.cuda.is_available())
    device = torch.device(f"cuda:{local}" if cuda else "cpu")
    if cuda:
        torch.cuda.set_device(device)
    if world > 1:
        import torch.distributed as td

        # rank 0 validates while the others wait: allow an hour
        td.init_process_group(
            backend="nccl" if cuda else "gloo", timeout=datetime.timedelta(hours=1)
        )
    return Dist(rank=rank, world_size=world, local_rank=local, device=device)


def barrier(d: Dist) -> None:
    if d.world_size > 1:
        import torch.distributed as td

        td.barrier()


def all_mean(d: Dist, values: list[float]) -> list[float]:
    if d.world_size == 1:
        return values
    import torch.distributed as td

    t = torch.tensor(values, dtype=torch.float64, device=d.device)
    td.all_reduce(t)
    return (t / d.world_size).tolist()


def broadcast(d: Dist, obj: Any) -> Any:
    if d.world_size == 1:
        return obj
    import torch.distributed as td

    box = [obj]
    td.broadcast_object_list(box, src=0)
    return box[0]


def gather(d: Dist, obj: Any) -> list[Any]:
    if d.world_size == 1:
        return [obj]
    import torch.distributed as td

    out: list[Any] = [None] * d.world_size
    td.all_gather_object(out, obj)
    return out


def param_checksum(model: nn.Module) -> str:
    """SHA-256 of all parameters (names, shapes and bytes), to compare processes."""
    h = hashlib.sha256()
    for name, p in model.named_parameters():
        t = p.detach().to("cpu").contiguous()
        h.update(name.encode())
        h.update(str(tuple(t.shape)).encode())
        h.update(t.numpy().tobytes())
    return h.hexdigest()
