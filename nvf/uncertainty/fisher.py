"""FisherRF's expected information gain on NVF's backbone (METHOD.md section 17, M30-M32).

Under a Gaussian likelihood of the rendered colours, the Fisher information of the model's parameters
``theta`` given rays ``r`` is ``sum_r J_r^T J_r`` with ``J_r = dC_r / dtheta`` (``[3, P]``). Only its
diagonal is kept: ``H_D`` over every pixel of the training views, ``H_c`` over a candidate's planning
image, and the candidate scores ``sum_j H_c,j / (H_D,j + lambda)`` (M32). ``theta`` is every parameter the
rendered colour depends on: the hash table, the density MLP and the colour head (stage 1's parameters,
METHOD 10). Diagonals are float64 ``[P]`` over ``params`` flattened in order.

A view's diagonal is exact (one backward pass per ray and channel, M30) where that takes no more
backward passes than the probes, else the mean of ``K`` Rademacher probes (M31): with ``s`` uniform on
``{-1, 1}^{R x 3}``, ``E[(sum_r s_r . J_r)^2] = sum_r diag(J_r^T J_r)``. A probe's gradient is accumulated
over the view's chunks of rays before it is squared, so the estimate does not depend on the chunking.
"""

from dataclasses import dataclass
from typing import ClassVar

import torch
from jaxtyping import Float
from torch import Tensor, nn

from nvf.cameras import pixel_rays
from nvf.observations import Observations
from nvf.seeding import GeneratorFactory

RGB = frozenset({"rgb"})
TRAIN_PROBES = "fisher/train_probes"  # generator purposes (PROTOCOL 3)
VIEW_PROBES = "fisher/view_probes"


def colour_parameters(model: nn.Module) -> list[nn.Parameter]:
    """The parameters of ``model`` that can carry gradients; those the rendered colour does not depend on
    (the variance and visibility heads) get a zero diagonal."""
    return [p for p in model.parameters() if p.requires_grad]


def rademacher(probes: int, rays: int, generator: torch.Generator) -> Float[Tensor, "K R 3"]:
    """``probes x rays x 3`` signs, uniform on ``{-1, 1}``, drawn on the generator's device."""
    bits = torch.randint(2, (probes, rays, 3), generator=generator, device=generator.device)
    return (2 * bits - 1).to(torch.float32)


def _flat(grads: tuple[Tensor | None, ...], params: list[nn.Parameter]) -> Float[Tensor, " P"]:
    """Gradients flattened in ``params``' order, zeros where a parameter is unused."""
    return torch.cat(
        [(torch.zeros_like(p) if g is None else g).reshape(-1) for g, p in zip(grads, params, strict=True)]
    )


def _rendered_colour(model: nn.Module, origins: Float[Tensor, "R 3"], dirs: Float[Tensor, "R 3"]) -> Tensor:
    """``C [R, 3]`` as planning renders it (no jitter, image 0's appearance), with autograd."""
    with torch.enable_grad():
        return model.render(origins, dirs, heads=RGB).rgb  # type: ignore[operator]  # a duck-typed nn.Module's attribute


def probe_fisher_diagonal(
    model: nn.Module,
    params: list[nn.Parameter],
    origins: Float[Tensor, "R 3"],
    dirs: Float[Tensor, "R 3"],
    signs: Float[Tensor, "K R 3"],
    chunk_rays: int,
) -> Float[Tensor, " P"]:
    """(M31) ``(1/K) sum_k (J^T s_k)^2``: one forward per chunk of rays and one backward per probe."""
    probes = signs.shape[0]
    sums = [torch.zeros(sum(p.numel() for p in params), device=origins.device) for _ in range(probes)]
    parts = [total.split([p.numel() for p in params]) for total in sums]  # each parameter's slice, a view
    for start in range(0, origins.shape[0], chunk_rays):
        rgb = _rendered_colour(model, origins[start : start + chunk_rays], dirs[start : start + chunk_rays])
        if not rgb.requires_grad:
            continue
        for k in range(probes):
            grads = torch.autograd.grad(
                rgb,
                params,
                signs[k, start : start + chunk_rays].to(rgb),
                retain_graph=k < probes - 1,
                allow_unused=True,
            )
            for part, grad in zip(parts[k], grads, strict=True):  # added in place: no flat copy of every gradient
                if grad is not None:
                    part.add_(grad.reshape(-1))
    return torch.stack([s.double().square() for s in sums]).mean(0)


