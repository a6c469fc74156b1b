"""COVER (CVPR 2026; not in the NVF paper) on NVF's backbone: a candidate is worth as much as the geometry it sees
from directions the training views have not covered (METHOD.md section 20, M37-M39).

Each surface element keeps, per direction bin on a Fibonacci sphere, whether some training camera has seen it
from that direction (COVER's per-Gaussian counts; only ``count > 0`` matters there). Here the elements are the
centres of the occupied cells of the backbone's occupancy grid (M5), the backbone's geometry, where COVER has
Gaussians. A candidate reads, per element, how close its own viewing direction comes to an observed bin (M38),
composites that along its rays with the backbone's rendering weights (M39, as COVER alpha-composites it) and
averages it over the pixels that see geometry: a low mean sees poorly covered geometry, so the planner takes the
argmax of one minus it.
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
    """COVER's scorer (a ``StepScorer``): ``prepare`` takes the elements (the occupied cells' centres) and their
    observed bins (M37) from the step's model and training views; ``bins``: the Fibonacci sphere's directions."""

    bins: int = 128
    name: ClassVar[str] = "cover"

    def prepare(
        self, model: nn.Module, observations: Observations, generators: GeneratorFactory, chunk_rays: int
    ) -> "CoveredViews":
        grid = model.grid
        assert isinstance(grid, OccupancyGrid), "a SceneModel's occupancy grid"
        cells = grid.occupied.nonzero().flatten()
        elements = grid.cell_centers()[cells]
        directions = fibonacci_sphere(self.bins).to(elements.device)
        seen = observed_bins(elements, observations.c2w.to(elements), observations.intrinsics, directions)
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
        """(M39) ``M(p) = sum_i w_i m(x_i)`` along pixel ``p``'s ray (M2's weights, ``m`` of the element whose cell
        holds the sample), ``S = mean M(p)`` over the pixels whose accumulated opacity is positive (1 when none
        is: nothing to cover), and the score ``1 - S`` (COVER takes the lowest ``S``). ``m`` is taken only for the
        elements the view's samples reach, not for every element."""
        grid = model.grid
        assert isinstance(grid, OccupancyGrid), "a SceneModel's occupancy grid"
        total = torch.zeros((), dtype=torch.float64, device=origins.device)
        pixels = 0
        for start in range(0, origins.shape[0], chunk_rays):
            o, d = origins[start : start + chunk_rays], dirs[start : start + chunk_rays]
            result = model.render(o, d, heads=RGB)  # type: ignore[operator]  # a duck-typed nn.Module's attribute
            rays = result.samples.ray_idx
            x = o[rays] + result.samples.t_mid[:, None] * d[rays]
            cell, inside = grid.cell_index(x)
            element = torch.where(inside, self.element_of[cell], -1)
            hit = element >= 0
            wanted, which = torch.unique(element[hit], return_inverse=True)  # M38 for the elements this chunk hits
            m = torch.zeros_like(result.weights)
            m[hit] = element_coverage(self.elements[wanted], self.seen[wanted], self.directions, origins[0])[which]
            composite = torch.zeros(o.shape[0], dtype=torch.float64, device=o.device)
            composite.index_add_(0, rays, (result.weights * m).to(torch.float64))
            sees = result.acc > 0
            total += composite[sees].sum()
            pixels += int(sees.sum())
        mean = total / pixels if pixels else torch.ones((), dtype=torch.float64, device=origins.device)
        return 1.0 - mean
