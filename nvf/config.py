"""Typed settings of the method library, one dataclass per concern (METHOD.md section 16).

These are plain dataclasses: Hydra's structured configs in ``pipeline.config.structured_configs`` embed them, so every
value has exactly one home and one default. Defaults are the ``paper`` budget; smaller budgets
override resolutions and iteration counts only. A setting with a fixed set of values is a ``StrEnum``
field: OmegaConf refuses any other value when a config is composed, and a member compares equal to its
name (``entropy.bound == "huber"``). A numeric setting's allowed values are a ``Range`` declared on its field
(``ranged``), which validation and ``--help-keys`` read. A method's own settings are its class's fields
(``nvf.methods``).
"""

import dataclasses
import math
import typing
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any


@dataclass(frozen=True)
class Range:
    """A numeric setting's allowed values, declared on its field (``ranged``): ``low`` to ``high`` (None: unbounded
    on that side), each end excluded where ``*_open``. Validation (``pipeline.config.validation``) checks every
    declared field against it; a field whose value may be None is checked when it holds a number."""

    low: float | int | None = None
    high: float | int | None = None
    low_open: bool = False
    high_open: bool = False

    def problem(self, key: str, value: float | int) -> str | None:
        """One line saying why ``key=value`` is outside the range, or None when it is inside."""
        below = self.low is not None and (value <= self.low if self.low_open else value < self.low)
        above = self.high is not None and (value >= self.high if self.high_open else value > self.high)
        if not (below or above):
            return None
        return f"{key}={value!r} must be {self.text()}"

    def text(self) -> str:
        """The range as a reader writes it: ``positive``, ``in [0, 1)``, ``any number``."""
        if self == POSITIVE:
            return "positive"
        if self == ANY:
            return "any number"
        low = "-inf" if self.low is None else _number(self.low)
        high = "inf" if self.high is None else _number(self.high)
        return f"in {'(' if self.low_open else '['}{low}, {high}{')' if self.high_open else ']'}"


def _number(value: float | int) -> str:
    return str(value) if isinstance(value, int) else f"{value:g}"


POSITIVE = Range(0.0, low_open=True)
NON_NEGATIVE = Range(0.0)
UNIT = Range(0.0, 1.0)  # a share, probability or transmittance
ANY = Range()  # declared unbounded: every finite value means something (a row order in tables)


def ranged(default: Any, allowed: Range) -> Any:
    """A dataclass field with ``default`` whose values are ``allowed`` (its ``Range`` in the field's metadata)."""
    return field(default=default, metadata={"range": allowed})


def required(allowed: Range) -> Any:
    """A dataclass field without a default whose values are ``allowed``."""
    return field(metadata={"range": allowed})


def field_ranges(schema: type, prefix: str = "") -> dict[str, Range]:
    """The declared ``Range`` of every field of the dataclass ``schema`` and of the dataclasses it nests, by
    dotted key (``train.backbone.iters``)."""
    found: dict[str, Range] = {}
    hints = typing.get_type_hints(schema)
    for item in dataclasses.fields(schema):
        kind = hints[item.name]
        if dataclasses.is_dataclass(kind):
            found |= field_ranges(kind, f"{prefix}{item.name}.")  # type: ignore[arg-type]  # a dataclass type
        elif "range" in item.metadata:
            found[prefix + item.name] = item.metadata["range"]
    return found


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
    """The backbone's encoding: ``hashgrid`` (Instant-NGP, the paper's) or ``densegrid`` (DVGO-style, cheap on CPU)."""
    num_levels: int = ranged(16, POSITIVE)
    """Hash-grid levels, resolutions growing geometrically from ``base_resolution`` to ``max_resolution``."""
    features_per_level: int = ranged(2, POSITIVE)
    """Features per hash-grid level (the encoding is ``num_levels x features_per_level`` wide)."""
    log2_hashmap_size: int = ranged(19, POSITIVE)
    """log2 of a hash-grid level's table entries (a coarser level with fewer vertices is indexed densely)."""
    base_resolution: int = ranged(16, POSITIVE)
    """The coarsest hash-grid level's resolution."""
    max_resolution: int = ranged(512, POSITIVE)
    """The finest hash-grid level's resolution."""
    dense_resolution: int = ranged(128, POSITIVE)
    """Voxels per side of the dense grid (densegrid only)."""
    dense_features: int = ranged(32, POSITIVE)
    """Feature channels per voxel (densegrid only)."""
    hidden_dim: int = ranged(64, POSITIVE)
    """Width of the MLPs' hidden layers (density MLP, colour and variance heads)."""
    geo_feat_dim: int = ranged(15, NON_NEGATIVE)
    """Geometry features the density MLP passes to the heads beside the density."""
    mlp_bias: bool = False
    """Bias terms in the MLPs' layers (tiny-cuda-nn's fused MLPs, the reference's, have none)."""
    appearance_embedding: bool = False
    """D8: the reference's per-image appearance embedding in the colour and variance heads' input."""
    backend: HashBackend = HashBackend.auto
    """The hash grid's gather/scatter: ``torch``, ``cpp`` (the CPU kernel) or ``auto`` (cpp where it builds)."""


