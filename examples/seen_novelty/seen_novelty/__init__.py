"""SeenNovelty: an example of a method that scores whole views, living outside the repository's packages.

A candidate view is worth how much of the object it sees (the mean over its pixels of the model's accumulated
opacity ``A``, M2) times how far its direction is from every observed view's (the angle, in radians, between its
optical axis and the nearest observed camera's). Views that see a lot of the object from a new direction win.

It shows what a whole-view method receives (``nvf.uncertainty.scorers.StepScorer``): ``prepare`` gets the step's
trained model (``nvf.model.SceneModel``), the observations (``nvf.training.Observations``: ``images`` ``[V, H, W,
4]``, ``c2w`` ``[V, 4, 4]`` camera-to-world poses in OpenGL axes, ``intrinsics``), a factory of the step's seeded
generators and the planner's ray chunk, once per planning step; the scorer it returns then gets each candidate's
rays (``origins``, ``dirs``: ``[R, 3]``, unit directions, the planning image's pixels row-major) and returns one
float64 score. The planner takes the argmax; -OPT does not apply to whole-view scores.
"""

from dataclasses import dataclass
from typing import ClassVar

import torch
from jaxtyping import Float
from torch import Tensor, nn

from nvf.methods import Method
from nvf.observations import Observations
from nvf.seeding import GeneratorFactory

RGB = frozenset({"rgb"})


@dataclass(frozen=True)
class SeenNoveltyScorer:
    """The step scorer: ``prepare`` reads the observed cameras' viewing directions (the ``-z`` axis of each pose)."""

    name: ClassVar[str] = "seen_novelty"

    def prepare(
        self, model: nn.Module, observations: Observations, generators: GeneratorFactory, chunk_rays: int
    ) -> "SeenNoveltyViews":
        return SeenNoveltyViews(-observations.c2w[:, :3, 2].to(torch.float64))


@dataclass(frozen=True)
class SeenNoveltyViews:
    """One step's whole-view scorer: the observed viewing directions ``[V, 3]``."""

    observed: Float[Tensor, "V 3"]
    name: ClassVar[str] = "seen_novelty"

    @torch.no_grad()
    def view_score(
        self, model: nn.Module, origins: Float[Tensor, "R 3"], dirs: Float[Tensor, "R 3"], chunk_rays: int
    ) -> Float[Tensor, ""]:
        """``mean_p A(p) x min_v angle(f, f_v)``: ``f`` the view's optical axis (its rays' mean direction)."""
        chunks = range(0, len(dirs), chunk_rays)
        seen = torch.cat(
            [model.render(origins[s : s + chunk_rays], dirs[s : s + chunk_rays], heads=RGB).acc for s in chunks]
        )
        seen = seen.to(torch.float64)
        axis = nn.functional.normalize(dirs.to(torch.float64).mean(0), dim=0)
        angle = torch.arccos((self.observed.to(axis) @ axis).clamp(-1.0, 1.0)).min()
        return seen.mean() * angle


@dataclass(frozen=True, kw_only=True)
class SeenNovelty(Method):
    """The method: its whole-view scorer, no setting of its own."""

    score_unit: ClassVar[str] = "radians x opacity"

    def scorer(self) -> SeenNoveltyScorer:
        return SeenNoveltyScorer()
