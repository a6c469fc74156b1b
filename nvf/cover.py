"""COVER (CVPR 2026; not in the NVF paper) on NVF's backbone: a candidate is worth as much as the geometry it sees
from directions the training views have not covered (METHOD.md section 20, M37-M39).

Each surface element keeps, per direction bin on a Fibonacci sphere, whether some training camera has seen it
from that direction (COVER's per-Gaussian counts; only ``count > 0`` matters there). Here the elements are the
centres of the occupied cells of the backbone's occupancy grid (M5) that some training view holds in its frustum,
the geometry the views put there, as COVER's Gaussians. A candidate reads, per element, how close its own viewing
direction comes to an observed bin (M38), composites that along its rays with the backbone's rendering weights
over the samples the 3DGS rasteriser would composite (M39, as COVER alpha-composites it), and scores the geometry
it sees that is poorly covered: the composited opacity less the composited coverage, over the image.
"""

import math
from dataclasses import dataclass
from typing import ClassVar

import torch
from jaxtyping import Bool, Float, Int
from torch import Tensor, nn

from nvf.cameras import Intrinsics, project
from nvf.observations import Observations
from nvf.occupancy import OccupancyGrid
from nvf.seeding import GeneratorFactory

RGB = frozenset({"rgb"})
NEAR = 0.01  # COVER's near plane for the frustum test (scene units)
ALPHA_FLOOR = 1.0 / 255.0  # a Gaussian's least opacity the 3DGS rasteriser composites at a pixel (M39)


def fibonacci_sphere(bins: int) -> Float[Tensor, "B 3"]:
    """``bins`` unit directions spread over the whole sphere (a Fibonacci lattice): ``z_b = 1 - 2 (b + 1/2) / B``,
    azimuth ``2 pi frac(b / phi)`` with ``phi`` the golden ratio."""
    b = torch.arange(bins, dtype=torch.float64)
    z = 1.0 - 2.0 * (b + 0.5) / bins
    r = torch.sqrt((1.0 - z * z).clamp(min=0.0))
    azimuth = 2.0 * math.pi * torch.frac(b / ((1.0 + math.sqrt(5.0)) / 2.0))
    return torch.stack([r * torch.cos(azimuth), r * torch.sin(azimuth), z], dim=-1).to(torch.float32)


def observed_bins(
    elements: Float[Tensor, "G 3"],
    c2w: Float[Tensor, "V 4 4"],
    intrinsics: Intrinsics,
    directions: Float[Tensor, "B 3"],
) -> Bool[Tensor, "G B"]:
    """(M37) Whether some camera of ``c2w`` saw each element from each bin: an element in a camera's frustum (in
    front of its near plane, projecting inside its image; COVER tests no occlusion) is seen from the bin nearest
    the direction from the camera's centre to it (the largest dot product)."""
    seen = torch.zeros(elements.shape[0], directions.shape[0], dtype=torch.bool, device=elements.device)
    for pose in c2w:
        uv, depth = project(elements, pose, intrinsics)
        inside = (depth > NEAR) & (uv[:, 0] >= 0) & (uv[:, 0] < intrinsics.width)
        inside &= (uv[:, 1] >= 0) & (uv[:, 1] < intrinsics.height)
        index = inside.nonzero().flatten()
        towards = nn.functional.normalize(elements[index] - pose[:3, 3], dim=-1)
        seen[index, (towards @ directions.T).argmax(dim=-1)] = True
    return seen


def element_coverage(
    elements: Float[Tensor, "G 3"],
    seen: Bool[Tensor, "G B"],
    directions: Float[Tensor, "B 3"],
    centre: Float[Tensor, "3"],
) -> Float[Tensor, " G"]:
    """(M38) ``m_g = max_b (1 + d_g . u_b) / 2`` over the bins ``b`` element ``g`` was seen from, ``d_g`` the
    direction from the candidate's centre to the element: 1 when the candidate looks along an observed bin, 0 from
    its opposite, and 0 for an element no training camera saw."""
    towards = nn.functional.normalize(elements - centre, dim=-1)
    closeness = 0.5 * (1.0 + towards @ directions.T)
    return torch.where(seen, closeness, torch.zeros_like(closeness)).amax(dim=-1)