@dataclass
class SamplerConfig:
    """Occupancy grid and ray marching (METHOD.md section 4, M5, M6)."""

    grid_resolution: int = ranged(128, POSITIVE)
    """Occupancy-grid cells per side over the object AABB (M5)."""
    step_size: float = ranged(4.0 * math.sqrt(3.0) / 1000.0, POSITIVE)
    """D16: the marching step near the camera, in scene units, the same for every scene (M6)."""
    cone_angle: float = ranged(0.004, NON_NEGATIVE)
    """The marching step grows as ``cone_angle x t`` once that is longer than ``step_size`` (M6)."""
    near: float = ranged(0.05, NON_NEGATIVE)
    """Where marching starts along a ray, in scene units."""
    far: float = ranged(1000.0, POSITIVE)
    """Where marching ends along a ray (clipped to the grid), in scene units."""
    alpha_threshold: float = ranged(0.01, UNIT)
    """A marched sample with opacity below ``min(alpha_threshold, mean occupancy)`` is skipped."""
    early_stop_eps: float = ranged(1e-4, UNIT)
    """A ray stops once its transmittance falls below this."""
    update_every: int = ranged(16, POSITIVE)
    """Stage-1 iterations between occupancy-grid updates (M5)."""
    warmup_iters: int = ranged(256, NON_NEGATIVE)
    """Stage-1 iterations during which an update probes every cell (later: a quarter uniformly, a quarter occupied)."""
    occ_threshold: float = ranged(0.01, NON_NEGATIVE)
    """A cell is occupied when its value exceeds ``min(mean occupancy, occ_threshold)`` (M5)."""
    occ_decay: float = ranged(0.95, UNIT)
    """M5: a probed cell's value becomes ``max(occ_decay x value, density x step_size)``."""
    inference_jitter: bool = False
    """D15: the reference's random start offset on every render, not only in training."""
    max_samples_per_ray: int = ranged(1024, POSITIVE)
    """Marched samples kept per ray at most (the first ones)."""
    mask_density_with_grid: bool = True
    """Labels and planning filters read density 0 in cells the grid marks empty, the density as rendered."""
    uniform_samples: int = ranged(50, POSITIVE)
    """``nvf.entropy.sampler=uniform``: stratified samples per ray on ``[0, uniform_far]``."""
    uniform_far: float = ranged(10.0, POSITIVE)
    """``nvf.entropy.sampler=uniform``: the far end of the stratified samples, in scene units."""


