"""Per-ray Gaussian mixture of NVF (METHOD.md sections 5-6, M7-M9) and its log-density (M21).

A ray's pixel colour is modelled as a mixture of one "seen" Gaussian per sample, one merged
"unknown" Gaussian and one background Gaussian. Mixtures are packed like samples (``ray_idx``).
"""

import math
from dataclasses import dataclass

import torch
from jaxtyping import Float, Int
from torch import Tensor

from nvf.config import EntropyConfig
from nvf.rendering import ray_sum

ALPHA_BAR_MAX = 1.0 - 1e-7  # M8 / METHOD 15.4: clamp inside the logs (an opaque sample gives no inf)
VAR_MIN = 1e-4  # M21: variances clamped to >= 1e-4 in the density


@dataclass
class RayMixture:
    """(M9) Packed diagonal Gaussian mixtures of ``n_rays`` rays, ``K = S + 2R`` components.

    Layout: the ``S`` seen components in sample order, then the unknown component of rays
    ``0..R-1``, then the background component of rays ``0..R-1``; the weights of each ray sum to 1.
    """

    weights: Float[Tensor, " K"]
    means: Float[Tensor, "K 3"]
    variances: Float[Tensor, "K 3"]
    ray_idx: Int[Tensor, " K"]
    n_rays: int

    def padded(self) -> tuple[Float[Tensor, "R N"], Float[Tensor, "R N 3"], Float[Tensor, "R N 3"]]:
        """Padded layout ``[R, N]`` (``N`` = most components of a ray), components in packed order.

        Padding slots get weight 0, mean 0 and variance 1, so they change neither (M10) nor (M12).
        """
        counts = torch.bincount(self.ray_idx, minlength=self.n_rays)
        width = int(counts.max()) if self.n_rays > 0 else 0
        order = torch.argsort(self.ray_idx, stable=True)
        first = torch.cumsum(counts, 0) - counts
        sorted_rays = self.ray_idx[order]
        slot = torch.arange(order.numel(), device=order.device) - first[sorted_rays]
        index = (sorted_rays, slot)
        weights = self.weights.new_zeros((self.n_rays, width)).index_put(index, self.weights[order])
        means = self.means.new_zeros((self.n_rays, width, 3)).index_put(index, self.means[order])
        variances = self.variances.new_ones((self.n_rays, width, 3)).index_put(index, self.variances[order])
        return weights, means, variances


def _exclusive_transmittance(
    alpha_bar: Float[Tensor, " S"], ray_idx: Int[Tensor, " S"], counts: Int[Tensor, " R"]
) -> Float[Tensor, " S"]:
    """(M8) ``T_bar_i = prod_{j<i} (1 - alpha_bar_j)`` per ray: ``exp`` of a segmented float64
    cumulative sum of ``ln(1 - min(alpha_bar, 1 - 1e-7))`` (samples sorted by ray, then ``t``;
    ``counts`` = samples per ray)."""
    log_keep = torch.log1p(-alpha_bar.to(torch.float64).clamp(max=ALPHA_BAR_MAX))
    exclusive = torch.cumsum(log_keep, 0) - log_keep
    first = torch.cumsum(counts, 0) - counts  # index of each ray's first sample
    start = exclusive.index_select(0, first.index_select(0, ray_idx))  # faster than [] indexing on CPU
    return torch.exp(exclusive - start).to(alpha_bar.dtype)


def checked_visibility(visibility: Float[Tensor, " S"] | None, cfg: EntropyConfig) -> Float[Tensor, " S"] | None:
    """``v``, or None when the w/o Vis. ablation sets ``v = 1`` (METHOD.md 11)."""
    if not cfg.use_visibility:
        return None
    if visibility is None:
        raise ValueError("use_visibility=True needs the visibility head's output")
    return visibility


def equivalent_alpha(
    alpha: Float[Tensor, " S"], visibility: Float[Tensor, " S"] | None, cfg: EntropyConfig
) -> Float[Tensor, " S"]:
    """(M7) ``alpha_bar = [v + beta (1 - v)] alpha + (1 - beta)(1 - v) alpha_un``.

    ``cfg.use_visibility=False`` (w/o Vis.) sets ``v = 1``, i.e. ``alpha_bar = alpha``.
    """
    v = checked_visibility(visibility, cfg)
    if v is None:
        return alpha
    return (v + cfg.beta * (1.0 - v)) * alpha + (1.0 - cfg.beta) * (1.0 - v) * cfg.alpha_un


