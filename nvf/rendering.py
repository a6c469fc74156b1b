"""Packed volume rendering (METHOD.md section 2, M1-M3).

Samples of ``R`` rays are stored packed: ``S`` intervals with ``ray_idx`` sorted by ray and then by
``t``; a ray may own zero samples and ``S`` may be 0. Per-ray reductions are segment sums
(``index_add``); no function loops over rays in Python.
"""

from dataclasses import dataclass

import torch
from jaxtyping import Bool, Float, Int
from torch import Tensor

# Floor of ``1 - alpha`` inside the log-transmittance: an opaque sample (alpha = 1) keeps its weight
# ``w = T`` and every later sample of the ray gets ``T <= 1e-10 * T`` (finite logs, no NaN).
_MIN_TRANSMITTANCE_FACTOR = 1e-10
# M3: ``D = sum w t / (A + 1e-10)``.
_DEPTH_EPS = 1e-10


@dataclass
class Samples:
    """Packed ray intervals ``[t_start, t_end]`` along ``o + t d``, sorted by ray then ``t``."""

    ray_idx: Int[Tensor, " S"]
    t_start: Float[Tensor, " S"]
    t_end: Float[Tensor, " S"]
    n_rays: int

    @property
    def t_mid(self) -> Float[Tensor, " S"]:
        """Interval midpoints ``t_m = (t_s + t_e) / 2`` (section 1)."""
        return 0.5 * (self.t_start + self.t_end)

    @property
    def deltas(self) -> Float[Tensor, " S"]:
        """Interval lengths ``delta = t_e - t_s`` (section 1)."""
        return self.t_end - self.t_start

    @property
    def num_samples(self) -> int:
        return int(self.ray_idx.shape[0])

    def select(self, mask: Bool[Tensor, " S"]) -> "Samples":
        """The samples where ``mask`` holds (order, and hence sortedness, is kept)."""
        return Samples(self.ray_idx[mask], self.t_start[mask], self.t_end[mask], self.n_rays)

    def positions(self, origins: Float[Tensor, "R 3"], dirs: Float[Tensor, "R 3"]) -> Float[Tensor, "S 3"]:
        """Sample positions ``x = o + t_m d`` (differentiable in ``origins`` and ``dirs``, not ``t``)."""
        t_mid = self.t_mid.detach()[:, None]
        return origins[self.ray_idx] + t_mid * dirs[self.ray_idx]


def alpha_from_density(sigma: Float[Tensor, " S"], deltas: Float[Tensor, " S"]) -> Float[Tensor, " S"]:
    """(M1) ``alpha = 1 - exp(-sigma delta)``."""
    return -torch.expm1(-sigma * deltas)


def weights_from_alpha(
    alpha: Float[Tensor, " S"], ray_idx: Int[Tensor, " S"], n_rays: int
) -> tuple[Float[Tensor, " S"], Float[Tensor, " S"]]:
    """(M2) Weights ``w_i = T_i alpha_i`` and exclusive transmittance ``T_i = prod_{j<i} (1 - alpha_j)``.

    A segmented exclusive cumulative sum of ``log(max(1 - alpha, 1e-10))`` per ray, accumulated in
    float64 so that long packed batches keep full precision; differentiable. ``n_rays`` is part of the
    packed-layout signature (segments are found from ``ray_idx``, which must be sorted).
    """
    if alpha.shape[0] == 0:
        return alpha.clone(), torch.ones_like(alpha)
    log_keep = torch.log(torch.clamp(1.0 - alpha.double(), min=_MIN_TRANSMITTANCE_FACTOR))
    inclusive = torch.cumsum(log_keep, dim=0)
    exclusive = inclusive - log_keep
    # Exclusive sum at each ray's first sample: subtracting it restarts the scan at every segment.
    first = torch.ones_like(ray_idx, dtype=torch.bool)
    first[1:] = ray_idx[1:] != ray_idx[:-1]
    segment = torch.cumsum(first.long(), dim=0) - 1
    trans = torch.exp(exclusive - exclusive[first][segment]).to(alpha.dtype)
    return trans * alpha, trans


def ray_sum(values: Float[Tensor, " S *C"], ray_idx: Int[Tensor, " S"], n_rays: int) -> Float[Tensor, " R *C"]:
    """Per-ray sum of packed ``values`` (zero for rays without samples); differentiable."""
    out = torch.zeros((n_rays, *values.shape[1:]), dtype=values.dtype, device=values.device)
    return out.index_add(0, ray_idx, values)


def expected_depth(
    weights: Float[Tensor, " S"], t_mid: Float[Tensor, " S"], ray_idx: Int[Tensor, " S"], n_rays: int
) -> Float[Tensor, " R"]:
    """(M3) ``D = sum_i w_i t_m,i / (A + 1e-10)``; 0 for a ray with no samples."""
    acc = ray_sum(weights, ray_idx, n_rays)
    return ray_sum(weights * t_mid, ray_idx, n_rays) / (acc + _DEPTH_EPS)
