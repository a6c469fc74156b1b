"""Structured Hydra schema of one run (``RunConfig``), registered as ``run_schema``.

It embeds the method library's own dataclasses (``nvf.config``), so every value has one home, and
imports nothing heavier than them: tables can compose configs without loading torch.
"""

import dataclasses
from dataclasses import dataclass

from hydra.core.config_store import ConfigStore
from omegaconf import MISSING

from nvf.config import (
    STAGES,
    BaselineConfig,
    EntropyConfig,
    FieldConfig,
    PlannerConfig,
    SamplerConfig,
    TrainConfig,
)


@dataclass
class PathsConfig:
    assets: str = MISSING
    outputs: str = "outputs"
    results: str = "results"
    blender_python: str = ".venv-blender/bin/python"  # Blender's Python (bpy); relative to the repository root


@dataclass
class RenderConfig:
    """Which ground-truth backend renders the RGB (PROTOCOL 1): ``pyrender`` (flat, unlit, ``budget.gt_samples``
    squared samples per pixel) or ``blender`` (Cycles, ``samples`` samples per pixel, lit; pipeline.scenes.blender).
    Depth, hit mask and face ids come from the same ray cast with either."""

    backend: str = "pyrender"
    samples: int = 64  # Cycles samples per pixel (blender only)


@dataclass
class SceneConfig:
    name: str = "default"


@dataclass
class MethodConfig:
    name: str = "nvf"
    stages: list[str] = dataclasses.field(default_factory=lambda: list(STAGES))
    aux_loss: str = "none"


@dataclass
class AblationConfig:
    name: str = "none"


@dataclass
class BudgetConfig:
    """What a budget scales besides training, planning and field sizes (DESIGN.md, budgets)."""

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
class NvfConfig:
    entropy: EntropyConfig = dataclasses.field(default_factory=EntropyConfig)


@dataclass
class RunConfig:
    """One run = (scene, method, planner, ablation, budget, seed)."""

    paths: PathsConfig = dataclasses.field(default_factory=PathsConfig)
    scene: SceneConfig = dataclasses.field(default_factory=SceneConfig)
    method: MethodConfig = dataclasses.field(default_factory=MethodConfig)
    ablation: AblationConfig = dataclasses.field(default_factory=AblationConfig)
    planner: PlannerConfig = dataclasses.field(default_factory=PlannerConfig)
    budget: BudgetConfig = dataclasses.field(default_factory=BudgetConfig)
    render: RenderConfig = dataclasses.field(default_factory=RenderConfig)
    field: FieldConfig = dataclasses.field(default_factory=FieldConfig)
    sampler: SamplerConfig = dataclasses.field(default_factory=SamplerConfig)
    train: TrainConfig = dataclasses.field(default_factory=TrainConfig)
    nvf: NvfConfig = dataclasses.field(default_factory=NvfConfig)
    baseline: BaselineConfig = dataclasses.field(default_factory=BaselineConfig)
    metrics: MetricsConfig = dataclasses.field(default_factory=MetricsConfig)
    seed: int = 100
    device: str = "auto"  # auto | cpu | cuda | cuda:N
    save_images: bool = True


def register_configs() -> None:
    """Register the schema under the name ``run_schema`` (first entry of conf/config.yaml's defaults)."""
    ConfigStore.instance().store(name="run_schema", node=RunConfig)
