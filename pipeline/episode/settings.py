"""The typed, resolved settings of one run: built once from the composed Hydra config, and the only settings
the episode and everything under it read. The method is built from its yaml (``pipeline.config.method``),
and the scene's defaults are filled in (NVF's d0, the density threshold, the collision-free sampler)."""

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import torch
from omegaconf import DictConfig, OmegaConf

from nvf.config import EntropyConfig, FieldConfig, PlannerConfig, SamplerConfig, TrainConfig
from nvf.methods import Method
from nvf.training import stages_to_train
from nvf.uncertainty import StepScorer, ViewScorer
from pipeline.config.method import build_method
from pipeline.config.schema import BudgetConfig, MetricsConfig, RenderConfig, RunConfig, StepMetrics
from pipeline.repo import CONF
from pipeline.scenes.blender import blender_python
from pipeline.scenes.scene import Scene


def resolved_d0(d0: float | int | str | None, scene: Scene) -> float:
    """(M13) NVF's correlation length: None = the scene's value (1.0, Room 6.0; D4), ``"auto"`` = 0.25 x
    the diagonal of the scene's object box (METHOD 8), a number as given (0 = Ind. Rays)."""
    if d0 is None:
        return float(scene.d0)
    if d0 == "auto":
        return 0.25 * float(torch.linalg.norm(scene.object_aabb[1] - scene.object_aabb[0]))
    return float(d0)


def entropy_d0(entropy: EntropyConfig) -> float:
    """The correlation length of entropy settings whose ``d0`` is resolved (``resolved_d0``), as a float."""
    assert isinstance(entropy.d0, (int, float)), f"entropy.d0={entropy.d0!r} is not resolved"
    return float(entropy.d0)


def run_config(cfg: DictConfig) -> RunConfig:
    """The composed config as the schema's typed objects (interpolations resolved)."""
    run = OmegaConf.to_object(cfg)
    assert isinstance(run, RunConfig), f"a composed run config, not {type(run).__name__}"
    return run


@dataclass
class EpisodeSettings:
    """The resolved, typed settings of one run, with scene defaults filled in (``entropy.d0`` resolved).
    ``rival``: the ``diagnostics.rank_against`` ablation's name and entropy settings, or None."""

    method: Method
    field: FieldConfig
    sampler: SamplerConfig
    train: TrainConfig
    entropy: EntropyConfig
    planner: PlannerConfig
    budget: BudgetConfig
    metrics: MetricsConfig
    render: RenderConfig
    blender_python: Path
    seed: int
    step_metrics: StepMetrics
    save_images: bool
    tau: float
    collision_free: bool
    rival: tuple[str, EntropyConfig] | None

    @property
    def stages(self) -> tuple[str, ...]:
        """The training stages a step runs, in order (``nvf.training.stages_to_train``)."""
        return stages_to_train(self.method.stages, self.train, self.entropy)

    def scorer(self, entropy: EntropyConfig | None = None) -> ViewScorer | StepScorer | None:
        """The method's view scorer with these settings' (or ``entropy``'s) NVF entropy settings (a
        ``StepScorer`` for a method that scores whole views, FisherRF); None for a method without one
        (Random)."""
        entropy = self.entropy if entropy is None else entropy
        return self.method.scorer(entropy, entropy_d0(entropy))

    @staticmethod
    def of(cfg: DictConfig, scene: Scene) -> "EpisodeSettings":
        """The settings of the composed config ``cfg`` (validated) on ``scene``."""
        run = run_config(cfg)
        entropy = dataclasses.replace(run.nvf.entropy, d0=resolved_d0(run.nvf.entropy.d0, scene))
        rival = None
        if run.diagnostics.rank_against is not None:
            name = run.diagnostics.rank_against
            merged = OmegaConf.merge(cfg, OmegaConf.load(CONF / "ablation" / f"{name}.yaml"))
            assert isinstance(merged, DictConfig), "a run config merged with an ablation's mapping"
            ablated = run_config(merged)
            rival = name, dataclasses.replace(ablated.nvf.entropy, d0=resolved_d0(ablated.nvf.entropy.d0, scene))
        planner = run.planner
        tau = planner.density_threshold if planner.density_threshold is not None else scene.density_threshold
        collision_free = planner.collision_free if planner.collision_free is not None else scene.collision_free
        return EpisodeSettings(
            method=build_method(run.method),
            field=run.field,
            sampler=run.sampler,
            train=run.train,
            entropy=entropy,
            planner=planner,
            budget=run.budget,
            metrics=run.metrics,
            render=run.render,
            blender_python=blender_python(run.paths.blender_python),
            seed=int(run.seed),
            step_metrics=run.step_metrics,
            save_images=run.save_images,
            tau=float(tau),
            collision_free=bool(collision_free),
            rival=rival,
        )
