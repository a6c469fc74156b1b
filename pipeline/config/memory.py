"""Sizes checked against memory before a run starts: for each size key, the bytes of the largest array
(or arrays alive together) that key alone makes the run allocate, once or per batch, a lower bound (the
working arrays around it only add). A run whose bound exceeds the memory it lives in is refused naming
the key and the number, instead of failing in the middle of a step (``budget.image_size=100000`` asked
for one 37 GiB float32 image; ``train.label_samples=1000000000`` died with an allocator traceback).

``SIZE_KEYS_BOUNDED`` lists the validated positive keys that scale no allocation of their own (times,
rates, lengths, caps) or one another key already bounds; every other positive key has an allocation here.

``stage_peaks`` predicts more than a bound: each stage's peak, the step's state and the stage's working set
together, as ``python -m pipeline.bench paper_shape`` measures it (docs/USAGE.md, "The paper budget on a GPU").
"""

import math
import os
from collections.abc import Callable
from dataclasses import dataclass

from nvf.config import FieldConfig
from nvf.density_lattice import lattice_vertices
from pipeline.config.typed_run import Run

GIB = float(1 << 30)
EVAL_VIEWS = 20  # PROTOCOL 2.4: every scene has 20 evaluation views
FLOAT32, INT64 = 4.0, 8.0
XYZ = 3 * FLOAT32
# nvf.visibility.segment_transmittance (M17's labels, M29's line of sight from the model), per sample of one chunk
# (at least one segment's samples - 1): offsets, fractions, xyz positions and densities (float32), and while the
# box test runs its two [.., 3] boolean comparisons and their conjunction, all alive together
SEGMENT_BYTES = FLOAT32 + FLOAT32 + XYZ + FLOAT32 + 3 * 3.0
LATTICE_VERTEX_BYTES = FLOAT32 + 1.0  # nvf.density_lattice: its float32 values and the boolean marks of the vertices

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
    "scene.density_threshold": "a density",
    "planner.density_threshold": "a density",
    "scene.cr_threshold": "a length",
    "sampler.far": "a length: samples per ray are capped by sampler.max_samples_per_ray",
    "nvf.entropy.chunk_rays": "the rows that share one depth (depth_mode=chunk): no array of its own",
    "nvf.entropy.var_un": "a variance",
    "nvf.entropy.var_bg": "a variance",
    "metrics.ssim_data_range": "an intensity range",
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


@dataclass(frozen=True)
class Term:
    """One row of ``TERMS``: the array a size key makes a run allocate, where ``applies`` to the run (every run when
    None): its bytes and its description as functions of the run, where it lives and the other keys that size it."""

    key: str
    nbytes: Callable[[Run], float]
    what: Callable[[Run], str]
    on_device: bool
    also: tuple[str, ...] = ()
    applies: Callable[[Run], bool] | None = None


def _side(run: Run) -> int:
    """A ground-truth render's samples per side (``budget.image_size x budget.gt_samples``)."""
    return int(run.budget.image_size) * int(run.budget.gt_samples)


def _hash_entries(run: Run, resolution: int) -> int:
    """Entries of a hash level of ``resolution`` (at most the table's size)."""
    return min(2 ** int(run.field.log2_hashmap_size), (resolution + 1) ** 3)


def _labels(run: Run) -> bool:
    """Whether the run computes M17's labels: stage 3's, or the scores' (``visibility_source=labels``)."""
    return "visibility" in run.method.stages or run.nvf.entropy.visibility_source == "labels"


def _collision_free(run: Run) -> bool:
    """Whether the planner draws with the collision-free sampler (the planner's setting, else the scene's)."""
    p = run.planner
    return bool(p.collision_free if p.collision_free is not None else run.scene.collision_free)


def _stage_batch(stage: str) -> Term:
    return Term(
        f"train.{stage}.batch",
        lambda r: XYZ * int(getattr(r.train, stage).batch),
        lambda r: "one batch's ray origins or points (float32 xyz)",
        on_device=True,
    )


