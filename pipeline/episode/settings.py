"""The typed, resolved settings of one run: built once from the typed run config (``pipeline.config.typed_run.Run``)
and the scene, and the only settings the episode and everything under it read (the scene's defaults filled
in: the density threshold and the collision-free sampler)."""

from dataclasses import dataclass
from pathlib import Path

from nvf.config import EntropyConfig, FieldConfig, PlannerConfig, SamplerConfig, TrainConfig
from nvf.methods import Method
from nvf.training import stages_to_train
from nvf.uncertainty import StepScorer, ViewScorer
from pipeline.config.structured_configs import BudgetConfig, MetricsConfig, RenderConfig, StepMetrics
from pipeline.config.typed_run import Run
from pipeline.scenes.blender import blender_python
from pipeline.scenes.scene import Scene


@dataclass
class EpisodeSettings:
    """The resolved, typed settings of one run, with scene defaults filled in. ``entropy``: the run's
    ``nvf.entropy`` (``d0`` resolved), which the variance head's loss (M21), the stages to train and the
    planning model's visibility source read; NVF's score reads its own copy (``NVF.entropy``). ``rival``: the
    ``diagnostics.rank_against`` ablation's name and the method under its settings, or None."""

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
    rival: tuple[str, Method] | None

    @property
    def stages(self) -> tuple[str, ...]:
        """The training stages a step runs, in order (``nvf.training.stages_to_train``)."""
        return stages_to_train(self.method.stages, self.train, self.entropy)

    def scorer(self) -> ViewScorer | StepScorer | None:
        """The method's view scorer (a ``StepScorer`` for a method that scores whole views, FisherRF); None for
        a method without one (Random)."""
        return self.method.scorer()

    @staticmethod
    def of(run: Run, scene: Scene) -> "EpisodeSettings":
        """The settings of the typed run ``run`` on ``scene``."""
        planner = run.planner
        tau = planner.density_threshold if planner.density_threshold is not None else scene.density_threshold
        collision_free = planner.collision_free if planner.collision_free is not None else scene.collision_free
        return EpisodeSettings(
            method=run.method,
            field=run.field,
            sampler=run.sampler,
            train=run.train,
            entropy=run.nvf.entropy,
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
            rival=run.rival,
        )
