"""Sizes checked against memory before a run starts: for each size key, the bytes of the largest array
(or arrays alive together) that key alone makes the run allocate, once or per batch, a lower bound (the
working arrays around it only add). A run whose bound exceeds the memory it lives in is refused naming
the key and the number, instead of failing in the middle of a step (``budget.image_size=100000`` asked
for one 37 GiB float32 image; ``train.label_samples=1000000000`` died with an allocator traceback).

``SIZE_KEYS_BOUNDED`` lists the validated positive keys that scale no allocation of their own (times,
rates, lengths, caps) or one another key already bounds; every other positive key has an allocation here.
"""

import functools
import os
from dataclasses import dataclass

from pipeline.config.typed import Run

GIB = float(1 << 30)
EVAL_VIEWS = 20  # PROTOCOL 2.4: every scene has 20 evaluation views
FLOAT32, INT64 = 4.0, 8.0
XYZ = 3 * FLOAT32
# nvf.visibility.segment_transmittance (M17's labels, M29's line of sight from the model), per sample of one chunk
# (at least one segment's samples - 1): offsets, fractions, xyz positions and densities (float32), and while the
# box test runs its two [.., 3] boolean comparisons and their conjunction, all alive together
SEGMENT_BYTES = FLOAT32 + FLOAT32 + XYZ + FLOAT32 + 3 * 3.0

SIZE_KEYS_BOUNDED = {
    "budget.gt_samples": "part of budget.image_size's render (budget.image_size x budget.gt_samples per side)",
    "render.samples": "Cycles' samples per pixel: time, not memory",
    "planner.score_chunk_rays": "a chunk of one candidate view: at most planner.resolution squared rays",
    "planner.opt.chunk_rays": "a chunk of one candidate view: at most planner.resolution squared rays",
    "planner.opt.top_k": "at most planner.num_candidates poses",
    "planner.opt.iters": "iterations: time",
    "train.backbone.iters": "iterations: time",
    "train.variance.iters": "iterations: time",
    "train.visibility.iters": "iterations: time",
    "train.lr_decay_horizon": "a rate",
    "train.backbone.lr": "a rate",
    "train.variance.lr": "a rate",
    "train.visibility.lr": "a rate",
    "planner.opt.lr": "a rate",
    "train.label_max_depth": "a length",
    "field.features_per_level": "part of field.log2_hashmap_size's table",
    "field.base_resolution": "at most field.max_resolution; part of field.num_levels's table",
    "field.max_resolution": "part of field.log2_hashmap_size's table (its entries are the smaller of the two)",
    "field.dense_features": "part of field.dense_resolution's grid",
    "sampler.step_size": "a length: samples per ray are capped by sampler.max_samples_per_ray",
    "sampler.update_every": "a period",
    "sampler.max_samples_per_ray": "a cap on samples per ray",
    "sampler.uniform_far": "a length",
    "render.timeout": "seconds",
}


@dataclass(frozen=True)
class Allocation:
    """``nbytes`` of one array sized by ``key`` (and by the keys in ``also``), held in host memory or on the
    run's ``device``."""

    key: str
    nbytes: float
    what: str
    on_device: bool
    also: tuple[str, ...] = ()