@dataclass
class EntropyConfig:
    """NVF view entropy and its ablation switches (METHOD.md sections 5-8, 11)."""

    logdet_coeff: float = ranged(0.5, NON_NEGATIVE)
    """M10's ``c`` on the components' log-variances: 0.5 the entropy of a Gaussian (D1: the reference uses 1.0)."""
    bound: Bound = Bound.huber
    """The ray entropy: ``huber`` (M10's upper bound) or ``moment_matched`` (M12, the Loose ablation)."""
    use_visibility: bool = True
    """Read the visibility ``v`` in M7 and M9 (false: w/o Vis.)."""
    use_variance: bool = True
    """Read the variance head's ``q`` (false: w/o Var., every seen component at ``var_bg``)."""
    d0: float | int | str | None = None
    """M13's correlation length: null the scene's (1.0, Room 6.0), 0 none (Ind. Rays), ``auto`` or a number."""
    corr: Correlation = Correlation.quadratic
    """M13's correlation of neighbouring pixels: ``quadratic`` (the paper's) or ``exp``."""
    depth_mode: DepthMode = DepthMode.pixel
    """M15's depth per pixel, or per ``chunk_rays`` chunk as the reference's bug has it (D3)."""
    chunk_rays: int = ranged(4096, POSITIVE)
    """``depth_mode=chunk``: the row-major chunk that shares one depth."""
    sampler: EntropySampler = EntropySampler.occupancy
    """The samples the entropy is scored on: the marched ones (``occupancy``) or ``uniform`` ones (section 4)."""
    beta: float = ranged(0.95, UNIT)
    """M7's share of the NeRF's density in an unseen interval."""
    alpha_un: float = ranged(1.0 - math.exp(-0.01), UNIT)
    """M7's prior opacity of one unseen sample."""
    mu_un: float = ranged(0.5, UNIT)
    """The colour prior's mean of unseen space, per channel (M9)."""
    var_un: float = ranged(1.0, POSITIVE)
    """The colour prior's variance of unseen space, per channel (M9)."""
    var_bg: float = ranged(1e-4, POSITIVE)
    """The black background's colour variance, per channel (M9, M11's floor)."""
    visibility_source: VisibilitySource = VisibilitySource.head
    """Where the score reads ``v`` of M7 and M9: the ``head``, M17-M18 ``labels``, or the ``mesh`` (an oracle)."""


@dataclass
class StageBudget:
    """Iterations, batch size (rays or points) and learning rate of one training stage."""

    iters: int = required(POSITIVE)
    """The stage's iterations."""
    batch: int = required(POSITIVE)
    """Rays (backbone, variance head) or points (visibility head) per iteration."""
    lr: float = required(POSITIVE)
    """Adam's learning rate (the backbone's decays from it, ``train.lr_decay_horizon``)."""


STAGES = ("backbone", "variance", "visibility")  # TrainConfig's stages, in training order


@dataclass
class TrainConfig:
    """The three training stages (METHOD.md section 10)."""

    backbone: StageBudget = field(default_factory=lambda: StageBudget(5000, 4096, 1e-2))
    """Stage 1: hash grid, density MLP and colour head on the RGB loss (M20)."""
    variance: StageBudget = field(default_factory=lambda: StageBudget(500, 4096, 1e-3))
    """Stage 2: the variance head on the mixture's likelihood (M21)."""
    visibility: StageBudget = field(default_factory=lambda: StageBudget(500, 65536, 1e-3))
    """Stage 3: the visibility head on its labels (M17-M19)."""
    schedule: Schedule = Schedule.paper
    """``paper``: one Adam step per iteration on a fixed batch; ``reference``: the reference's (D5-D7)."""
    target_samples: int = ranged(1 << 18, POSITIVE)
    """``schedule=reference``: the kept samples per batch its dynamic batch aims at (D5)."""
    stage_order: StageOrder = StageOrder.var_first
    """Train the variance head before the visibility head (``var_first``) or after it (``vis_first``)."""
    var_loss_background: VarianceBackground = VarianceBackground.random
    """M21's ground truth on each ray's ``random`` background (M4), or on ``black``."""
    ablation_affects_training: bool = False
    """Let w/o Var. and w/o Vis. change the variance loss's mixture, as the reference does (section 11)."""
    lr_decay_horizon: int = ranged(10000, POSITIVE)
    """The backbone's lr decays as ``lr x 0.01^(k / horizon)`` over iterations ``k``."""
    label_samples: int = ranged(200, POSITIVE)
    """M17: stratified samples on each camera-to-point segment."""
    label_max_depth: float = ranged(10.0, POSITIVE)
    """M17: a camera labels a point only within this camera depth, in scene units."""
    label_margin: float = ranged(0.0, NON_NEGATIVE)
    """M17 deviation: the camera-to-point segment stops this far (scene units) short of the point."""
    label_cutoff: float = ranged(0.0, Range(0.0, 1.0, high_open=True))
    """M17 early stop: a segment stops once its transmittance is below this (0: never)."""
    label_lattice: int = ranged(0, NON_NEGATIVE)
    """M17's density read from a lattice this many times finer than the occupancy grid, trilinearly (0: the field)."""
    warm_start: bool = False
    """Deviation: start each step from the previous step's weights instead of fresh ones."""
    precision: Precision = Precision.fp32
    """The MLPs' layers in training: ``fp32``, ``bf16`` or ``fp16`` (``nvf.precision``)."""


