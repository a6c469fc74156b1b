"""Structured Hydra schema of one run (``RunConfig``), registered as ``run_schema``: every key's one default.

It embeds the method library's own dataclasses (``nvf.config``), so every value has one home, and
imports nothing heavier than them: tables can compose configs without loading torch. The conf files set
only what differs from these defaults. The method's node is its yaml: the keys of its own dataclass
(``nvf.methods``), built and checked with the rest when an entry point turns the composed config into the
typed ``pipeline.config.typed_run.Run`` that everything below it reads.
"""

import dataclasses
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

from hydra.core.config_store import ConfigStore
from omegaconf import MISSING

from nvf.config import (
    ANY,
    NON_NEGATIVE,
    POSITIVE,
    EntropyConfig,
    FieldConfig,
    PlannerConfig,
    Range,
    SamplerConfig,
    TrainConfig,
    ranged,
)
from pipeline.config.catalog import register_resolvers
from pipeline.records.store import MAX_SEED


@dataclass
class PathsConfig:
    """Where scene assets are read from, where runs are recorded, where tables, figures and benchmark reports
    go (the user's own folder beside the runs: the committed ``results/`` is rewritten only when asked for,
    ``paths.results=results``), and Blender's Python (relative to the repository root)."""

    assets: str = "${oc.env:NVF_ASSETS,data/assets}"
    """The scenes' mesh files, ``<scene>/<scene>.<ext>`` (``NVF_ASSETS`` where set)."""
    outputs: str = "outputs"
    """Where runs are recorded: ``<scene>/<method>-<planner>-<ablation>/<budget>/seed_<seed>/``."""
    results: str = "${paths.outputs}/results"
    """Where tables, figures, the site and benchmark reports go."""
    blender_python: str = "${oc.env:NVF_BLENDER_PYTHON,.venv-blender/bin/python}"
    """Blender's Python with ``bpy`` (``NVF_BLENDER_PYTHON`` where set), for ``render.backend=blender``."""


class RenderBackend(StrEnum):
    pyrender = "pyrender"
    blender = "blender"


class StepMetrics(StrEnum):
    all = "all"  # every metric at every step
    psnr = "psnr"  # steps before the last record PSNR alone (the last step every metric)


@dataclass
class RenderConfig:
    """Which ground-truth backend renders the RGB (PROTOCOL 1): ``pyrender`` (flat, unlit, ``budget.gt_samples``
    squared samples per pixel) or ``blender`` (Cycles, ``samples`` samples per pixel, lit; pipeline.scenes.blender).
    Depth, hit mask and face ids come from the same ray cast with either."""

    backend: RenderBackend = RenderBackend.pyrender
    """The ground truth's RGB: ``pyrender`` (flat, unlit) or ``blender`` (Cycles, lit; the paper's)."""
    samples: int = ranged(64, POSITIVE)
    """Cycles samples per pixel (blender only)."""
    timeout: float = ranged(1800.0, POSITIVE)
    """Seconds Blender's worker may take to answer one request (a view, opening a scene; blender only) before the
    run stops, left to resume: a 512-px view takes 24-75 s at 64 samples on a 2-core CPU (docs/BUDGETS.md)."""


@dataclass
class AssetFile:
    """A development file name of a scene's mesh (tried after ``<name>/<name>.<ext>``) and its up axis."""

    path: str = MISSING
    """The file, relative to ``paths.assets``."""
    up: str = "z"
    """Its up axis: ``z``, or ``y`` (a Y-up file is rotated (x, y, z) -> (x, -z, y))."""


