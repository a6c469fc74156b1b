"""Per-ray scores of the baselines (METHOD.md section 12, M22-M24, M26).

All read the ordinary render outputs (M1, M2); a ray without samples scores 0.
"""

from dataclasses import dataclass
from typing import ClassVar

import torch
from jaxtyping import Float, Int
from torch import Tensor

from nvf.model import RenderResult
from nvf.rendering import ray_sum

LOG_FLOOR = 1e-6  # M22-M24
VAR_SCORE_FLOOR = 1e-9  # M26


def binary_entropy(a: Float[Tensor, " S"]) -> Float[Tensor, " S"]:
    """(M23) ``h(a) = -a ln(a + 1e-6) - (1 - a) ln(1 - a + 1e-6)``."""
    return -a * torch.log(a + LOG_FLOOR) - (1.0 - a) * torch.log(1.0 - a + LOG_FLOOR)


@dataclass(frozen=True)
class WDScorer:
    """(M22) Weight-distribution entropy ``-sum_i w_i ln max(w_i, 1e-6) - w_bg ln max(w_bg, 1e-6)``."""

    name: ClassVar[str] = "wd"
    heads: ClassVar[frozenset[str]] = frozenset()
    sampler: ClassVar[str] = "occupancy"

    def pixel_scores(self, result: RenderResult, pixel_index: Int[Tensor, " R"] | None = None) -> Float[Tensor, " R"]:
        w, samples = result.weights, result.samples
        background = 1.0 - ray_sum(w, samples.ray_idx, samples.n_rays)
        inner = ray_sum(-w * torch.log(w.clamp(min=LOG_FLOOR)), samples.ray_idx, samples.n_rays)
        return inner - background * torch.log(background.clamp(min=LOG_FLOOR))


@dataclass(frozen=True)
class ActiveRMAPScorer:
    """(M23) ``sum_i h(alpha_i)``, or ``sum_i T_i h(alpha_i)`` when ``occlusion_weighted``."""

    occlusion_weighted: bool = False
    name: ClassVar[str] = "activermap"
    heads: ClassVar[frozenset[str]] = frozenset()
    sampler: ClassVar[str] = "occupancy"

    def pixel_scores(self, result: RenderResult, pixel_index: Int[Tensor, " R"] | None = None) -> Float[Tensor, " R"]:
        per_sample = binary_entropy(result.alpha)
        if self.occlusion_weighted:
            per_sample = result.trans * per_sample
        return ray_sum(per_sample, result.samples.ray_idx, result.samples.n_rays)


@dataclass(frozen=True)
class AIRScorer:
    """(M24) ``(1/N_r) sum_i T+_i h(alpha_i)`` with inclusive ``T+_i = T_i (1 - alpha_i)``;
    ``reduce="sum"`` drops the ``1/N_r``. AIR's top-K view score is not implemented."""

    reduce: str = "mean"
    name: ClassVar[str] = "air"
    heads: ClassVar[frozenset[str]] = frozenset()
    sampler: ClassVar[str] = "occupancy"

    def __post_init__(self) -> None:
        if self.reduce not in ("mean", "sum"):
            raise ValueError(f"baseline.air_reduce={self.reduce!r} not in ('mean', 'sum')")

    def pixel_scores(self, result: RenderResult, pixel_index: Int[Tensor, " R"] | None = None) -> Float[Tensor, " R"]:
        samples = result.samples
        per_sample = result.trans * (1.0 - result.alpha) * binary_entropy(result.alpha)
        total = ray_sum(per_sample, samples.ray_idx, samples.n_rays)
        if self.reduce == "sum":
            return total
        count = torch.bincount(samples.ray_idx, minlength=samples.n_rays).clamp(min=1)
        return total / count


@dataclass(frozen=True)
class RenderedVarianceScorer:
    """(M26) ActiveNeRF / NeurAR: ``sum_i max(w_i mean_ch q_i,ch, 1e-9)``."""

    name: str = "activenerf"  # activenerf | neurar (same score, different training loss)
    heads: ClassVar[frozenset[str]] = frozenset({"variance"})
    sampler: ClassVar[str] = "occupancy"

    def pixel_scores(self, result: RenderResult, pixel_index: Int[Tensor, " R"] | None = None) -> Float[Tensor, " R"]:
        assert result.variance is not None, "rendered with the variance head (heads)"
        per_sample = (result.weights * result.variance.mean(-1)).clamp(min=VAR_SCORE_FLOOR)
        return ray_sum(per_sample, result.samples.ray_idx, result.samples.n_rays)