TERMS: tuple[Term, ...] = (  # the largest array each size key makes a run allocate, in the order they are checked
    Term(
        "budget.image_size",
        lambda r: 16.0 * _side(r) ** 2,
        lambda r: (
            f"one ground-truth render of {_side(r)}x{_side(r)} RGBA float32 samples "
            "(budget.image_size x budget.gt_samples per side)"
        ),
        on_device=False,
    ),
    Term(
        "budget.eval_size",
        lambda r: 12.0 * EVAL_VIEWS * int(r.budget.eval_size) ** 2,
        lambda r: f"the {EVAL_VIEWS} evaluation views' RGB float32 ground truth",
        on_device=False,
    ),
    Term(
        "budget.horizon",
        lambda r: 4 * FLOAT32 * int(r.budget.image_size) ** 2 * int(r.budget.horizon),
        lambda r: "the training images of the last step (RGBA float32, at least one per step)",
        on_device=True,
        also=("budget.image_size",),
    ),
    Term(
        "planner.resolution",
        lambda r: XYZ * int(r.planner.resolution) ** 2,
        lambda r: "one candidate view's ray directions (float32)",
        on_device=True,
    ),
    Term(
        "planner.num_candidates",
        lambda r: CANDIDATE_FLOATS * FLOAT32 * drawn_poses(r),
        lambda r: (
            "the candidate draw (3 x planner.num_candidates poses for the collision-free sampler, else "
            "planner.oversample x): per pose its 7 float32s, the draw's intermediates and the density filter's hash "
            "encoding (M28)"
        ),
        on_device=True,
    ),
    Term(
        "sampler.grid_resolution",
        lambda r: 6.0 * int(r.sampler.grid_resolution) ** 3,
        lambda r: "the occupancy grid (float32 values and two boolean masks per cell)",
        on_device=True,
    ),
    Term(
        "budget.gt_points",
        lambda r: 24.0 * int(r.budget.gt_points),
        lambda r: "the ground-truth surface points (float64 xyz)",
        on_device=False,
    ),
    Term(
        "budget.recon_points",
        lambda r: XYZ * int(r.budget.recon_points),
        lambda r: "the reconstructed points (float32 xyz)",
        on_device=True,
    ),
    Term(
        "budget.recon_batch",
        lambda r: XYZ * int(r.budget.recon_batch),
        lambda r: "one point-cloud batch's ray directions (float32 xyz)",
        on_device=True,
    ),
    Term(
        "field.dense_resolution",
        lambda r: FLOAT32 * int(r.field.dense_resolution) ** 3 * int(r.field.dense_features),
        lambda r: "the dense feature grid (float32)",
        on_device=True,
        applies=lambda r: r.field.kind == "densegrid",
    ),
    Term(
        "field.log2_hashmap_size",
        lambda r: FLOAT32 * int(r.field.features_per_level) * _hash_entries(r, int(r.field.max_resolution)),
        lambda r: "the finest level's hash table (float32)",
        on_device=True,
        applies=lambda r: r.field.kind != "densegrid",
    ),
    Term(
        "field.num_levels",
        lambda r: (
            FLOAT32
            * int(r.field.features_per_level)
            * _hash_entries(r, int(r.field.base_resolution))
            * int(r.field.num_levels)
        ),
        lambda r: "the hash table of every level (float32; each level at least the coarsest one's entries)",
        on_device=True,
        applies=lambda r: r.field.kind != "densegrid",
    ),
    Term(
        "field.hidden_dim",
        lambda r: FLOAT32 * int(r.field.hidden_dim) * int(r.train.visibility.batch),
        lambda r: "one hidden layer's outputs for a visibility batch (float32)",
        on_device=True,
        also=("train.visibility.batch",),
        applies=lambda r: "visibility" in r.method.stages,
    ),
    Term(
        "field.hidden_dim",
        lambda r: FLOAT32 * int(r.field.hidden_dim) ** 2,
        lambda r: "one hidden layer's weights (float32)",
        on_device=True,
        applies=lambda r: "visibility" not in r.method.stages,
    ),
    Term(
        "train.label_samples",
        lambda r: SEGMENT_BYTES * (int(r.train.label_samples) - 1),
        lambda r: (
            "one chunk of M17's label samples (float32 offsets, fractions, xyz and densities and boolean box "
            "tests, at least train.label_samples - 1 per point)"
        ),
        on_device=True,
        applies=_labels,
    ),
    Term(
        "train.label_lattice",
        lambda r: lattice_bytes(r),
        lambda r: (
            "the density lattice of M17's labels (a float32 value and a boolean mark per vertex, "
            "(sampler.grid_resolution x train.label_lattice + 1)³ vertices)"
        ),
        on_device=True,
        also=("sampler.grid_resolution",),
        applies=lambda r: _labels(r) and lattice_bytes(r) > 0,
    ),
    *(_stage_batch(stage) for stage in ("backbone", "variance", "visibility")),
    Term(
        "train.target_samples",
        lambda r: XYZ * max(1, int(r.train.target_samples) // int(r.sampler.max_samples_per_ray)),
        lambda r: "the dynamic batch's first rays (float32 xyz, train.target_samples / sampler.max_samples_per_ray)",
        on_device=True,
        applies=lambda r: r.train.schedule == "reference",
    ),
    Term(
        "planner.los_samples",
        lambda r: SEGMENT_BYTES * (int(r.planner.los_samples) - 1),
        lambda r: (
            "one chunk of M29's line-of-sight samples (float32 offsets, fractions, xyz and densities and "
            "boolean box tests, at least planner.los_samples - 1 per candidate)"
        ),
        on_device=True,
        applies=lambda r: _collision_free(r) and r.planner.los_source == "model",
    ),
    Term(
        "sampler.uniform_samples",
        lambda r: (
            INT64
            * min(int(r.planner.score_chunk_rays), int(r.planner.resolution) ** 2)
            * int(r.sampler.uniform_samples)
        ),
        lambda r: "one scoring chunk's uniform samples (their int64 ray indices)",
        on_device=True,
        applies=lambda r: r.nvf.entropy.sampler == "uniform",
    ),
)


def allocations(run: Run) -> list[Allocation]:
    """The largest array each size key of ``run`` makes the run allocate (lower bounds): ``TERMS`` that apply."""
    return [
        Allocation(term.key, term.nbytes(run), term.what(run), term.on_device, term.also)
        for term in TERMS
        if term.applies is None or term.applies(run)
    ]


def lattice_bytes(run: Run) -> float:
    """Bytes of ``train.label_lattice``'s density lattice while it is built (``nvf.density_lattice``): a float32
    value and a boolean mark per vertex; 0 without one."""
    subdivisions = int(run.train.label_lattice)
    if subdivisions == 0:
        return 0.0
    return LATTICE_VERTEX_BYTES * lattice_vertices(int(run.sampler.grid_resolution), subdivisions)


def host_memory() -> float:
    """Bytes of physical memory of this machine."""
    return float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))


