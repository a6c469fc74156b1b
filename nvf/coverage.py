"""Farthest view sampling (FVS; NeRF Director, Xiao et al., CVPR 2024; not in the NVF paper): a training-free
choice that spreads the views apart, the next view the candidate farthest from every view observed so far
(METHOD.md 18, M33).

A pose's view is its camera centre ``c`` and viewing direction ``f`` (the camera's ``-z`` axis, OpenGL). The
distance between two views (M33) is the great-circle distance between their centres seen from the object's
centre ``o`` (the angle between ``c_v - o`` and ``c_s - o``: NeRF Director's distance for object scenes, whose
cameras look at the object) plus the angle between their viewing directions (candidates here have any
orientation, so a pose at an observed place but looking elsewhere is a different view). A candidate scores
``min_s d(v, s)`` over the observed views ``s``; the planner takes the argmax.

With ``facing`` (M33's facing variant, ``method=fvs_facing``) the candidates whose optical axis misses the object's
box rank below every candidate whose axis meets it (their score less ``BEHIND``), so FVS picks among the views
that look at the object, as NeRF Director's candidates all do, whenever the draw holds one.
"""

import math
from dataclasses import dataclass
from typing import ClassVar

import torch
from jaxtyping import Float
from torch import Tensor, nn

from nvf.observations import Observations
from nvf.occupancy import ray_aabb
from nvf.seeding import GeneratorFactory

BEHIND = 4.0 * math.pi  # what a candidate that does not face the object loses: more than any distance (2 pi)


def _angle(a: Float[Tensor, "*B 3"], b: Float[Tensor, "*B 3"]) -> Float[Tensor, "*B"]:
    """The angle between vectors, in radians (``atan2`` of the cross and dot products: exact near 0 and pi)."""
    return torch.atan2(torch.linalg.cross(a, b).norm(dim=-1), (a * b).sum(-1))


def faces(centre: Float[Tensor, "3"], forward: Float[Tensor, "3"], box: Float[Tensor, "2 3"]) -> bool:
    """Whether the optical axis ``centre + t forward``, ``t >= 0``, meets ``box``: it leaves the box ahead of the
    camera and no earlier than it enters."""
    t_in, t_out = ray_aabb(centre[None], forward[None], box[0], box[1])
    return bool(t_out[0] >= t_in[0].clamp(min=0.0))


def view_distance(
    centre: Float[Tensor, "3"],
    forward: Float[Tensor, "3"],
    centres: Float[Tensor, "M 3"],
    forwards: Float[Tensor, "M 3"],
    pivot: Float[Tensor, "3"],
) -> Float[Tensor, " M"]:
    """(M33) ``d(v, s) = angle(c_v - o, c_s - o) + angle(f_v, f_s)`` of the view ``(centre, forward)`` to each of
    ``M`` views, ``o = pivot``; in ``[0, 2 pi]`` radians."""
    return _angle((centre - pivot).expand_as(centres), centres - pivot) + _angle(forward.expand_as(forwards), forwards)


@dataclass(frozen=True)
class FarthestViewScorer:
    """FVS's scorer: ``prepare`` reads the observed views' centres and directions (``Observations.c2w``) and the
    object's centre (the model's AABB) and returns the step's ``FarthestViews``; it reads no field. ``facing``:
    the candidates that do not look at the object's box rank last (M33's facing variant)."""

    facing: bool = False
    name: ClassVar[str] = "fvs"

    def prepare(
        self, model: nn.Module, observations: Observations, generators: GeneratorFactory, chunk_rays: int
    ) -> "FarthestViews":
        c2w = observations.c2w.to(torch.float64)
        box = model.aabb
        assert isinstance(box, Tensor), "a SceneModel's aabb buffer"
        aabb = box.to(torch.float64)
        return FarthestViews(c2w[:, :3, 3], -c2w[:, :3, 2], 0.5 * (aabb[0] + aabb[1]), aabb if self.facing else None)


@dataclass(frozen=True)
class FarthestViews:
    """One step's FVS scorer (a ``WholeViewScorer``): a view's score is its distance to the nearest observed
    view (M33). The view is read off its rays: the centre is their origin, the direction their mean (the
    optical axis of a pinhole image centred on it). With ``box`` a view whose axis misses it scores ``BEHIND``
    less."""

    centres: Float[Tensor, "M 3"]
    forwards: Float[Tensor, "M 3"]
    pivot: Float[Tensor, "3"]
    box: Float[Tensor, "2 3"] | None = None
    name: ClassVar[str] = "fvs"

    def view_score(
        self, model: nn.Module, origins: Float[Tensor, "R 3"], dirs: Float[Tensor, "R 3"], chunk_rays: int
    ) -> Float[Tensor, ""]:
        centre = origins[0].to(torch.float64)
        forward = torch.nn.functional.normalize(dirs.to(torch.float64).mean(0), dim=0)
        distance = view_distance(centre, forward, self.centres, self.forwards, self.pivot).min()
        return distance if self.box is None or faces(centre, forward, self.box) else distance - BEHIND