def exact_fisher_diagonal(
    model: nn.Module, params: list[nn.Parameter], origins: Float[Tensor, "R 3"], dirs: Float[Tensor, "R 3"]
) -> Float[Tensor, " P"]:
    """(M30) ``sum_r sum_ch (dC_r,ch / dtheta)^2``: one render per ray, one backward per ray and channel."""
    total = torch.zeros(sum(p.numel() for p in params), dtype=torch.float64, device=origins.device)
    for r in range(origins.shape[0]):
        rgb = _rendered_colour(model, origins[r : r + 1], dirs[r : r + 1])
        if not rgb.requires_grad:
            continue
        for ch in range(3):
            grads = torch.autograd.grad(rgb[0, ch], params, retain_graph=ch < 2, allow_unused=True)
            total += _flat(grads, params).double().square()
    return total


def view_fisher_diagonal(
    model: nn.Module,
    params: list[nn.Parameter],
    origins: Float[Tensor, "R 3"],
    dirs: Float[Tensor, "R 3"],
    probes: int,
    generator: torch.Generator,
    chunk_rays: int,
) -> Float[Tensor, " P"]:
    """The diagonal of one view's ``J^T J``: exact (M30) when ``3 R <= probes`` (no more backward passes),
    else ``probes`` Rademacher probes drawn from ``generator`` (M31)."""
    if 3 * origins.shape[0] <= probes:
        return exact_fisher_diagonal(model, params, origins, dirs)
    signs = rademacher(probes, origins.shape[0], generator).to(origins.device)
    return probe_fisher_diagonal(model, params, origins, dirs, signs, chunk_rays)


def information_gain(
    candidate: Float[Tensor, " P"], train: Float[Tensor, " P"], prior_precision: float
) -> Float[Tensor, ""]:
    """(M32) ``sum_j H_c,j / (H_D,j + lambda)``, float64."""
    return (candidate.double() / (train.double() + prior_precision)).sum()


@dataclass(frozen=True)
class FisherRFScorer:
    """FisherRF's view score (METHOD 17): ``prepare`` computes ``H_D`` over every pixel of the training views
    and returns the step's ``FisherRFViewScorer``. ``probes``: ``K`` per view (M31); ``prior_precision``:
    ``lambda`` (M32)."""

    probes: int
    prior_precision: float
    name: ClassVar[str] = "fisherrf"

    def __post_init__(self) -> None:
        if self.probes < 1:
            raise ValueError(f"FisherRF needs at least one probe per view, got probes={self.probes}")
        if not self.prior_precision > 0:
            raise ValueError(f"FisherRF's prior precision lambda must be > 0, got {self.prior_precision}")

    def train_diagonal(
        self, model: nn.Module, observations: Observations, generators: GeneratorFactory, chunk_rays: int
    ) -> Float[Tensor, " P"]:
        """``diag H_D``: the sum over the training views of ``view_fisher_diagonal``, every pixel, one
        generator (``TRAIN_PROBES``) drawn view after view."""
        params = colour_parameters(model)
        generator = generators(TRAIN_PROBES)
        total = torch.zeros(sum(p.numel() for p in params), dtype=torch.float64, device=observations.c2w.device)
        for c2w in observations.c2w:
            origins, dirs = pixel_rays(c2w, observations.intrinsics)
            total += view_fisher_diagonal(model, params, origins, dirs, self.probes, generator, chunk_rays)
        return total

    def prepare(
        self, model: nn.Module, observations: Observations, generators: GeneratorFactory, chunk_rays: int
    ) -> "FisherRFViewScorer":
        return FisherRFViewScorer(self, self.train_diagonal(model, observations, generators, chunk_rays), generators)


@dataclass(frozen=True)
class FisherRFViewScorer:
    """One step's FisherRF scorer: ``view_score`` is M32 with ``H_c`` from ``view_fisher_diagonal``.

    ``train``: ``diag H_D`` ``[P]``. Every view of the step reads the same probes (a fresh
    ``VIEW_PROBES`` generator per view), so a pose scores the same each time it is scored and candidates
    differ by their Jacobians, not by their draws."""

    settings: FisherRFScorer
    train: Float[Tensor, " P"]
    generators: GeneratorFactory
    name: ClassVar[str] = "fisherrf"

    def view_score(
        self, model: nn.Module, origins: Float[Tensor, "R 3"], dirs: Float[Tensor, "R 3"], chunk_rays: int
    ) -> Float[Tensor, ""]:
        params = colour_parameters(model)
        generator = self.generators(VIEW_PROBES)
        candidate = view_fisher_diagonal(model, params, origins, dirs, self.settings.probes, generator, chunk_rays)
        return information_gain(candidate, self.train, self.settings.prior_precision)