def drawn_poses(run: Run) -> int:
    """The poses the planner draws for ``planner.num_candidates`` (METHOD 13): 3 N for the collision-free
    sampler, else ``floor(planner.oversample N)``."""
    n = int(run.planner.num_candidates)
    return 3 * n if _collision_free(run) else math.floor(float(run.planner.oversample) * n)


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
    value = run.setting(worst.key)
    return (
        f"{worst.key}={value}: {worst.what} needs {worst.nbytes / GIB:.1f} GiB, "
        f"more than the {limit / GIB:.1f} GiB of memory of {where}; lower {lower}"
    )


# --- Peak memory of each stage of a step (``stage_peaks``). A step holds its state (the training images, the
# evaluation views' ground truth and LPIPS features, the field with its Adam moments, the occupancy grid), and
# each stage adds its working set: a batch or chunk of rays times the samples each marches (``marched_per_ray``:
# M6's steps along the object box's diagonal, a fully occupied grid) times the bytes those samples hold at
# once (the skipping pass's, and the kept samples' autograd graph). The bytes per marched sample were fitted to
# earlier runs of ``python -m pipeline.bench paper_shape`` (pyrender's ground truth; the peak minus the resident
# size before the stage, over rays x ``marched_per_ray``): one constant per kind of work for every scene, the
# geometric mean of the default scene's and Room's values, which differ up to 7x (a model at step 0 keeps 10
# samples per ray on one and 169 on the other). The committed run (results/bench/paper_shape.json) is the
# check: every stage within 2x (tests/test_memory.py). On the CPU the process itself is half of each peak, so
# the check is loose there; on CUDA (``on_device``) the working sets dominate and no GPU run has checked them yet.
PROCESS_BYTES = 0.85 * GIB  # resident before a step's first stage (0.85-0.91 GiB in runs of paper_shape)
TRAIN_SAMPLE_BYTES = 355.0  # stage 1: autograd through the encoding, the density MLP and the colour head
HEAD_SAMPLE_BYTES = 150.0  # stage 2: every head rendered, autograd through the variance head alone
SCORE_SAMPLE_BYTES = 390.0  # inference with every head and NVF's entropy terms (planning, evaluation)
POSE_SAMPLE_BYTES = 350.0  # -OPT: autograd through every head to the pose
DENSITY_SAMPLE_BYTES = 55.0  # density alone without autograd (point clouds)
LABEL_SAMPLE_BYTES = 600.0  # one M17 label position: its density without autograd (cpp encoding, the MLP in blocks)
VIS_POINT_BYTES = 2048.0  # stage 3: the visibility MLPs' autograd per point
# float32s a drawn candidate pose holds at the draw's peak: the pose (7), the draw's intermediates (positions,
# quaternions, their norms: 11) and the density filter's hash encoding of its centre (32), M28
CANDIDATE_FLOATS = 7 + 11 + 32
LABEL_CHUNK = 1 << 18  # nvf.visibility.segment_transmittance's positions per chunk
RENDER_CHUNK = 4096  # rays per call of an evaluation render (pipeline.episode.evaluation.RENDER_CHUNK)
GT_POINT_BYTES = 4 * 24.0  # float64 xyz of a mesh sample, with the KD-tree and distances over it
RENDER_PIXEL_BYTES = 24.0  # an evaluation render's colour, depth, accumulation and score (float32)
STAGES = (  # a step's stages, in the order they run (pipeline.bench.paper_shape)
    *("ground_truth", "backbone", "variance", "visibility", "candidates", "planning", "opt", "evaluation"),
    "mesh_metrics",
)


