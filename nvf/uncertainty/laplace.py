"""Bayes' Rays (Goli, Reading, Selllán, Jacobson and Tagliasacchi, CVPR 2024; not in the NVF paper): post-hoc
Laplace uncertainty of the trained backbone from a spatial perturbation field (METHOD.md 19, M34-M36).

A perturbation field ``D_theta`` on a grid of ``(n + 1)^3`` vertices over the object AABB (``n`` cells a side),
three components a vertex, read trilinearly, zero at the trained model: the field is evaluated at
``x + D_theta(x)``. Its posterior is a Gaussian (Laplace) whose precision is the diagonal Gauss-Newton Hessian
of the photometric loss over the training pixels (M34) plus an isotropic prior (M35); a point's uncertainty is
its interpolated deviation (M36), rendered along a ray like a colour. A view scores the mean of its rays'
rendered uncertainty (the paper uses the uncertainty for maps and clean-up, not for choosing views; the mean
over the view's pixels is this repository's choice, as M16 averages the other methods' per-pixel scores).
"""

from dataclasses import dataclass
from typing import ClassVar

import torch
from jaxtyping import Float, Int
from torch import Tensor, nn

from nvf.cameras import pixel_rays
from nvf.observations import Observations
from nvf.rendering import ray_sum
from nvf.seeding import GeneratorFactory

PRIOR_SCALE = 1e-4  # lambda_0 of M35 (the reference code's), divided by the grid's cells
U_MIN, U_MAX = -3.0, 6.0  # M36: a ray's log10 uncertainty is clipped to [U_MIN, U_MAX] (the reference's bounds)
LOG_EPS = 1e-12  # M36: log10(sqrt(variance) + LOG_EPS)


@dataclass(frozen=True)
class PerturbationGrid:
    """The perturbation field's vertex grid: ``cells`` a side over ``aabb`` (min, max)."""

    aabb: Float[Tensor, "2 3"]
    cells: int

    @property
    def vertices(self) -> int:
        return (self.cells + 1) ** 3

    def corners(self, x: Float[Tensor, "N 3"]) -> tuple[Int[Tensor, "N 8"], Float[Tensor, "N 8"]]:
        """The 8 vertices (flat, x-major) around each point and their trilinear weights (points clamped to the
        AABB)."""
        u = ((x - self.aabb[0]) / (self.aabb[1] - self.aabb[0])).clamp(0.0, 1.0) * self.cells
        cell = torch.minimum(u.floor(), torch.full_like(u, self.cells - 1.0))
        frac = u - cell
        cell = cell.long()
        side = self.cells + 1
        index, weight = [], []
        for a in (0, 1):
            for b in (0, 1):
                for c in (0, 1):
                    index.append(((cell[:, 0] + a) * side + cell[:, 1] + b) * side + cell[:, 2] + c)
                    wx = frac[:, 0] if a else 1.0 - frac[:, 0]
                    wy = frac[:, 1] if b else 1.0 - frac[:, 1]
                    wz = frac[:, 2] if c else 1.0 - frac[:, 2]
                    weight.append(wx * wy * wz)
        return torch.stack(index, dim=1), torch.stack(weight, dim=1)


class Displacement:
    """A render's perturbation (``SceneModel.render``'s ``displacement``): each sample's position plus a leaf
    offset of zeros, kept as ``offsets`` so that the colours' gradients with respect to it can be read."""

    def __init__(self) -> None:
        self.offsets: Tensor | None = None

    def __call__(self, positions: Float[Tensor, "S 3"]) -> Float[Tensor, "S 3"]:
        self.offsets = torch.zeros_like(positions, requires_grad=True)
        return positions + self.offsets


def ray_hessian(
    model: nn.Module, grid: PerturbationGrid, origins: Float[Tensor, "R 3"], dirs: Float[Tensor, "R 3"]
) -> Float[Tensor, " V"]:
    """(M34) ``H_v = sum_r sum_ch sum_k (dC_{r,ch} / d theta_{v,k})^2`` over these rays: each sample's colour
    gradient with respect to its own offset (one backward pass per channel), spread to its 8 vertices by their
    trilinear weights and summed per ray before it is squared."""
    displacement = Displacement()
    result = model.render(origins, dirs, displacement=displacement)  # type: ignore[operator]  # a SceneModel
    hessian = torch.zeros(grid.vertices, dtype=torch.float64, device=origins.device)
    offsets = displacement.offsets
    if offsets is None or offsets.shape[0] == 0:
        return hessian
    samples = result.samples
    index, weight = grid.corners(samples.positions(origins, dirs).detach())
    key = (samples.ray_idx[:, None] * grid.vertices + index).reshape(-1)
    keys, inverse = torch.unique(key, return_inverse=True)
    for channel in range(3):
        (grad,) = torch.autograd.grad(result.rgb[:, channel].sum(), offsets, retain_graph=channel < 2)
        spread = (weight[:, :, None] * grad[:, None, :]).reshape(-1, 3).to(torch.float64)
        per_ray = torch.zeros(keys.shape[0], 3, dtype=torch.float64, device=origins.device).index_add_(
            0, inverse, spread
        )
        hessian.index_add_(0, keys % grid.vertices, per_ray.square().sum(-1))
    return hessian


