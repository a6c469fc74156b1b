"""What a run record holds, at record version ``RECORD_VERSION``: run.json (``RunInfo``) and each line of steps.jsonl
(``StepRow``) as dataclasses whose fields are the record's keys, in the order a record writes them. Each field's
docstring (the string on the line after it) says what the value is and its unit; its type says what JSON value it is
and, where it has one, its range (``Annotated[int, Range(1, MAX_VIEWS)]``; a metric's from ``pipeline.metrics.info``).

``pipeline.episode.loop`` builds a ``StepRow`` and the runner a ``RunStart`` and write ``as_json`` of them;
``pipeline.records.verify`` checks every record, read as this version (``pipeline.records.upgrade``), against these
types and ranges; docs/RECORDS.md is generated from this module (``scripts/records_doc.py``).

A key may be absent from a record unless its class lists it in ``REQUIRED`` (a record older than the key lacks it);
a key that is present holds a value of its field's type. Keys a class does not declare are kept as recorded (records
of other versions) and checked only as every record value is (``pipeline.records.verify.record_value_problem``).
"""

import dataclasses
import math
from dataclasses import dataclass
from typing import Annotated, Any, ClassVar, Literal

from pipeline.metrics.info import METRICS
from pipeline.records.store import IDENTITY_KEYS, MAX_SEED

RECORD_VERSION = 3  # the version this code writes (run.json's record_version); pipeline.records.upgrade reads older
SceneSource = Literal["procedural", "proxy", "mesh", "blend"]  # how a scene's mesh was built (run.json's scene_source)
MAX_HORIZON = 1000  # steps of a run: every step rewrites steps.jsonl whole; the paper's horizon is 20
MAX_VIEWS = 1_000_000  # n_views of a row
INT64 = 2**63 - 1
POSE_SIZE = 7  # [qx, qy, qz, qw, x, y, z]


@dataclass(frozen=True)
class Range:
    """The closed range ``[low, high]`` a number lies in (``high`` may be ``math.inf``)."""

    low: int | float
    high: int | float


@dataclass(frozen=True)
class Length:
    """How many items a list holds."""

    items: int


def metric_range(name: str) -> Range:
    """A metric's range as ``pipeline.metrics.info`` declares it (its ``bounds``)."""
    low, high = METRICS[name].bounds
    return Range(low, high)


COUNT = Range(0, INT64)
NONNEGATIVE = Range(0.0, math.inf)


def as_json(record: Any) -> Any:
    """A record dataclass as the JSON object a record holds: its fields in order, nested records as objects, and a
    field whose default is None left out while it is None (a key present only where it applies). Other values are
    returned as they are (``pipeline.records.store.to_jsonable`` makes them strict JSON when written)."""
    if dataclasses.is_dataclass(record) and not isinstance(record, type):
        return {
            field.name: as_json(getattr(record, field.name))
            for field in dataclasses.fields(record)
            if not (field.default is None and getattr(record, field.name) is None)
        }
    if isinstance(record, dict):
        return {key: as_json(value) for key, value in record.items()}
    return record


# ------------------------------------------------------------------------------------------------ steps.jsonl


@dataclass(frozen=True)
class Metrics:
    """A step's metrics of its trained model on the evaluation views (PROTOCOL 4), null where a metric is undefined
    or was not measured (``step_metrics=psnr``: PSNR alone before the last step). Their definitions are in run.json's
    ``metric_definitions``."""

    REQUIRED: ClassVar[tuple[str, ...]] = ()

    psnr: Annotated[float | None, metric_range("psnr")]
    """Peak signal-to-noise ratio of the evaluation views, in dB."""
    ssim: Annotated[float | None, metric_range("ssim")]
    """Structural similarity, mean over the evaluation views (no unit)."""
    lpips: Annotated[float | None, metric_range("lpips")]
    """Learned perceptual distance (AlexNet), mean over the views (no unit); null without its weights."""
    rgb: Annotated[float | None, metric_range("rgb")]
    """Mean squared error of the colours in [0, 1], over every evaluation pixel and channel."""
    acc: Annotated[float | None, metric_range("acc")]
    """Accuracy: mean distance from a reconstructed point to the nearest ground-truth point, in scene units."""
    comp: Annotated[float | None, metric_range("comp")]
    """Completeness: mean distance from a ground-truth point to the nearest reconstructed point, in scene units."""
    cr: Annotated[float | None, metric_range("cr")]
    """Completion ratio: the fraction of ground-truth points near a reconstructed point."""
    vis: Annotated[float | None, metric_range("vis")]
    """Visual coverage: the fraction of the mesh's faces seen from the observed poses (a face count)."""
    vis_area: Annotated[float | None, metric_range("vis_area")]
    """Visual coverage weighted by face area (logged, not in the paper's tables)."""
    num_points: Annotated[int | None, COUNT]
    """Points of the reconstructed point cloud that Acc., Comp. and C.R. read (a count)."""
    patch_pearson: Annotated[float | None, metric_range("patch_pearson")]
    """Pearson r of 32x32-patch means of error and uncertainty (no unit)."""
    view_pearson: Annotated[float | None, metric_range("view_pearson")]
    """Pearson r of per-view sums of error and uncertainty (no unit)."""
    ause: Annotated[float | None, metric_range("ause")]
    """Area under the sparsification error curve minus the oracle's (error units: a pixel's summed squared error)."""


