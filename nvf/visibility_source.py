"""Where NVF's scores read the visibility ``v`` of M7 and M9 from (``nvf.entropy.visibility_source``).

- ``head``: the visibility head (METHOD 3, trained by M19): what the method does.
- ``labels``: M17-M18 evaluated at the scored samples themselves, from the training cameras and the model's
  density (bin centres, no jitter): what a perfect head would predict. A diagnostic; it costs
  ``label_samples - 1`` density evaluations per sample and training camera.
- ``mesh``: whether some training camera has an unoccluded line of sight to the sample, from the scene
  mesh: privileged information, supplied by the caller (``nvf/`` knows no mesh) and marked in the tables.

``SourcedVisibility`` wraps a ``SceneModel`` so that planning and scoring code stays unchanged.
"""

import dataclasses
from collections.abc import Callable

import torch
from jaxtyping import Float, Int
from torch import Tensor, nn

from nvf.cameras import Intrinsics
from nvf.config import TrainConfig, VisibilitySource
from nvf.model import RenderResult, SceneModel
from nvf.visibility import visibility_labels

SOURCES = tuple(VisibilitySource)

# sample positions [S, 3] -> v [S] in [0, 1]
VisibilityFn = Callable[[Float[Tensor, "S 3"]], Float[Tensor, " S"]]


def label_visibility(
    model: SceneModel, c2w: Float[Tensor, "M 4 4"], intrinsics: Intrinsics, cfg: TrainConfig
) -> VisibilityFn:
    """``v(x) = V*(x)`` (M17-M18) from the cameras ``c2w`` through ``model.density``, as stage 3 labels
    its points (``cfg.label_samples``, ``label_max_depth``, ``label_margin``, ``label_cutoff``, ``label_lattice``:
    a lattice is built once, for a model that no longer changes), with bin-centre samples."""
    density = model.label_density(cfg.label_lattice)

    def visibility(points: Float[Tensor, "S 3"]) -> Float[Tensor, " S"]:
        support = model.density_support()
        return visibility_labels(density, points, c2w, intrinsics, cfg, aabb=support.box, grid=support.grid)

    return visibility


class SourcedVisibility(nn.Module):
    """A ``SceneModel`` whose renders take ``v`` from ``source(positions)`` instead of the visibility head.

    Everything else (density, filters, colours, variances) is the wrapped model's. ``v`` carries no
    gradient: -OPT refines poses through the other terms only.
    """

    def __init__(self, model: SceneModel, source: VisibilityFn):
        super().__init__()
        self.model = model
        self.source = source

    @property
    def aabb(self) -> Float[Tensor, "2 3"]:
        return self.model.aabb

    def density(self, x: Float[Tensor, "N 3"]) -> Float[Tensor, " N"]:
        return self.model.density(x)

    def observed_density(self, x: Float[Tensor, "N 3"]) -> Float[Tensor, " N"]:
        return self.model.observed_density(x)

    def render(
        self,
        origins: Float[Tensor, "R 3"],
        dirs: Float[Tensor, "R 3"],
        heads: frozenset[str] = frozenset({"rgb"}),
        train: bool = False,
        generator: torch.Generator | None = None,
        sampler: str = "occupancy",
        image_idx: Int[Tensor, " R"] | None = None,
    ) -> RenderResult:
        """``SceneModel.render``, with ``visibility`` from the source when it is asked for."""
        if "visibility" not in heads:
            return self.model.render(origins, dirs, heads, train, generator, sampler, image_idx)
        result = self.model.render(origins, dirs, heads - {"visibility"}, train, generator, sampler, image_idx)
        with torch.no_grad():
            positions = result.samples.positions(origins.detach(), dirs.detach())
            v = self.source(positions).to(result.alpha.dtype)
        return dataclasses.replace(result, visibility=v)