def vertex_variance(hessian: Float[Tensor, " V"], pixels: int, grid: PerturbationGrid) -> Float[Tensor, " V"]:
    """(M35) ``sigma^2_v = 1 / (H_v / N + lambda)``, ``N`` the training pixels, ``lambda = 1e-4 / cells^3``."""
    return 1.0 / (hessian / pixels + PRIOR_SCALE / grid.cells**3)


def point_uncertainty(
    x: Float[Tensor, "N 3"], grid: PerturbationGrid, variance: Float[Tensor, " V"]
) -> Float[Tensor, " N"]:
    """(M36) ``u(x) = log10(sqrt(sum_c w_c^2 sigma^2_c / sum_c w_c^2) + 1e-12)`` over the 8 vertices around x."""
    index, weight = grid.corners(x)
    squared = weight.to(variance.dtype).square()
    mixed = (squared * variance[index]).sum(-1) / squared.sum(-1).clamp_min(1e-30)
    return torch.log10(mixed.sqrt() + LOG_EPS)


@torch.no_grad()
def ray_uncertainty(
    model: nn.Module,
    grid: PerturbationGrid,
    variance: Float[Tensor, " V"],
    origins: Float[Tensor, "R 3"],
    dirs: Float[Tensor, "R 3"],
) -> Float[Tensor, " R"]:
    """(M36) ``U_r = sum_i w_i u(x_i) + (1 - A_r) u_min``, clipped to ``[u_min, u_max] = [-3, 6]`` and scaled to
    ``[0, 1]``."""
    result = model.render(origins, dirs)  # type: ignore[operator]  # a SceneModel
    samples = result.samples
    u = point_uncertainty(samples.positions(origins, dirs), grid, variance)
    rendered = ray_sum(result.weights.to(u.dtype) * u, samples.ray_idx, samples.n_rays)
    rendered = rendered + (1.0 - result.acc.to(u.dtype)) * U_MIN
    return (rendered.clamp(U_MIN, U_MAX) - U_MIN) / (U_MAX - U_MIN)


@dataclass(frozen=True)
class BayesRaysScorer:
    """Bayes' Rays' view score: ``prepare`` accumulates M34 over every pixel of the training views and returns
    the step's ``BayesRaysViewScorer``. ``cells``: the perturbation grid's cells a side."""

    cells: int
    name: ClassVar[str] = "bayesrays"

    def __post_init__(self) -> None:
        if self.cells < 1:
            raise ValueError(f"Bayes' Rays needs a perturbation grid of at least one cell a side, got {self.cells}")

    def prepare(
        self, model: nn.Module, observations: Observations, generators: GeneratorFactory, chunk_rays: int
    ) -> "BayesRaysViewScorer":
        grid = PerturbationGrid(model.aabb, self.cells)  # type: ignore[arg-type]  # a duck-typed nn.Module's buffer
        hessian = torch.zeros(grid.vertices, dtype=torch.float64, device=observations.c2w.device)
        for c2w in observations.c2w:
            origins, dirs = pixel_rays(c2w, observations.intrinsics)
            for start in range(0, origins.shape[0], chunk_rays):
                end = start + chunk_rays
                hessian += ray_hessian(model, grid, origins[start:end], dirs[start:end])
        pixels = observations.num_images * observations.intrinsics.num_pixels
        return BayesRaysViewScorer(grid, vertex_variance(hessian, pixels, grid))


@dataclass(frozen=True)
class BayesRaysViewScorer:
    """One step's Bayes' Rays scorer: a view's score is the mean of its rays' rendered uncertainty (M36)."""

    grid: PerturbationGrid
    variance: Float[Tensor, " V"]
    name: ClassVar[str] = "bayesrays"

    def view_score(
        self, model: nn.Module, origins: Float[Tensor, "R 3"], dirs: Float[Tensor, "R 3"], chunk_rays: int
    ) -> Float[Tensor, ""]:
        total = torch.zeros((), dtype=torch.float64, device=origins.device)
        for start in range(0, origins.shape[0], chunk_rays):
            end = start + chunk_rays
            total += ray_uncertainty(model, self.grid, self.variance, origins[start:end], dirs[start:end]).sum()
        return total / max(1, origins.shape[0])