@dataclass(frozen=True)
class CandidateScores:
    """The candidates' view rewards at the step (population statistics), in the method's score unit."""

    REQUIRED: ClassVar[tuple[str, ...]] = ()

    count: Annotated[int, COUNT]
    """Candidate poses drawn and kept by the filters (a count)."""
    min: float | None
    """The lowest reward; null for a method without a score (Random)."""
    mean: float | None
    """The mean reward; null without a score."""
    max: float | None
    """The highest reward; null without a score."""
    std: Annotated[float | None, NONNEGATIVE]
    """The rewards' population standard deviation; null without a score."""
    ties_at_max: Annotated[int | None, COUNT]
    """Candidates sharing the highest reward exactly (a count; above 1 the first drawn wins); null without a score."""


@dataclass(frozen=True)
class StageSummary:
    """One training stage of the step (nvf.training): its length, losses and time."""

    REQUIRED: ClassVar[tuple[str, ...]] = ()

    iters: Annotated[float, COUNT]
    """Iterations run (a count, written as a number)."""
    steps: Annotated[float, COUNT]
    """Optimiser steps taken (a count, written as a number; fewer than iters where fp16 skipped steps)."""
    first_loss: float | None
    """The stage's loss at its first iteration; null when it ran no iteration."""
    last_loss: float | None
    """The stage's loss at its last iteration; null when it ran no iteration."""
    seconds: Annotated[float, NONNEGATIVE]
    """Wall-clock seconds of the stage."""
    skipped_steps: Annotated[float, COUNT] | None = None
    """Optimiser steps fp16's loss scaling skipped (a count, written as a number); only with train.precision=fp16."""
    samples_per_ray: Annotated[float, NONNEGATIVE] | None = None
    """Mean samples kept per ray after alpha skipping (no unit); only in stages that render rays."""
    rays_per_batch: Annotated[float, NONNEGATIVE] | None = None
    """Mean rays per batch (a count; it varies with the reference's dynamic batch); only in stages that render rays."""
    first_aux_loss: float | None = None
    """The method's auxiliary loss at the first iteration (ActiveNeRF's M25, NeurAR's M27); only where it has one."""
    last_aux_loss: float | None = None
    """The method's auxiliary loss at the last iteration; only where it has one."""


@dataclass(frozen=True)
class StepSeconds:
    """Wall-clock seconds of the step's parts (vary between executions of one run)."""

    REQUIRED: ClassVar[tuple[str, ...]] = ()

    train: Annotated[float, NONNEGATIVE]
    """Training every stage, in seconds."""
    eval: Annotated[float, NONNEGATIVE]
    """Evaluating the trained model, in seconds."""
    plan: Annotated[float, NONNEGATIVE]
    """Drawing, scoring and choosing the candidates, in seconds."""


@dataclass(frozen=True)
class OptScores:
    """What -OPT did (METHOD 14), in the method's score unit."""

    REQUIRED: ClassVar[tuple[str, ...]] = ()

    original_scores: list[float | None]
    """The top-k candidates' full-image rewards, best first (null where not finite)."""
    refined_scores: list[float | None]
    """The refined poses' full-image rewards, in the order of their candidates."""


@dataclass(frozen=True)
class RankAgreement:
    """How the ``diagnostics.rank_against`` ablation's score ranks the step's candidates against the run's own."""

    REQUIRED: ClassVar[tuple[str, ...]] = ()

    against: str
    """The ablation ranked against (its name)."""
    spearman: Annotated[float | None, Range(-1.0, 1.0)]
    """Spearman correlation of the two scores over the candidates; null where either is constant or one candidate."""
    same_choice: bool
    """Whether both scores pick the same candidate."""