@dataclass
class SceneConfig:
    """One scene, declared once in ``conf/scene/<name>.yaml`` (PROTOCOL.md 2; ``pipeline.scenes.loading`` builds
    it): where its mesh comes from, its boxes (``[[min x, y, z], [max x, y, z]]``), constants and view rigs."""

    name: str = MISSING
    """The scene's name (its yaml's and its asset folder's)."""
    kind: str = "object"
    """``object`` or ``room`` (tables average object scenes apart)."""
    source: str = "mesh"
    """Where its mesh comes from: ``mesh`` (an asset file), ``proxy`` or ``procedural`` (built from ``recipe``)."""
    recipe: str | None = None
    """``proxy`` / ``procedural``: the builder in pipeline.scenes.procedural."""
    paper_scene: str | None = None
    """The paper scene it is or stands in for (tables set the paper's numbers beside it)."""
    nerf_asset: bool = False
    """One of the paper's eight NeRF-asset scenes: averaged into the object-scene mean."""
    rank: int = ranged(100, ANY)
    """Its order in tables."""
    experiments: list[str] = dataclasses.field(default_factory=list)
    """The paper tables (conf/experiment) and experiments it joins."""
    files: list[AssetFile] = dataclasses.field(default_factory=list)
    """Development file names of its mesh, tried after ``<name>/<name>.<ext>``."""
    asset: str | None = None
    """``source: mesh``: the one file to build it from, relative to ``paths.assets`` (e.g.
    ``room/room_nvf_gt_yup.obj``), its up axis that of the ``files`` entry of the same path, else ``z``; null:
    the first file that exists of the lookup (``pipeline.scenes.loading``)."""
    fit_tight_box: bool = False
    """Scale the mesh uniformly into the tight box (Hubble)."""
    object_aabb: list[list[float]] = MISSING
    """Normalises the field, bounds the occupancy grid and the visibility labels' points."""
    camera_box: list[list[float]] = MISSING
    """Where candidate positions are drawn, and -OPT's clipping."""
    tight_box: list[list[float]] = MISSING
    """The ground-truth mesh's bounds."""
    density_threshold: float = ranged(1e-4, POSITIVE)
    """M28's ``tau``: a candidate's camera centre must have density below it."""
    d0: float = ranged(1.0, NON_NEGATIVE)
    """M13's correlation length (NVF's ``nvf.entropy.d0=null`` takes it)."""
    cr_threshold: float = ranged(0.01, POSITIVE)
    """The completion ratio's distance, in scene units (PROTOCOL 4.2)."""
    collision_free: bool = False
    """M29's collision-free candidate sampler (Room)."""
    init_views: dict[str, Any] = dataclasses.field(default_factory=dict)
    """The initial views: a rig of pipeline.scenes.views and its settings."""
    eval_views: dict[str, Any] = dataclasses.field(default_factory=dict)
    """The evaluation views: a rig of pipeline.scenes.views and its settings."""


@dataclass
class AblationConfig:
    """One NVF ablation (``conf/ablation/<name>.yaml``): the score switches it sets, its table label and order."""

    name: str = "none"
    """The ablation's name (``none``: full NVF)."""
    label: str = "NVF"
    """Its row name in tables."""
    rank: int = ranged(100, ANY)
    """Its row order in tables."""
    of: str = "nvf"
    """The method it ablates."""


@dataclass
class BudgetConfig:
    """What a budget scales besides training, planning and field sizes (docs/BUDGETS.md)."""

    name: str = "paper"
    """The budget's name (``paper``, ``cpu``, ``smoke``): tables never average runs of different budgets."""
    image_size: int = ranged(512, POSITIVE)
    """Ground-truth and training images, pixels per side (square, 90 degree field of view)."""
    eval_size: int = ranged(512, POSITIVE)
    """Evaluation renders of the 20 evaluation views, pixels per side."""
    horizon: int = ranged(20, POSITIVE)
    """Active-mapping steps."""
    gt_points: int = ranged(500_000, POSITIVE)
    """Area-uniform samples of the ground-truth mesh (PROTOCOL 4.2)."""
    recon_points: int = ranged(500_000, POSITIVE)
    """Reconstructed points from training-view rays (PROTOCOL 4.2)."""
    recon_batch: int = ranged(16_384, POSITIVE)
    """Pixels drawn per point-cloud batch."""
    gt_samples: int = ranged(1, POSITIVE)
    """Each ground-truth pixel (training, evaluation) the mean of k x k sub-pixel samples."""


