"""The view-scorer protocols (METHOD.md sections 8, 12 and 17).

A ``ViewScorer`` turns one rendered ray batch into a per-ray (per-pixel) score; the view reward is the
mean over the planning image (M16), computed by the planner. A ``StepScorer`` (FisherRF) first reads the
step's trained model and training views (``prepare``), then scores whole views by the model's
parameters (``WholeViewScorer``), without a per-pixel score. Each method's scorer is built by its class
in ``nvf.methods``; Random has none.
"""

from typing import Protocol, runtime_checkable

from jaxtyping import Float, Int
from torch import Tensor, nn

from nvf.model import RenderResult
from nvf.observations import Observations
from nvf.seeding import GeneratorFactory


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


@runtime_checkable
class WholeViewScorer(Protocol):
    """Score of one whole view from its rays (no per-pixel score, so no -OPT and no score map), bound to the
    model and training views it was prepared from (``StepScorer.prepare``).

    ``view_score``: the view's rays ``[R, 3]`` (row-major pixels), rendered with autograd in chunks of
    ``chunk_rays`` rays; the score is a float64 scalar that does not depend on the chunking.
    """

    @property
    def name(self) -> str: ...

    def view_score(
        self, model: nn.Module, origins: Float[Tensor, "R 3"], dirs: Float[Tensor, "R 3"], chunk_rays: int
    ) -> Float[Tensor, ""]: ...


@runtime_checkable
class StepScorer(Protocol):
    """A scorer that needs the step's trained model and training views before it scores a view:
    ``prepare`` (once per planning step, after training; random draws from ``generators``, PROTOCOL 3)
    returns the ``WholeViewScorer`` the planner uses for that step."""

    @property
    def name(self) -> str: ...

    def prepare(
        self, model: nn.Module, observations: Observations, generators: GeneratorFactory, chunk_rays: int
    ) -> WholeViewScorer: ...
