"""The typed, resolved settings of one run: the nvf dataclasses built from the Hydra config, with the
scene's defaults filled in (NVF's d0, the density threshold, the collision-free sampler)."""

import dataclasses
from dataclasses import dataclass

import torch
from omegaconf import DictConfig, OmegaConf

from nvf.config import BaselineConfig, EntropyConfig, FieldConfig, PlannerConfig, SamplerConfig, TrainConfig
from nvf.methods import Method
from nvf.uncertainty import StepScorer, ViewScorer
from pipeline.config.schema import BudgetConfig, MetricsConfig
from pipeline.config.validation import ConfigError
from pipeline.scenes.scene import Scene


def typed(cfg: DictConfig, cls: type):
    """A plain dataclass instance of ``cls`` from a config node (nvf/ never sees OmegaConf)."""
    return OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(cls), cfg))


def resolved_d0(d0: float | int | str | None, scene: Scene) -> float:
    """(M13) NVF's correlation length: None = the scene's value (1.0, Room 6.0; D4), ``"auto"`` = 0.25 x
    the diagonal of the scene's object box (METHOD 8), a number as given (0 = Ind. Rays)."""
    if d0 is None:
        return float(scene.d0)
    if d0 == "auto":
        return 0.25 * float(torch.linalg.norm(scene.object_aabb[1] - scene.object_aabb[0]))
    return float(d0)


@dataclass
class EpisodeSettings:
    """The resolved, typed settings of one run, with scene defaults filled in."""

    field: FieldConfig
    sampler: SamplerConfig
    train: TrainConfig
    entropy: EntropyConfig
    baseline: BaselineConfig
    planner: PlannerConfig
    budget: BudgetConfig
    metrics: MetricsConfig
    seed: int
    tau: float
    collision_free: bool

    def scorer(self, method: Method) -> ViewScorer | StepScorer | None:
        """``method``'s view scorer with these settings (NVF's resolved ``d0``); None for a method without one
        (Random). ``ConfigError`` for ``planner=opt`` with a scorer of whole views (FisherRF, METHOD 17)."""
        scorer = method.scorer(self.entropy, self.baseline, float(self.entropy.d0))
        if self.planner.name == "opt" and scorer is not None and not isinstance(scorer, ViewScorer):
            raise ConfigError(
                f"planner=opt: {scorer.name} scores whole views, without the per-pixel score -OPT refines "
                "(docs/METHOD.md 17); use planner=argmax"
            )
        return scorer

    @staticmethod
    def of(cfg: DictConfig, scene: Scene) -> "EpisodeSettings":
        entropy = typed(cfg.nvf.entropy, EntropyConfig)
        entropy = dataclasses.replace(entropy, d0=resolved_d0(entropy.d0, scene))
        planner = typed(cfg.planner, PlannerConfig)
        tau = planner.density_threshold if planner.density_threshold is not None else scene.density_threshold
        collision_free = planner.collision_free if planner.collision_free is not None else scene.collision_free
        return EpisodeSettings(
            field=typed(cfg.field, FieldConfig),
            sampler=typed(cfg.sampler, SamplerConfig),
            train=typed(cfg.train, TrainConfig),
            entropy=entropy,
            baseline=typed(cfg.baseline, BaselineConfig),
            planner=planner,
            budget=typed(cfg.budget, BudgetConfig),
            metrics=typed(cfg.metrics, MetricsConfig),
            seed=int(cfg.seed),
            tau=float(tau),
            collision_free=bool(collision_free),
        )