@dataclass
class MetricsConfig:
    """How the image metrics are computed (PROTOCOL 4.1)."""

    ssim_data_range: float | None = ranged(None, POSITIVE)
    """SSIM's data range: null inferred from the image stacks (PROTOCOL 4.1), or a number such as 1.0."""


@dataclass
class DiagnosticsConfig:
    """Extra measurements recorded in each step's row; they never change a run's views or metrics, so they
    are not settings (records made with and without them are the same run)."""

    rank_against: str | None = None
    """An ablation (conf/ablation) whose score ranks the same candidates too (its agreement in each row)."""


@dataclass
class NvfConfig:
    """NVF's own settings, shared by its ablations and the variance head's loss."""

    entropy: EntropyConfig = dataclasses.field(default_factory=EntropyConfig)
    """NVF's view entropy (METHOD.md sections 5-8)."""


@dataclass
class RunConfig:
    """One run = (scene, method, planner, ablation, budget, seed)."""

    paths: PathsConfig = dataclasses.field(default_factory=PathsConfig)
    """Where assets, records and results live."""
    scene: SceneConfig = dataclasses.field(default_factory=SceneConfig)
    """The scene observed (``scene=<name>``, conf/scene)."""
    method: Any = dataclasses.field(default_factory=dict)
    """The method's yaml node (a mapping, ``method=<name>``, conf/method): pipeline.config.typed_run.Run holds the
    nvf.methods.Method built from it."""
    ablation: AblationConfig = dataclasses.field(default_factory=AblationConfig)
    """NVF's ablation (``ablation=<name>``, conf/ablation; ``none``: full NVF)."""
    planner: PlannerConfig = dataclasses.field(default_factory=PlannerConfig)
    """Candidate poses, filters and selection (``planner=argmax`` or ``opt``)."""
    budget: BudgetConfig = dataclasses.field(default_factory=BudgetConfig)
    """Image sizes, horizon and point counts (``budget=paper``, ``cpu`` or ``smoke``)."""
    render: RenderConfig = dataclasses.field(default_factory=RenderConfig)
    """The ground-truth renderer."""
    field: FieldConfig = dataclasses.field(default_factory=FieldConfig)
    """The backbone and heads."""
    sampler: SamplerConfig = dataclasses.field(default_factory=SamplerConfig)
    """Occupancy grid and ray marching."""
    train: TrainConfig = dataclasses.field(default_factory=TrainConfig)
    """The three training stages."""
    nvf: NvfConfig = dataclasses.field(default_factory=NvfConfig)
    """NVF's view entropy, read by NVF, its ablations and the variance head's loss."""
    metrics: MetricsConfig = dataclasses.field(default_factory=MetricsConfig)
    """How the image metrics are computed."""
    diagnostics: DiagnosticsConfig = dataclasses.field(default_factory=DiagnosticsConfig)
    """Extra measurements that never change the run."""
    seed: int = ranged(100, Range(0, MAX_SEED))
    """The run's seed: every random draw comes from a generator seeded from (seed, step, purpose)."""
    device: str = "auto"
    """Where the model runs: ``auto`` (CUDA where torch sees it), ``cpu``, ``cuda`` or ``cuda:N``."""
    save_images: bool = True
    """Save each step's pictures (ground truth, prediction, score map, depth) beside the record."""
    step_metrics: StepMetrics = StepMetrics.all
    """``all``: every metric at every step; ``psnr``: PSNR alone before the last step (not a setting)."""


def register_configs() -> None:
    """Register the schema under the name ``run_schema`` (first entry of conf/config.yaml's defaults) and the
    experiments' resolver (``pipeline.config.catalog.register_resolvers``)."""
    ConfigStore.instance().store(name="run_schema", node=RunConfig)
    register_resolvers()
