"""DepthSpread: an example next-best-view method that lives outside the repository's packages.

A view scores the mean over its pixels (M16) of each ray's depth spread: the variance of the ray's
termination depth under its rendering weights (M2), plus ``background_weight`` times the share of the ray
that reaches the background. Views where the model is unsure *where* the surface is, or that look into
space it has not filled, win. It needs no head beyond the backbone, so it trains stage 1 alone.

Everything a method needs is here: a frozen ``nvf.methods.Method`` subclass whose fields are its yaml's keys
(``conf/method/depth_spread.yaml``; ``label``, ``rank`` and ``experiments`` there are how results show it, read by
the harness), with one setting of its own, and a scorer that follows ``nvf.uncertainty.scorers.ViewScorer``.
"""

from dataclasses import dataclass
from typing import ClassVar

import torch
from jaxtyping import Float, Int
from torch import Tensor

from nvf.methods import Method
from nvf.model import RenderResult
from nvf.rendering import ray_sum

EPS = 1e-6  # the accumulated weight below which a ray's depth spread is taken as zero


@dataclass(frozen=True)
class DepthSpreadScorer:
    """Per ray: ``sum_i w_i (t_i - d)^2 / max(A, eps) + background_weight (1 - A)``, with ``t_i`` the samples'
    midpoints, ``A = sum_i w_i`` and ``d = sum_i w_i t_i / max(A, eps)`` (the expected depth given a hit).
    Rays without samples score ``background_weight``; differentiable in the weights (-OPT)."""

    background_weight: float
    name: ClassVar[str] = "depth_spread"
    heads: ClassVar[frozenset[str]] = frozenset()
    sampler: ClassVar[str] = "occupancy"

    def pixel_scores(self, result: RenderResult, pixel_index: Int[Tensor, " R"] | None = None) -> Float[Tensor, " R"]:
        samples, w = result.samples, result.weights
        t = samples.t_mid
        acc = ray_sum(w, samples.ray_idx, samples.n_rays)
        hit = acc.clamp(min=EPS)
        depth = ray_sum(w * t, samples.ray_idx, samples.n_rays) / hit
        spread = ray_sum(w * (t - depth[samples.ray_idx]) ** 2, samples.ray_idx, samples.n_rays) / hit
        return torch.where(acc > EPS, spread, torch.zeros_like(spread)) + self.background_weight * (1.0 - acc)


@dataclass(frozen=True, kw_only=True)
class DepthSpread(Method):
    """The method: its scorer, with its own setting ``background_weight`` (squared scene units per unit of
    background; 0 scores only the spread of what the ray hits)."""

    background_weight: float
    """A ray into the background scores as this much depth variance (0: only the spread of what it hits)."""

    score_unit: ClassVar[str] = "squared depth"

    def scorer(self) -> DepthSpreadScorer:
        return DepthSpreadScorer(self.background_weight)

    def unsupported(self) -> str | None:
        if self.background_weight < 0:
            return f"background_weight={self.background_weight} must be >= 0"
        return None