@dataclass
class OptConfig:
    """Gradient refinement of the top candidates, -OPT (METHOD.md section 14)."""

    top_k: int = ranged(3, POSITIVE)
    """The best candidates refined."""
    iters: int = ranged(20, POSITIVE)
    """Adam steps per refinement."""
    lr: float = ranged(1e-4, POSITIVE)
    """Adam's learning rate on the pose parameters."""
    ray_fraction: float = ranged(0.1, Range(0.0, 1.0, low_open=True))
    """The share of each chunk's rays rendered per step."""
    chunk_rays: int = ranged(4096, POSITIVE)
    """Row-major chunk of the planning image from which ``ray_fraction`` of the rays is drawn."""
    param: PoseParam = PoseParam.quat_raw
    """The refined parameters: the raw ``[qx, qy, qz, qw, x, y, z]`` (``quat_raw``) or an ``se3`` update."""


@dataclass
class PlannerConfig:
    """Candidate poses, filters and selection (METHOD.md section 13)."""

    name: Planner = Planner.argmax
    """``argmax`` of the candidates' scores, or ``opt`` (-OPT: the best refined by gradient, METHOD 14)."""
    num_candidates: int = ranged(512, POSITIVE)
    """Candidate poses scored per step (fewer when the filters leave fewer)."""
    oversample: float = ranged(1.2, Range(1.0))
    """The base sampler draws ``floor(oversample x N)`` poses before its filters; the collision-free one ``3 N``."""
    resolution: int = ranged(300, POSITIVE)
    """Planning image side in pixels (90 degree field of view)."""
    density_threshold: float | None = ranged(None, POSITIVE)
    """M28's ``tau``: a candidate's camera centre must have density below it (null: the scene's)."""
    collision_free: bool | None = None
    """M29's collision-free sampler (null: the scene's choice, Room only)."""
    los_samples: int = ranged(200, POSITIVE)
    """M29: samples on the segment from the current camera to a candidate."""
    los_threshold: float = ranged(0.95, UNIT)
    """M29: the transmittance that segment must exceed."""
    los_unobserved_free: bool = False
    """M29 deviation: density 0 in cells no training sample reached."""
    los_source: LineOfSightSource = LineOfSightSource.model
    """M29's line of sight from the ``model`` (METHOD) or the scene ``mesh`` (a deviation, an oracle)."""
    random_filters: bool = False
    """D25: Random's candidates go through the filters too."""
    score_chunk_rays: int = ranged(8192, POSITIVE)
    """Rays rendered at once when scoring candidates (memory, not results)."""
    opt: OptConfig = field(default_factory=OptConfig)
    """-OPT's refinement (``planner=opt``)."""
