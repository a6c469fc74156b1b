"""Typed settings of the method library, one dataclass per concern (METHOD.md section 16).

These are plain dataclasses: Hydra's structured configs in ``pipeline.config.schema`` embed them, so every
value has exactly one home and one default. Defaults are the ``paper`` budget; smaller budgets
override resolutions and iteration counts only. A setting with a fixed set of values is a ``StrEnum``
field: OmegaConf refuses any other value when a config is composed, and a member compares equal to its
name (``entropy.bound == "huber"``). A method's own settings are its class's fields (``nvf.methods``).
"""

import math
from dataclasses import dataclass, field
from enum import StrEnum


class FieldKind(StrEnum):
    hashgrid = "hashgrid"  # Instant-NGP, the paper's
    densegrid = "densegrid"  # DVGO-style, cheap on CPU


class HashBackend(StrEnum):
    auto = "auto"
    torch = "torch"
    cpp = "cpp"


class Bound(StrEnum):
    huber = "huber"  # M10
    moment_matched = "moment_matched"  # M12, "Loose"


class Correlation(StrEnum):
    quadratic = "quadratic"
    exp = "exp"


class DepthMode(StrEnum):
    pixel = "pixel"
    chunk = "chunk"  # D3, the reference's bug


class EntropySampler(StrEnum):
    occupancy = "occupancy"
    uniform = "uniform"


class VisibilitySource(StrEnum):
    """Where NVF's score reads ``v`` (METHOD 9.3, ``nvf.visibility_source``)."""

    head = "head"  # the visibility head (METHOD)
    labels = "labels"  # M17-M18 at the scored samples
    mesh = "mesh"  # the scene mesh's line of sight (an oracle)


class Schedule(StrEnum):
    paper = "paper"
    reference = "reference"  # D5-D7


class StageOrder(StrEnum):
    var_first = "var_first"
    vis_first = "vis_first"


class VarianceBackground(StrEnum):
    random = "random"
    black = "black"


class Precision(StrEnum):
    """The MLPs' layers in training (``nvf.precision``)."""

    fp32 = "fp32"
    bf16 = "bf16"
    fp16 = "fp16"


class Planner(StrEnum):
    argmax = "argmax"
    opt = "opt"  # -OPT, METHOD 14


class PoseParam(StrEnum):
    quat_raw = "quat_raw"
    se3 = "se3"


class LineOfSightSource(StrEnum):
    model = "model"  # METHOD's M29
    mesh = "mesh"  # deviation: the scene mesh's exact line of sight


@dataclass
class FieldConfig:
    """Backbone and heads (METHOD.md section 3)."""

    kind: FieldKind = FieldKind.hashgrid
    num_levels: int = 16
    features_per_level: int = 2
    log2_hashmap_size: int = 19
    base_resolution: int = 16
    max_resolution: int = 512
    dense_resolution: int = 128  # densegrid only
    dense_features: int = 32  # densegrid only: feature channels per voxel
    hidden_dim: int = 64
    geo_feat_dim: int = 15
    mlp_bias: bool = False  # tiny-cuda-nn fused MLPs have no biases
    appearance_embedding: bool = False  # D8: the reference's per-image embedding
    backend: HashBackend = HashBackend.auto  # hash-grid gather/scatter


@dataclass
class SamplerConfig:
    """Occupancy grid and ray marching (METHOD.md section 4, M5, M6)."""

    grid_resolution: int = 128
    step_size: float = 4.0 * math.sqrt(3.0) / 1000.0  # D16: the same for every scene
    cone_angle: float = 0.004
    near: float = 0.05
    far: float = 1000.0
    alpha_threshold: float = 0.01
    early_stop_eps: float = 1e-4
    update_every: int = 16
    warmup_iters: int = 256
    occ_threshold: float = 0.01
    occ_decay: float = 0.95
    inference_jitter: bool = False  # D15: the reference jitters every render
    max_samples_per_ray: int = 1024
    mask_density_with_grid: bool = True  # labels and filters read sigma = 0 in empty grid cells
    uniform_samples: int = 50  # entropy sampler=uniform: stratified on [0, uniform_far]
    uniform_far: float = 10.0