@dataclass(frozen=True)
class CoverScorer:
    """COVER's scorer (a ``StepScorer``): ``prepare`` takes the elements (the centres of the occupied cells some
    training view holds in its frustum) and their observed bins (M37) from the step's model and training views;
    ``bins``: the Fibonacci sphere's directions."""

    bins: int = 128
    name: ClassVar[str] = "cover"

    def prepare(
        self, model: nn.Module, observations: Observations, generators: GeneratorFactory, chunk_rays: int
    ) -> "CoveredViews":
        grid = model.grid
        assert isinstance(grid, OccupancyGrid), "a SceneModel's occupancy grid"
        cells = grid.occupied.nonzero().flatten()
        centres = grid.cell_centers()[cells]
        directions = fibonacci_sphere(self.bins).to(centres.device)
        seen = observed_bins(centres, observations.c2w.to(centres), observations.intrinsics, directions)
        kept = seen.any(dim=-1)  # the geometry some training view holds in its frustum, as COVER's Gaussians
        cells, elements, seen = cells[kept], centres[kept], seen[kept]
        element_of = torch.full((grid.occupied.numel(),), -1, dtype=torch.long, device=elements.device)
        element_of[cells] = torch.arange(cells.numel(), device=elements.device)
        return CoveredViews(elements, seen, directions, element_of)


@dataclass(frozen=True)
class CoveredViews:
    """One step's COVER scorer (a ``WholeViewScorer``): the elements, their observed bins and each grid cell's
    element (-1 for an empty cell). A view scores ``1 - S`` (M39)."""

    elements: Float[Tensor, "G 3"]
    seen: Bool[Tensor, "G B"]
    directions: Float[Tensor, "B 3"]
    element_of: Int[Tensor, " C"]
    name: ClassVar[str] = "cover"

    @torch.no_grad()
    def view_score(
        self, model: nn.Module, origins: Float[Tensor, "R 3"], dirs: Float[Tensor, "R 3"], chunk_rays: int
    ) -> Float[Tensor, ""]:
        """(M39) The score ``mean_p (A(p) - M(p))`` over all ``R`` pixels (``opacity_and_coverage``): how much of
        what the view sees is seen from uncovered directions, 0 for a view that sees no element."""
        opacity, coverage = self.opacity_and_coverage(model, origins, dirs, chunk_rays)
        return (opacity - coverage).mean()

    @torch.no_grad()
    def opacity_and_coverage(
        self, model: nn.Module, origins: Float[Tensor, "R 3"], dirs: Float[Tensor, "R 3"], chunk_rays: int
    ) -> tuple[Float[Tensor, " R"], Float[Tensor, " R"]]:
        """(M39) Per pixel ``p``, ``A(p) = sum_i w_i`` and ``M(p) = sum_i w_i m(x_i)`` along its ray over its samples
        in an element's cell with opacity ``alpha_i >= 1/255`` (M2's weights, ``m`` of that element; float64).
        ``m`` is taken only for the elements the view's samples reach."""
        grid = model.grid
        assert isinstance(grid, OccupancyGrid), "a SceneModel's occupancy grid"
        opacity = torch.zeros(origins.shape[0], dtype=torch.float64, device=origins.device)
        coverage = torch.zeros_like(opacity)
        for start in range(0, origins.shape[0], chunk_rays):
            o, d = origins[start : start + chunk_rays], dirs[start : start + chunk_rays]
            result = model.render(o, d, heads=RGB)  # type: ignore[operator]  # a duck-typed nn.Module's attribute
            rays = result.samples.ray_idx
            x = o[rays] + result.samples.t_mid[:, None] * d[rays]
            cell, inside = grid.cell_index(x)
            element = torch.where(inside, self.element_of[cell], -1)
            hit = (element >= 0) & (result.alpha >= ALPHA_FLOOR)  # what the rasteriser would composite
            wanted, which = torch.unique(element[hit], return_inverse=True)  # M38 for the elements this chunk hits
            m = torch.zeros_like(result.weights)
            m[hit] = element_coverage(self.elements[wanted], self.seen[wanted], self.directions, origins[0])[which]
            weights = torch.where(hit, result.weights, torch.zeros_like(result.weights)).to(torch.float64)
            opacity.index_add_(0, rays + start, weights)
            coverage.index_add_(0, rays + start, weights * m.to(torch.float64))
        return opacity, coverage
