"""The view-scorer protocol and the method registry (METHOD.md sections 8 and 12).

A scorer turns one rendered ray batch into a per-ray (per-pixel) score; the view reward is the
mean over the planning image (M16), computed by the planner. Random has no scorer.
"""

from typing import Protocol, runtime_checkable

from jaxtyping import Float, Int
from torch import Tensor

from nvf.config import BaselineConfig, EntropyConfig
from nvf.model import RenderResult
from nvf.uncertainty.baselines import ActiveRMAPScorer, AIRScorer, RenderedVarianceScorer, WDScorer
from nvf.uncertainty.nvf_entropy import NVFEntropyScorer

METHODS = ("random", "wd", "activermap", "air", "activenerf", "neurar", "nvf")


@runtime_checkable
class ViewScorer(Protocol):
    """Per-ray score of a rendered batch (``nvf.model.RenderResult``).

    ``heads``: field heads the render must produce, a subset of {"rgb", "variance", "visibility"};
    ``sampler``: "occupancy" | "uniform"; ``pixel_index``: each ray's row-major pixel id in its
    image (only NVF's ``depth_mode=chunk`` needs it). Rays without samples score the method's
    floor; scores are differentiable in the per-sample render outputs (-OPT).
    """

    @property
    def name(self) -> str: ...

    @property
    def heads(self) -> frozenset[str]: ...

    @property
    def sampler(self) -> str: ...

    def pixel_scores(self, result: RenderResult, pixel_index: Int[Tensor, "R"] | None = None) -> Float[Tensor, "R"]: ...


def make_scorer(method: str, entropy: EntropyConfig, baseline: BaselineConfig, d0: float) -> ViewScorer | None:
    """The scorer of ``method`` (one of ``METHODS``); None for random. ``d0`` is NVF's resolved
    correlation length (M13; 0 = Ind. Rays), ignored by the baselines."""
    if method == "random":
        return None
    if method == "nvf":
        return NVFEntropyScorer(entropy, d0)
    if method == "wd":
        return WDScorer()
    if method == "activermap":
        return ActiveRMAPScorer(occlusion_weighted=baseline.rmap_occlusion_weighted)
    if method == "air":
        if baseline.air_view_score != "pixel_mean":
            raise NotImplementedError(f"AIR view score {baseline.air_view_score!r}: only pixel_mean is implemented")
        return AIRScorer(reduce=baseline.air_reduce)
    if method in ("activenerf", "neurar"):
        if method == "activenerf" and baseline.activenerf_variant != "A":
            raise NotImplementedError(
                f"ActiveNeRF variant {baseline.activenerf_variant!r}: only A (the NVF variance head, M26) is implemented"
            )
        return RenderedVarianceScorer(name=method)
    raise ValueError(f"unknown method {method!r} (one of {', '.join(METHODS)})")
