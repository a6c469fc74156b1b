"""The view-scorer protocol (METHOD.md sections 8 and 12).

A scorer turns one rendered ray batch into a per-ray (per-pixel) score; the view reward is the
mean over the planning image (M16), computed by the planner. Each method's scorer is built by its
class in ``nvf.methods``; Random has none.
"""

from typing import Protocol, runtime_checkable

from jaxtyping import Float, Int
from torch import Tensor

from nvf.model import RenderResult


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

    def pixel_scores(
        self, result: RenderResult, pixel_index: Int[Tensor, " R"] | None = None
    ) -> Float[Tensor, " R"]: ...