@dataclass(frozen=True)
class StepRow:
    """One line of steps.jsonl: a finished step of the episode (PROTOCOL 3), written once the step is complete."""

    REQUIRED: ClassVar[tuple[str, ...]] = ("step", "n_views", "status", "metrics", "selected_pose")

    step: Annotated[int, Range(0, MAX_HORIZON - 1)]
    """The step's index; rows hold steps 0, 1, ... in order."""
    n_views: Annotated[int, Range(1, MAX_VIEWS)]
    """Views the step trained on: the scene's initial views and one per earlier step (a count)."""
    status: Literal["ok"]
    """Always ``ok``: a step that cannot complete writes no row (the run is marked failed)."""
    metrics: Metrics
    """The trained model's metrics (below)."""
    selected_pose: Annotated[list[float], Length(POSE_SIZE)]
    """The chosen next view, [qx, qy, qz, qw, x, y, z]: a unit quaternion (camera to scene) and a position in scene
    units inside the scene's camera box (widened by a tenth of its size)."""
    selected_index: Annotated[int, COUNT]
    """The chosen candidate's index in draw order (for -OPT, the candidate its refined pose started from)."""
    selected_score: float | None
    """The chosen view's full-image reward, in the method's score unit; null for Random."""
    refined: bool
    """Whether -OPT refined the chosen pose."""
    candidate_scores: CandidateScores
    """The candidates' rewards (below)."""
    train: dict[str, StageSummary]
    """Each training stage the step ran (backbone, variance, visibility), in run order, with its summary (below)."""
    seconds: StepSeconds
    """Where the step's time went (below)."""
    opt: OptScores | None = None
    """-OPT's scores (below); only with planner=opt."""
    rank_agreement: RankAgreement | None = None
    """How a rival ranked the candidates (below); only with diagnostics.rank_against and a scoring method."""


# --------------------------------------------------------------------------------------------------- run.json


@dataclass(frozen=True)
class BudgetKeys:
    """``config.budget``: the budget's keys the runner reads (the others as the config declares them)."""

    REQUIRED: ClassVar[tuple[str, ...]] = ()

    horizon: Annotated[int, Range(1, MAX_HORIZON)]
    """Steps of the run (a count): a finished run has this many rows."""


@dataclass(frozen=True)
class MethodKeys:
    """``config.method``: how the tables name and order the method."""

    REQUIRED: ClassVar[tuple[str, ...]] = ()

    name: str
    """The method's name (conf/method/<name>.yaml)."""
    label: str
    """The tables' row name."""
    rank: int
    """The row's place in the tables (lower first)."""


@dataclass(frozen=True)
class AblationKeys:
    """``config.ablation``: how the tables name and order the ablation."""

    REQUIRED: ClassVar[tuple[str, ...]] = ()

    name: str
    """The ablation's name (conf/ablation/<name>.yaml; ``none`` for the method itself)."""
    label: str
    """The tables' row name."""
    rank: int
    """The row's place in the tables (lower first)."""
    of: str
    """The method it ablates."""


@dataclass(frozen=True)
class PlannerKeys:
    """``config.planner``: the planner's keys the tables read."""

    REQUIRED: ClassVar[tuple[str, ...]] = ()

    name: str
    """``argmax`` or ``opt`` (-OPT)."""
    los_source: str
    """Where M29's line of sight came from: ``model`` or ``mesh`` (an oracle)."""
    collision_free: bool | None
    """The collision-free sampler (M29) as configured; null: the scene's choice (run.json's collision_free)."""
    random_filters: bool
    """Whether Random's candidates went through the filters (METHOD 12)."""


@dataclass(frozen=True)
class SceneKeys:
    """``config.scene``: the scene's keys the tables and the checks read."""

    REQUIRED: ClassVar[tuple[str, ...]] = ()

    name: str
    """The scene's name (conf/scene/<name>.yaml)."""
    rank: int
    """The scene's place in the tables (lower first)."""
    paper_scene: str | None
    """The paper's scene it stands for; null for none."""
    nerf_asset: bool
    """Whether it counts in the object-scene mean."""
    camera_box: list[list[float]]
    """The box camera positions lie in, [[min x, y, z], [max x, y, z]] in scene units."""


@dataclass(frozen=True)
class RenderKeys:
    """``config.render``: the ground-truth renderer as configured."""

    REQUIRED: ClassVar[tuple[str, ...]] = ()

    backend: str
    """``pyrender`` or ``blender``."""
    samples: Annotated[int, COUNT] | None
    """Cycles' samples per pixel; null without Blender."""


@dataclass(frozen=True)
class RecordedConfig:
    """``config``: the run's whole composed config without ``paths`` (pipeline.config.structured_configs declares
    every key); the keys below are those the runner and the tables read."""

    REQUIRED: ClassVar[tuple[str, ...]] = ()

    budget: BudgetKeys
    """The budget (below)."""
    method: MethodKeys
    """The method (below)."""
    ablation: AblationKeys
    """The ablation (below)."""
    planner: PlannerKeys
    """The planner (below)."""
    scene: SceneKeys
    """The scene (below)."""
    render: RenderKeys
    """The ground-truth renderer (below)."""