def allocations(run: Run) -> list[Allocation]:
    """The largest array each size key of ``run`` makes the run allocate (lower bounds)."""
    b, s, f, p, t = run.budget, run.sampler, run.field, run.planner, run.train
    side = int(b.image_size) * int(b.gt_samples)
    pixels = int(b.image_size) ** 2
    view_rays = int(p.resolution) ** 2
    stages = set(run.method.stages)
    found = [
        Allocation(
            "budget.image_size",
            16.0 * side**2,
            f"one ground-truth render of {side}x{side} RGBA float32 samples "
            "(budget.image_size x budget.gt_samples per side)",
            on_device=False,
        ),
        Allocation(
            "budget.eval_size",
            12.0 * EVAL_VIEWS * int(b.eval_size) ** 2,
            f"the {EVAL_VIEWS} evaluation views' RGB float32 ground truth",
            on_device=False,
        ),
        Allocation(
            "budget.horizon",
            4 * FLOAT32 * pixels * int(b.horizon),
            "the training images of the last step (RGBA float32, at least one per step)",
            on_device=True,
            also=("budget.image_size",),
        ),
        Allocation(
            "planner.resolution", XYZ * view_rays, "one candidate view's ray directions (float32)", on_device=True
        ),
        Allocation(
            "planner.num_candidates",
            4 * FLOAT32 * int(p.num_candidates),
            "the candidate orientations drawn (float32 quaternions, at least planner.num_candidates)",
            on_device=True,
        ),
        Allocation(
            "sampler.grid_resolution",
            6.0 * int(s.grid_resolution) ** 3,
            "the occupancy grid (float32 values and two boolean masks per cell)",
            on_device=True,
        ),
        Allocation(
            "budget.gt_points",
            24.0 * int(b.gt_points),
            "the ground-truth surface points (float64 xyz)",
            on_device=False,
        ),
        Allocation(
            "budget.recon_points", XYZ * int(b.recon_points), "the reconstructed points (float32 xyz)", on_device=True
        ),
        Allocation(
            "budget.recon_batch",
            XYZ * int(b.recon_batch),
            "one point-cloud batch's ray directions (float32 xyz)",
            on_device=True,
        ),
    ]
    if f.kind == "densegrid":
        voxels = int(f.dense_resolution) ** 3 * int(f.dense_features)
        found.append(
            Allocation("field.dense_resolution", FLOAT32 * voxels, "the dense feature grid (float32)", on_device=True)
        )
    else:
        finest = min(2 ** int(f.log2_hashmap_size), (int(f.max_resolution) + 1) ** 3)
        coarsest = min(2 ** int(f.log2_hashmap_size), (int(f.base_resolution) + 1) ** 3)
        features = FLOAT32 * int(f.features_per_level)
        found += [
            Allocation(
                "field.log2_hashmap_size", features * finest, "the finest level's hash table (float32)", on_device=True
            ),
            Allocation(
                "field.num_levels",
                features * coarsest * int(f.num_levels),
                "the hash table of every level (float32; each level at least the coarsest one's entries)",
                on_device=True,
            ),
        ]
    hidden = int(f.hidden_dim)
    if "visibility" in stages:
        found.append(
            Allocation(
                "field.hidden_dim",
                FLOAT32 * hidden * int(t.visibility.batch),
                "one hidden layer's outputs for a visibility batch (float32)",
                on_device=True,
                also=("train.visibility.batch",),
            )
        )
    else:
        found.append(
            Allocation("field.hidden_dim", FLOAT32 * hidden**2, "one hidden layer's weights (float32)", on_device=True)
        )
    if "visibility" in stages or run.nvf.entropy.visibility_source == "labels":  # M17: stage 3's labels, or the scores'
        found.append(
            Allocation(
                "train.label_samples",
                SEGMENT_BYTES * (int(t.label_samples) - 1),
                "one chunk of M17's label samples (float32 offsets, fractions, xyz and densities and "
                "boolean box tests, at least train.label_samples - 1 per point)",
                on_device=True,
            )
        )
    for stage in ("backbone", "variance", "visibility"):
        batch = int(getattr(t, stage).batch)
        found.append(
            Allocation(
                f"train.{stage}.batch", XYZ * batch, "one batch's ray origins or points (float32 xyz)", on_device=True
            )
        )
    if t.schedule == "reference":
        rays = max(1, int(t.target_samples) // int(s.max_samples_per_ray))
        found.append(
            Allocation(
                "train.target_samples",
                XYZ * rays,
                "the dynamic batch's first rays (float32 xyz, train.target_samples / sampler.max_samples_per_ray)",
                on_device=True,
            )
        )
    collision_free = p.collision_free if p.collision_free is not None else run.scene.collision_free
    if collision_free and p.los_source == "model":
        found.append(
            Allocation(
                "planner.los_samples",
                SEGMENT_BYTES * (int(p.los_samples) - 1),
                "one chunk of M29's line-of-sight samples (float32 offsets, fractions, xyz and densities "
                "and boolean box tests, at least planner.los_samples - 1 per candidate)",
                on_device=True,
            )
        )
    if run.nvf.entropy.sampler == "uniform":
        chunk = min(int(p.score_chunk_rays), view_rays)
        found.append(
            Allocation(
                "sampler.uniform_samples",
                INT64 * chunk * int(s.uniform_samples),
                "one scoring chunk's uniform samples (their int64 ray indices)",
                on_device=True,
            )
        )
    return found


def host_memory() -> float:
    """Bytes of physical memory of this machine."""
    return float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))


def too_large(run: Run, host_bytes: float, device_bytes: float, device_name: str) -> str | None:
    """One line for the allocation that does not fit its memory by the largest factor (one that a single key
    sizes first, so the line names the key to lower), or None when all fit."""
    over = [
        (a.nbytes / (device_bytes if a.on_device else host_bytes), a)
        for a in allocations(run)
        if a.nbytes > (device_bytes if a.on_device else host_bytes)
    ]
    if not over:
        return None
    _, worst = min(over, key=lambda pair: (bool(pair[1].also), -pair[0]))
    limit, where = (device_bytes, device_name) if worst.on_device else (host_bytes, "this machine")
    lower = " or ".join((worst.key, *worst.also))
    value = functools.reduce(getattr, worst.key.split("."), run)
    return (
        f"{worst.key}={value}: {worst.what} needs {worst.nbytes / GIB:.1f} GiB, "
        f"more than the {limit / GIB:.1f} GiB of memory of {where}; lower {lower}"
    )
