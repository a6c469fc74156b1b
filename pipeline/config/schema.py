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

from nvf.config import EntropyConfig, FieldConfig, PlannerConfig, SamplerConfig, TrainConfig
from pipeline.config.catalog import register_resolvers


@dataclass
class PathsConfig:
    """Where scene assets are read from, where runs are recorded, where tables, figures and benchmark reports
    go (the user's own folder beside the runs: the committed ``results/`` is rewritten only when asked for,
    ``paths.results=results``), and Blender's Python (relative to the repository root)."""

    assets: str = "${oc.env:NVF_ASSETS,data/assets}"
    outputs: str = "outputs"
    results: str = "${paths.outputs}/results"
    blender_python: str = "${oc.env:NVF_BLENDER_PYTHON,.venv-blender/bin/python}"  # Blender's Python (bpy)


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
    samples: int = 64  # Cycles samples per pixel (blender only)
    # seconds Blender's worker may take to answer one request (a view, opening a scene; blender only) before the
    # run stops, left to resume: a 512-px view takes 24-75 s at 64 samples on a 2-core CPU (docs/BUDGETS.md)
    timeout: float = 1800.0


@dataclass
class AssetFile:
    """A development file name of a scene's mesh (tried after ``<name>/<name>.<ext>``) and its up axis."""

    path: str = MISSING
    up: str = "z"  # z | y (a Y-up file is rotated (x, y, z) -> (x, -z, y))


@dataclass
class SceneConfig:
    """One scene, declared once in ``conf/scene/<name>.yaml`` (PROTOCOL.md 2; ``pipeline.scenes.loading`` builds
    it): where its mesh comes from, its boxes (``[[min x, y, z], [max x, y, z]]``), constants and view rigs."""

    name: str = MISSING
    kind: str = "object"  # object | room
    source: str = "mesh"  # mesh | proxy | procedural
    recipe: str | None = None  # proxy / procedural: the builder in pipeline.scenes.procedural
    paper_scene: str | None = None  # the paper scene it is or stands in for (tables set the paper's numbers beside it)
    nerf_asset: bool = False  # one of the paper's eight NeRF-asset scenes: averaged into the object-scene mean
    rank: int = 100  # order in tables
    experiments: list[str] = dataclasses.field(default_factory=list)  # the paper tables (conf/experiment) it joins
    files: list[AssetFile] = dataclasses.field(default_factory=list)
    fit_tight_box: bool = False  # scale the mesh uniformly into the tight box (Hubble)
    object_aabb: list[list[float]] = MISSING  # normalises the field, bounds the occupancy grid and labels
    camera_box: list[list[float]] = MISSING  # candidate positions and -OPT clipping
    tight_box: list[list[float]] = MISSING  # the ground-truth mesh's bounds
    density_threshold: float = 1e-4  # tau (M28)
    d0: float = 1.0  # M13's correlation length
    cr_threshold: float = 0.01  # C.R. distance (PROTOCOL 4.2)
    collision_free: bool = False  # M29's collision-free candidate sampler (Room)
    init_views: dict[str, Any] = dataclasses.field(default_factory=dict)  # a rig of pipeline.scenes.views
    eval_views: dict[str, Any] = dataclasses.field(default_factory=dict)


@dataclass
class AblationConfig:
    """One NVF ablation (``conf/ablation/<name>.yaml``): the score switches it sets, its table label and order."""

    name: str = "none"
    label: str = "NVF"
    rank: int = 100
    of: str = "nvf"  # the method it ablates


@dataclass
class BudgetConfig:
    """What a budget scales besides training, planning and field sizes (docs/BUDGETS.md)."""

    name: str = "paper"
    image_size: int = 512  # ground truth and training images (square, 90 degree FoV)
    eval_size: int = 512  # evaluation renders of the 20 evaluation views
    horizon: int = 20  # active-mapping steps
    gt_points: int = 500_000  # area-uniform samples of the GT mesh (PROTOCOL 4.2)
    recon_points: int = 500_000  # reconstructed points from training-view rays
    recon_batch: int = 16_384  # pixels drawn per point-cloud batch
    gt_samples: int = 1  # each ground-truth pixel (training, evaluation) the mean of k x k sub-pixel samples


@dataclass
class MetricsConfig:
    ssim_data_range: float | None = None  # None: inferred from the image stacks (PROTOCOL 4.1); or 1.0


@dataclass
class DiagnosticsConfig:
    """Extra measurements recorded in each step's row; they never change a run's views or metrics, so they
    are not settings (records made with and without them are the same run)."""

    rank_against: str | None = None  # an ablation (conf/ablation) whose score ranks the same candidates too


@dataclass
class NvfConfig:
    entropy: EntropyConfig = dataclasses.field(default_factory=EntropyConfig)


@dataclass
class RunConfig:
    """One run = (scene, method, planner, ablation, budget, seed)."""

    paths: PathsConfig = dataclasses.field(default_factory=PathsConfig)
    scene: SceneConfig = dataclasses.field(default_factory=SceneConfig)
    # the method's yaml node (a mapping): pipeline.config.typed_run.Run holds the nvf.methods.Method built from it
    method: Any = dataclasses.field(default_factory=dict)
    ablation: AblationConfig = dataclasses.field(default_factory=AblationConfig)
    planner: PlannerConfig = dataclasses.field(default_factory=PlannerConfig)
    budget: BudgetConfig = dataclasses.field(default_factory=BudgetConfig)
    render: RenderConfig = dataclasses.field(default_factory=RenderConfig)
    field: FieldConfig = dataclasses.field(default_factory=FieldConfig)
    sampler: SamplerConfig = dataclasses.field(default_factory=SamplerConfig)
    train: TrainConfig = dataclasses.field(default_factory=TrainConfig)
    nvf: NvfConfig = dataclasses.field(default_factory=NvfConfig)
    metrics: MetricsConfig = dataclasses.field(default_factory=MetricsConfig)
    diagnostics: DiagnosticsConfig = dataclasses.field(default_factory=DiagnosticsConfig)
    seed: int = 100
    device: str = "auto"  # auto | cpu | cuda | cuda:N
    save_images: bool = True
    step_metrics: StepMetrics = StepMetrics.all


def register_configs() -> None:
    """Register the schema under the name ``run_schema`` (first entry of conf/config.yaml's defaults) and the
    experiments' resolver (``pipeline.config.catalog.register_resolvers``)."""
    ConfigStore.instance().store(name="run_schema", node=RunConfig)
    register_resolvers()