def marched_per_ray(cfg: Run) -> int:
    """M6's steps ``dt(t) = max(step_size, cone_angle t)`` from ``t = 0`` over the object box's diagonal,
    at most ``sampler.max_samples_per_ray``: the samples a ray marches through a fully occupied grid."""
    s = cfg.sampler
    box = cfg.scene.object_aabb
    diagonal = sum((float(hi) - float(lo)) ** 2 for lo, hi in zip(box[0], box[1], strict=True)) ** 0.5
    step, cone = float(s.step_size), float(s.cone_angle)
    knee = step / cone if cone > 0 else diagonal  # where the cone's step overtakes the fixed one
    steps = min(diagonal, knee) / step + (math.log(diagonal / knee) / cone if diagonal > knee else 0.0)
    return min(int(s.max_samples_per_ray), math.ceil(steps))


def alexnet_floats(side: int) -> int:
    """Floats of LPIPS' five AlexNet feature maps of a ``side x side`` image (conv1 stride 4, two max-pools)."""
    h1 = (side + 4 - 11) // 4 + 1
    h2 = (h1 - 3) // 2 + 1
    h3 = (h2 - 3) // 2 + 1
    return 64 * h1 * h1 + 192 * h2 * h2 + (384 + 256 + 256) * h3 * h3


def table_entries(f: FieldConfig) -> int:
    """Rows of the field's feature table (hash grid: every level; dense grid: its voxels)."""
    if f.kind == "densegrid":
        return int(f.dense_resolution) ** 3
    levels = int(f.num_levels)
    base, top = int(f.base_resolution), int(f.max_resolution)
    growth = (top / base) ** (1.0 / max(1, levels - 1))
    size = 2 ** int(f.log2_hashmap_size)
    return sum(min((int(base * growth**level + 1e-9) + 1) ** 3, size) for level in range(levels))


def stage_peaks(cfg: Run, views: int, eval_views: int = EVAL_VIEWS, on_device: bool = False) -> dict[str, float]:
    """Predicted peak bytes of each stage (``STAGES``) of a step with ``views`` training views and ``eval_views``
    evaluation views: the process's resident memory on the CPU, or with ``on_device`` what the CUDA device
    holds (the same model without the process, the host-only ground truth and the point clouds)."""
    b, p, t, f = cfg.budget, cfg.planner, cfg.train, cfg.field
    samples = marched_per_ray(cfg)
    features = int(f.dense_features) if f.kind == "densegrid" else int(f.features_per_level)
    table = FLOAT32 * features * table_entries(f)
    grid = 6.0 * int(cfg.sampler.grid_resolution) ** 3
    eval_pixels = eval_views * int(b.eval_size) ** 2
    images = views * int(b.image_size) ** 2 * 4 * FLOAT32  # the observations' RGBA
    device_state = images + grid + 2 * table  # the table and its last gradient
    host_state = PROCESS_BYTES + images + views * int(b.image_size) ** 2 * (4 * FLOAT32 + INT64)
    lpips_features = eval_views * alexnet_floats(int(b.eval_size)) * FLOAT32
    host_state += eval_pixels * XYZ + lpips_features
    working = {
        "ground_truth": 0.0,
        "backbone": 2 * table + int(t.backbone.batch) * samples * TRAIN_SAMPLE_BYTES,  # + Adam's two moments
        "variance": int(t.variance.batch) * samples * HEAD_SAMPLE_BYTES,
        "visibility": LABEL_CHUNK * LABEL_SAMPLE_BYTES + int(t.visibility.batch) * VIS_POINT_BYTES + lattice_bytes(cfg),
        "candidates": 0.0,
        "planning": min(int(p.score_chunk_rays), int(p.resolution) ** 2) * samples * SCORE_SAMPLE_BYTES,
        "opt": float(p.opt.ray_fraction) * int(p.resolution) ** 2 * samples * POSE_SAMPLE_BYTES,
        "evaluation": min(RENDER_CHUNK, int(b.eval_size) ** 2) * samples * SCORE_SAMPLE_BYTES,
        "mesh_metrics": int(b.recon_batch) * samples * DENSITY_SAMPLE_BYTES,
    }
    host_working = {
        "evaluation": eval_pixels * RENDER_PIXEL_BYTES + lpips_features,
        "mesh_metrics": int(b.gt_points) * GT_POINT_BYTES + int(b.recon_points) * 2 * XYZ,
    }
    if on_device:
        return {stage: device_state + working[stage] for stage in STAGES}
    state = host_state + device_state - images  # on the CPU the observations are the host's stacked images
    return {stage: state + working[stage] + host_working.get(stage, 0.0) for stage in STAGES}
