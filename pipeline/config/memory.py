"""Sizes checked against memory before a run starts: for each size key, the bytes of the largest single
array that key alone makes the run allocate, a lower bound (the working arrays around it only add).
A run whose bound exceeds the machine's memory is refused naming the key and the number, instead of
failing in the middle of a step (``budget.image_size=100000`` asked for one 37 GiB float32 image).
"""

import os
from dataclasses import dataclass

from omegaconf import DictConfig, OmegaConf

GIB = float(1 << 30)
EVAL_VIEWS = 20  # PROTOCOL 2.4: every scene has 20 evaluation views


@dataclass(frozen=True)
class Allocation:
    """``nbytes`` of one array sized by ``key``, held in host memory or on the run's ``device``."""

    key: str
    nbytes: float
    what: str
    on_device: bool


def allocations(cfg: DictConfig) -> list[Allocation]:
    """The largest array each size key of ``cfg`` makes a run allocate (lower bounds)."""
    b, s, f, p = cfg.budget, cfg.sampler, cfg.field, cfg.planner
    side = int(b.image_size) * int(b.gt_samples)
    found = [
        Allocation("budget.image_size", 16.0 * side**2, f"one ground-truth render of {side}x{side} RGBA float32 samples "
                   "(budget.image_size x budget.gt_samples per side)", on_device=False),
        Allocation("budget.eval_size", 12.0 * EVAL_VIEWS * int(b.eval_size) ** 2,
                   f"the {EVAL_VIEWS} evaluation views' RGB float32 ground truth", on_device=False),
        Allocation("planner.resolution", 12.0 * int(p.resolution) ** 2, "one candidate view's ray directions (float32)",
                   on_device=True),
        Allocation("sampler.grid_resolution", 6.0 * int(s.grid_resolution) ** 3,
                   "the occupancy grid (float32 values and two boolean masks per cell)", on_device=True),
        Allocation("budget.gt_points", 24.0 * int(b.gt_points), "the ground-truth surface points (float64 xyz)",
                   on_device=False),
        Allocation("budget.recon_points", 12.0 * int(b.recon_points), "the reconstructed points (float32 xyz)",
                   on_device=True),
    ]  # fmt: skip
    if f.kind == "densegrid":
        voxels = int(f.dense_resolution) ** 3 * int(f.dense_features)
        found.append(Allocation("field.dense_resolution", 4.0 * voxels, "the dense feature grid (float32)", on_device=True))
    else:
        entries = min(2 ** int(f.log2_hashmap_size), (int(f.max_resolution) + 1) ** 3)
        table = 4.0 * entries * int(f.features_per_level)
        found.append(Allocation("field.log2_hashmap_size", table, "the finest level's hash table (float32)", on_device=True))
    for stage in ("backbone", "variance", "visibility"):
        batch = int(cfg.train[stage].batch)
        found.append(Allocation(f"train.{stage}.batch", 12.0 * batch, "one batch's ray origins or points (float32 xyz)",
                                on_device=True))  # fmt: skip
    return found


def host_memory() -> float:
    """Bytes of physical memory of this machine."""
    return float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))


def too_large(cfg: DictConfig, host_bytes: float, device_bytes: float, device_name: str) -> str | None:
    """One line for the largest allocation that does not fit its memory, or None when all fit."""
    over = [
        (a.nbytes / (device_bytes if a.on_device else host_bytes), a)
        for a in allocations(cfg)
        if a.nbytes > (device_bytes if a.on_device else host_bytes)
    ]
    if not over:
        return None
    _, worst = max(over, key=lambda pair: pair[0])
    limit, where = (device_bytes, device_name) if worst.on_device else (host_bytes, "this machine")
    return (
        f"{worst.key}={OmegaConf.select(cfg, worst.key)}: {worst.what} needs {worst.nbytes / GIB:.1f} GiB, "
        f"more than the {limit / GIB:.1f} GiB of memory of {where}; lower {worst.key}"
    )
