"""Data-parallel training under torchrun, with no new code in the training loop.

`torchrun --nproc_per_node N fignetctl train ...` starts N processes with RANK, LOCAL_RANK and
WORLD_SIZE set; each joins one process group (gloo on the CPU, nccl on GPUs), draws its own
batches, and DistributedDataParallel averages the gradients, so the effective batch is N times
--batch-size. Buffers (the normalizers' running statistics) are broadcast from rank 0 at each
forward pass, so every rank normalizes alike. Only rank 0 writes checkpoints.
"""

from __future__ import annotations

import os

import torch


def world_size() -> int:
    return int(os.environ.get("WORLD_SIZE", "1"))


def join_process_group(device: str) -> tuple[int, str]:
    """(rank, device of this process); joins torchrun's group when WORLD_SIZE > 1."""
    if world_size() == 1:
        return 0, device
    import torch.distributed as dist

    if device.startswith("cuda"):
        device = f"cuda:{int(os.environ.get('LOCAL_RANK', '0'))}"
        torch.cuda.set_device(device)
    if not dist.is_initialized():
        dist.init_process_group("nccl" if device.startswith("cuda") else "gloo")
    return dist.get_rank(), device


def data_parallel(module, device: str):
    """The module wrapped in DistributedDataParallel when there is more than one process."""
    if world_size() == 1:
        return module
    from torch.nn.parallel import DistributedDataParallel

    device_ids = [torch.device(device).index] if device.startswith("cuda") else None
    return DistributedDataParallel(module, device_ids=device_ids)


def gather_from_all(value) -> list:
    """[value of rank 0, value of rank 1, ...] on every rank; [value] in one process."""
    if world_size() == 1:
        return [value]
    import torch.distributed as dist

    gathered = [None] * world_size()
    dist.all_gather_object(gathered, value)
    return gathered


def barrier() -> None:
    if world_size() > 1:
        import torch.distributed as dist

        dist.barrier()