@dataclass(frozen=True)
class GroundTruth:
    """How the ground truth was rendered (``pipeline.scenes.ground_truth.ground_truth_info``)."""

    REQUIRED: ClassVar[tuple[str, ...]] = ()

    backend: str
    """``pyrender`` or ``blender``."""
    asset: str | None
    """The mesh file, relative to paths.assets where it lies under it, else its absolute path; null for a procedural
    scene."""
    samples: Annotated[int, COUNT] | None = None
    """Cycles' samples per pixel; only with Blender."""
    device: str | None = None
    """Cycles' device; only with Blender."""
    blender: str | None = None
    """Blender's version; only with Blender."""


@dataclass(frozen=True)
class RunStart:
    """What the runner records of a run when it starts (``pipeline.episode.runner.run_info``): the first keys of
    run.json, in order."""

    REQUIRED: ClassVar[tuple[str, ...]] = (*IDENTITY_KEYS, "config")

    scene: str
    """The scene's name (a plain name of at most 64 characters, as the other identity keys)."""
    method: str
    """The method's name."""
    planner: str
    """The planner's name."""
    ablation: str
    """The ablation's name (``none`` for the method itself)."""
    budget: str
    """The budget's name."""
    seed: Annotated[int, Range(0, MAX_SEED)]
    """The run's seed: every draw is seeded from (seed, step, purpose)."""
    config: Annotated[dict[str, Any], RecordedConfig]
    """The run's config (``RecordedConfig``, below)."""
    scene_source: SceneSource
    """Where the scene's mesh came from: ``procedural``, ``proxy``, ``mesh`` (an asset file) or ``blend`` (a
    ``.blend`` read by Blender)."""
    ground_truth: Annotated[dict[str, Any] | None, GroundTruth]
    """How the ground truth was rendered (below); absent in records from before it was recorded (pyrender)."""
    collision_free: bool
    """Whether the candidates were drawn by the collision-free sampler (M29), as resolved for the scene."""
    candidate_filters: bool
    """Whether the candidates went through the filters (M28, M29): every method but Random, unless configured."""
    field: str
    """The backbone's encoding: ``hashgrid`` or ``densegrid``."""
    device: str
    """The torch device the run used (``cpu``, ``cuda:0``)."""
    torch_threads: Annotated[int, Range(1, 1 << 16)]
    """torch's CPU threads (a count): a record's numbers depend on it, a run resumes only with the same."""
    lpips_missing_reason: str | None
    """Why LPIPS is null in every row; null when it was measured."""
    record_version: Annotated[int, Range(1, RECORD_VERSION)] = RECORD_VERSION
    """The record version that wrote the record; absent in records from before it was written."""


@dataclass(frozen=True)
class GitState:
    """The checkout the run ran from."""

    REQUIRED: ClassVar[tuple[str, ...]] = ()

    commit: str | None
    """The commit's hash; null outside a git checkout."""
    dirty: bool | None
    """Whether the checkout had uncommitted changes; null outside a git checkout."""


@dataclass(frozen=True)
class Timings:
    """When the run started, resumed and ended (UTC, ISO 8601 with seconds)."""

    REQUIRED: ClassVar[tuple[str, ...]] = ()

    started: str
    """When the run first started."""
    resumed: list[str]
    """When it was resumed, each time."""
    ended: str | None
    """When it finished or failed; null while it runs."""


@dataclass(frozen=True, kw_only=True)
class RunInfo(RunStart):
    """run.json: what the runner records (``RunStart``), then what the record adds when the run starts and ends
    (``pipeline.records.store.RunRecord``)."""

    status: Literal["running", "done", "failed"]
    """``running`` until the run finishes (``done``) or fails (``failed``)."""
    git: GitState
    """The checkout (below)."""
    versions: dict[str, str | None]
    """The versions of the packages a run depends on, by name; null for one not installed."""
    metric_definitions: dict[str, str]
    """Each metric's definition, by name (pipeline.metrics.info)."""
    timings: Timings
    """When the run ran (below)."""
    failure_reason: str
    """Why the run failed (one line); only in a failed run."""
    record_digest: str
    """``sha256:<hex>`` of run.json's content and steps.jsonl, taken when the run ended; a changed record fails it."""
    steps_digest: str
    """``sha256:<hex>`` of steps.jsonl alone: the digest of records of version 2, in place of record_digest."""