def equivalent_weights(
    alpha: Float[Tensor, " S"],
    visibility: Float[Tensor, " S"] | None,
    ray_idx: Int[Tensor, " S"],
    counts: Int[Tensor, " R"],
    cfg: EntropyConfig,
) -> Float[Tensor, " S"]:
    """(M7, M8) ``w_bar_i = T_bar_i alpha_bar_i`` straight from ``alpha_bar`` (no
    ``-ln(1 - alpha_bar)/delta`` round trip; ``alpha_bar <= 1 - 1e-7`` inside the logs).

    ``counts [R]``: samples per ray, ``torch.bincount(ray_idx, minlength=R)``.
    """
    alpha_bar = equivalent_alpha(alpha, visibility, cfg)
    return _exclusive_transmittance(alpha_bar, ray_idx, counts) * alpha_bar


def checked_variance(variance: Float[Tensor, "S 3"] | None, cfg: EntropyConfig) -> Float[Tensor, "S 3"] | None:
    """``q`` of the seen components, or None when the w/o Var. ablation sets ``q = var_bg`` (METHOD.md 11)."""
    if not cfg.use_variance:
        return None
    if variance is None:
        raise ValueError("use_variance=True needs the variance head's output")
    return variance


def ray_mixture(
    alpha: Float[Tensor, " S"],
    rgb_s: Float[Tensor, "S 3"],
    variance: Float[Tensor, "S 3"] | None,
    visibility: Float[Tensor, " S"] | None,
    ray_idx: Int[Tensor, " S"],
    n_rays: int,
    cfg: EntropyConfig,
) -> tuple[RayMixture, Float[Tensor, " S"]]:
    """(M8, M9) Mixture of each ray and the equivalent weights ``w_bar [S]`` (``equivalent_weights``).

    Reference split (D22):
    ``pi_i = w_bar_i v_i``, ``pi_un = sum_i w_bar_i (1 - v_i)`` (one merged component, mean ``mu_un``,
    variance ``var_un``), ``pi_bg = clip(1 - sum_i w_bar_i, 0, 1)`` (mean 0, variance ``var_bg``).
    Switches (METHOD.md 11): ``use_visibility=False`` gives ``v = 1`` (so ``pi_un = 0``);
    ``use_variance=False`` gives ``q = var_bg`` for the seen components only.
    """
    v = checked_visibility(visibility, cfg)
    counts = torch.bincount(ray_idx, minlength=n_rays)
    eq_weights = equivalent_weights(alpha, visibility, ray_idx, counts, cfg)
    if v is None:
        seen = eq_weights
        unknown = eq_weights.new_zeros(n_rays)
    else:
        seen = eq_weights * v
        unknown = ray_sum(eq_weights * (1.0 - v), ray_idx, n_rays)
    background = (1.0 - ray_sum(eq_weights, ray_idx, n_rays)).clamp(0.0, 1.0)

    seen_var = checked_variance(variance, cfg)
    if seen_var is None:
        seen_var = torch.full_like(rgb_s, cfg.var_bg)
    per_ray = rgb_s.new_ones((n_rays, 3))
    rays = torch.arange(n_rays, device=ray_idx.device)
    mixture = RayMixture(
        weights=torch.cat([seen, unknown, background]),
        means=torch.cat([rgb_s, per_ray * cfg.mu_un, torch.zeros_like(per_ray)]),
        variances=torch.cat([seen_var, per_ray * cfg.var_un, per_ray * cfg.var_bg]),
        ray_idx=torch.cat([ray_idx, rays, rays]),
        n_rays=n_rays,
    )
    return mixture, eq_weights


def mixture_log_density(mix: RayMixture, z: Float[Tensor, "R 3"]) -> Float[Tensor, " R"]:
    """``ln p_r(z_r)`` of each ray's mixture (M21), by log-sum-exp of ``ln pi + ln N`` in float64.

    Variances are clamped to ``>= 1e-4``; ``-inf`` where ``p_r = 0`` (all weights 0), with zero
    (not NaN) gradients there, so such rays can simply be masked out of the loss.
    """
    weights = mix.weights.to(torch.float64)
    var = mix.variances.to(torch.float64).clamp(min=VAR_MIN)
    diff = z.to(torch.float64)[mix.ray_idx] - mix.means.to(torch.float64)
    log_normal = -0.5 * (torch.log(2.0 * math.pi * var) + diff.square() / var).sum(-1)
    positive = weights > 0
    log_weights = torch.where(positive, torch.log(torch.where(positive, weights, 1.0)), -math.inf)
    x = log_weights + log_normal
    peak = torch.full((mix.n_rays,), -math.inf, dtype=x.dtype, device=x.device)
    peak = peak.scatter_reduce(0, mix.ray_idx, x.detach(), "amax")
    peak = torch.where(torch.isfinite(peak), peak, 0.0)
    total = ray_sum(torch.exp(x - peak[mix.ray_idx]), mix.ray_idx, mix.n_rays)
    nonzero = total > 0
    log_p = torch.where(nonzero, torch.log(torch.where(nonzero, total, 1.0)) + peak, -math.inf)
    return log_p.to(z.dtype)