@dataclass
class EntropyConfig:
    """NVF view entropy and its ablation switches (METHOD.md sections 5-8, 11)."""

    logdet_coeff: float = 0.5  # D1: the reference uses 1.0
    bound: Bound = Bound.huber
    use_visibility: bool = True  # false: w/o Vis.
    use_variance: bool = True  # false: w/o Var.
    d0: float | int | str | None = None  # M13: None = the scene's (1.0, Room 6.0); 0 disables (Ind. Rays); "auto"
    corr: Correlation = Correlation.quadratic  # M13
    depth_mode: DepthMode = DepthMode.pixel
    chunk_rays: int = 4096  # depth_mode=chunk: row-major chunk size
    sampler: EntropySampler = EntropySampler.occupancy
    beta: float = 0.95
    alpha_un: float = 1.0 - math.exp(-0.01)
    mu_un: float = 0.5
    var_un: float = 1.0
    var_bg: float = 1e-4
    visibility_source: VisibilitySource = VisibilitySource.head  # v of M7/M9


@dataclass
class StageBudget:
    """Iterations, batch size (rays or points) and learning rate of one training stage."""

    iters: int
    batch: int
    lr: float


STAGES = ("backbone", "variance", "visibility")  # TrainConfig's stages, in training order


@dataclass
class TrainConfig:
    """The three training stages (METHOD.md section 10)."""

    backbone: StageBudget = field(default_factory=lambda: StageBudget(5000, 4096, 1e-2))
    variance: StageBudget = field(default_factory=lambda: StageBudget(500, 4096, 1e-3))
    visibility: StageBudget = field(default_factory=lambda: StageBudget(500, 65536, 1e-3))
    schedule: Schedule = Schedule.paper
    target_samples: int = 1 << 18  # schedule=reference: kept samples per batch of the dynamic batch (D5)
    stage_order: StageOrder = StageOrder.var_first
    var_loss_background: VarianceBackground = VarianceBackground.random  # M21
    ablation_affects_training: bool = False
    lr_decay_horizon: int = 10000  # backbone lr(k) = lr * 0.01 ** (k / horizon)
    label_samples: int = 200  # M17: samples on each camera-to-point segment
    label_max_depth: float = 10.0
    label_margin: float = 0.0  # M17 deviation: the camera-to-point segment stops this far (scene units) short of x
    label_cutoff: float = 0.0  # M17 early stop: a segment stops once its transmittance is below this (0: never)
    warm_start: bool = False  # deviation: reuse the previous step's weights instead of retraining
    precision: Precision = Precision.fp32


@dataclass
class OptConfig:
    """Gradient refinement of the top candidates, -OPT (METHOD.md section 14)."""

    top_k: int = 3
    iters: int = 20
    lr: float = 1e-4
    ray_fraction: float = 0.1
    chunk_rays: int = 4096
    param: PoseParam = PoseParam.quat_raw


@dataclass
class PlannerConfig:
    """Candidate poses, filters and selection (METHOD.md section 13)."""

    name: Planner = Planner.argmax
    num_candidates: int = 512
    oversample: float = 1.2  # base sampler draws floor(1.2 N); collision-free draws 3 N
    resolution: int = 300  # planning image side (f = W / 2)
    density_threshold: float | None = None  # None: the scene's tau (1e-4, Hubble 1e-3)
    collision_free: bool | None = None  # None: the scene's choice (Room only)
    los_samples: int = 200
    los_threshold: float = 0.95
    los_unobserved_free: bool = False  # M29 deviation: density 0 in cells no training sample reached
    los_source: LineOfSightSource = LineOfSightSource.model  # M29
    random_filters: bool = False
    score_chunk_rays: int = 8192
    opt: OptConfig = field(default_factory=OptConfig)
