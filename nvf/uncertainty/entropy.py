"""Ray entropy of the NVF mixture and its per-pixel correction (METHOD.md sections 7-8, M10-M15).

Entropies are in nats. ``H_MIN`` (M11) is the floor: the entropy of the background Gaussian.
"""

import math

import torch
from jaxtyping import Float, Int
from torch import Tensor

from nvf.config import EntropyConfig
from nvf.rendering import ray_sum
from nvf.uncertainty.mixture import RayMixture

LOG_2PIE = math.log(2.0 * math.pi * math.e)
LOG_EPS = 1e-9  # M10: inside ln(pi) and ln(q)
DEPTH_EPS = 1e-10  # M15


def entropy_floor(var_bg: float) -> float:
    """(M11) ``(3/2) ln(2 pi e) + (3/2) ln var_bg``: the background Gaussian's entropy."""
    return 1.5 * LOG_2PIE + 1.5 * math.log(var_bg)


H_MIN = entropy_floor(1e-4)  # M11: -9.558695 nats


def mixture_entropy_upper_bound(mix: RayMixture, logdet_coeff: float = 0.5) -> Float[Tensor, " R"]:
    """(M10) Packed component-wise bound
    ``sum_k pi_k [-ln(pi_k + 1e-9) + (3/2) ln(2 pi e) + c sum_ch ln(q_k,ch + 1e-9)]``.

    ``c = logdet_coeff`` (0.5: S7; 1.0: the reference, D1). A NaN bracket counts as 0.
    """
    bracket = (
        -torch.log(mix.weights + LOG_EPS) + 1.5 * LOG_2PIE + logdet_coeff * torch.log(mix.variances + LOG_EPS).sum(-1)
    )
    bracket = torch.where(torch.isnan(bracket), 0.0, bracket)
    return ray_sum(mix.weights * bracket, mix.ray_idx, mix.n_rays)


def _log_det(var: float, logdet_coeff: float, like: Tensor) -> Float[Tensor, ""]:
    """(M10) ``c sum_ch ln(q_ch + 1e-9)`` of a constant variance ``q = var``, in ``like``'s dtype and
    arithmetic (as on a packed ``[K,3]`` variance tensor)."""
    return logdet_coeff * torch.log(like.new_full((3,), var) + LOG_EPS).sum()


def _weighted_bracket(
    weights: Float[Tensor, " K"], log_det: Float[Tensor, " K"] | Float[Tensor, ""]
) -> Float[Tensor, " K"]:
    """(M10) ``pi [-ln(pi + 1e-9) + (3/2) ln(2 pi e) + log_det]`` per component; a NaN bracket counts as 0."""
    bracket = 1.5 * LOG_2PIE - torch.log(weights + LOG_EPS) + log_det
    return weights * bracket.nan_to_num(nan=0.0, posinf=math.inf, neginf=-math.inf)


def upper_bound_and_depth(
    eq_weights: Float[Tensor, " S"],
    visibility: Float[Tensor, " S"] | None,
    variance: Float[Tensor, "S 3"] | None,
    t_mid: Float[Tensor, " S"],
    ray_idx: Int[Tensor, " S"],
    n_rays: int,
    cfg: EntropyConfig,
) -> tuple[Float[Tensor, " R"], Float[Tensor, " R"]]:
    """(M9, M10, M15) The bound ``H [R]`` of ``ray_mixture``'s mixture and the per-pixel depth ``d [R]``,
    without packing the mixture.

    Segment sums of ``pi_i bracket_i`` (seen), ``w_bar_i (1 - v_i)``, ``w_bar_i`` and ``w_bar_i t_m,i``
    over the samples, then the unknown (``pi_un``, ``var_un``) and background
    (``pi_bg = clip(1 - sum w_bar, 0, 1)``, ``var_bg``) components per ray: the same sums in the same
    order as ``mixture_entropy_upper_bound(ray_mixture(...))`` and ``equivalent_depth(..., "pixel")``.
    ``visibility`` / ``variance`` None: the w/o Vis. (``v = 1``) / w/o Var. (seen ``q = var_bg``) ablations.
    """
    c = cfg.logdet_coeff
    seen = eq_weights if visibility is None else eq_weights * visibility
    if variance is None:
        seen_log_det = _log_det(cfg.var_bg, c, eq_weights)
    else:
        log_q = torch.log(variance + LOG_EPS)
        seen_log_det = c * (log_q[:, 0] + log_q[:, 1] + log_q[:, 2])  # = .sum(-1), faster on CPU
    entropy = ray_sum(_weighted_bracket(seen, seen_log_det), ray_idx, n_rays)
    if visibility is not None:
        unknown = ray_sum(eq_weights * (1.0 - visibility), ray_idx, n_rays)
        entropy = entropy + _weighted_bracket(unknown, _log_det(cfg.var_un, c, entropy))
    mass = ray_sum(eq_weights, ray_idx, n_rays)
    entropy = entropy + _weighted_bracket((1.0 - mass).clamp(0.0, 1.0), _log_det(cfg.var_bg, c, entropy))
    depth = ray_sum(eq_weights * t_mid, ray_idx, n_rays) / (mass + DEPTH_EPS)
    return entropy, depth


TERMS = ("seen", "unknown", "background", "mixing")  # M10's bound split per ray; see ``entropy_terms``


def entropy_terms(
    eq_weights: Float[Tensor, " S"],
    visibility: Float[Tensor, " S"] | None,
    variance: Float[Tensor, "S 3"] | None,
    ray_idx: Int[Tensor, " S"],
    n_rays: int,
    cfg: EntropyConfig,
) -> dict[str, Float[Tensor, " R"]]:
    """(M9, M10) The bound ``H`` of each ray split into ``TERMS``, ``H = H_min + sum of the terms``
    (``H_min`` of M11; the weights of a ray sum to 1):

    - ``seen``: ``sum_i pi_i (G_i - H_min)``, the seen components' Gaussian terms above the floor, with
      ``G = (3/2) ln(2 pi e) + c sum_ch ln(q_ch + 1e-9)``;
    - ``unknown``: ``pi_un (G_un - H_min)``, about 13.8 nats per unit of weight with ``c = 0.5``;
    - ``background``: ``pi_bg (G_bg - H_min)``, 0 with ``c = 0.5``;
    - ``mixing``: ``-sum_k pi_k ln(pi_k + 1e-9)`` over every component.

    Arguments as in ``upper_bound_and_depth`` (``None``: the w/o Vis. / w/o Var. ablations).
    """
    c, floor = cfg.logdet_coeff, entropy_floor(cfg.var_bg)
    seen = eq_weights if visibility is None else eq_weights * visibility
    if variance is None:
        seen_gauss = 1.5 * LOG_2PIE + _log_det(cfg.var_bg, c, eq_weights)
    else:
        seen_gauss = 1.5 * LOG_2PIE + c * torch.log(variance + LOG_EPS).sum(-1)
    mass = ray_sum(eq_weights, ray_idx, n_rays)
    unknown = (
        torch.zeros_like(mass) if visibility is None else ray_sum(eq_weights * (1.0 - visibility), ray_idx, n_rays)
    )
    background = (1.0 - mass).clamp(0.0, 1.0)

    def gauss_excess(var: float) -> Float[Tensor, ""]:
        return 1.5 * LOG_2PIE + _log_det(var, c, mass) - floor

    def mixing(weights: Tensor) -> Tensor:
        return -weights * torch.log(weights + LOG_EPS)

    return {
        "seen": ray_sum(seen * (seen_gauss - floor), ray_idx, n_rays),
        "unknown": unknown * gauss_excess(cfg.var_un),
        "background": background * gauss_excess(cfg.var_bg),
        "mixing": ray_sum(mixing(seen), ray_idx, n_rays) + mixing(unknown) + mixing(background),
    }


def mixture_moment_matched_entropy(mix: RayMixture) -> Float[Tensor, " R"]:
    """(M12) Packed "Loose" bound: entropy ``(3/2) ln(2 pi e) + (1/2) logdet Sigma`` of the
    moment-matched Gaussian, ``Sigma = sum_k pi_k (diag q_k + (mu_k - mu_bar)(mu_k - mu_bar)^T)``
    (full 3x3, float64)."""
    weights = mix.weights.to(torch.float64)
    means = mix.means.to(torch.float64)
    mean = ray_sum(weights[:, None] * means, mix.ray_idx, mix.n_rays)
    centred = means - mean[mix.ray_idx]
    spread = torch.diag_embed(mix.variances.to(torch.float64)) + centred[:, :, None] * centred[:, None, :]
    cov = ray_sum(weights[:, None, None] * spread, mix.ray_idx, mix.n_rays)
    return (1.5 * LOG_2PIE + 0.5 * torch.linalg.slogdet(cov).logabsdet).to(mix.weights.dtype)


def _packed(
    weights: Float[Tensor, "R K"], means: Float[Tensor, "R K 3"], variances: Float[Tensor, "R K 3"]
) -> RayMixture:
    n_rays, n_comp = weights.shape
    ray_idx = torch.arange(n_rays, device=weights.device).repeat_interleave(n_comp)
    return RayMixture(weights.reshape(-1), means.reshape(-1, 3), variances.reshape(-1, 3), ray_idx, n_rays)


def gmm_entropy_upper_bound(
    weights: Float[Tensor, "R K"],
    means: Float[Tensor, "R K 3"],
    variances: Float[Tensor, "R K 3"],
    logdet_coeff: float = 0.5,
) -> Float[Tensor, " R"]:
    """(M10) Upper bound on the entropy of ``R`` padded diagonal mixtures (means do not enter it)."""
    return mixture_entropy_upper_bound(_packed(weights, means, variances), logdet_coeff)


def moment_matched_entropy(
    weights: Float[Tensor, "R K"], means: Float[Tensor, "R K 3"], variances: Float[Tensor, "R K 3"]
) -> Float[Tensor, " R"]:
    """(M12) Moment-matched Gaussian entropy of ``R`` padded diagonal mixtures."""
    return mixture_moment_matched_entropy(_packed(weights, means, variances))


def correlation_factor(depth: Float[Tensor, " R"], d0: float, corr: str) -> Float[Tensor, " R"]:
    """(M13) ``1 - rho``: ``min(d/d0, 1)^2`` (quadratic) or ``1 - exp(-d/d0)`` (exp); 1 if ``d0 = 0``."""
    if d0 < 0:
        raise ValueError(f"d0 must be >= 0 (resolve auto/scene values first), got {d0}")
    if d0 == 0:
        return torch.ones_like(depth)
    if corr == "quadratic":
        return (depth / d0).clamp(max=1.0).square()
    if corr == "exp":
        return 1.0 - torch.exp(-depth / d0)
    raise ValueError(f"unknown correlation {corr!r} (quadratic | exp)")


def corrected_entropy(
    entropy: Float[Tensor, " R"], depth: Float[Tensor, " R"], d0: float, corr: str, h_min: float = H_MIN
) -> Float[Tensor, " R"]:
    """(M13, M14) ``H' = max(H_min + (1 - rho)(H - H_min), H_min)``; ``d0 = 0``: ``max(H, H_min)``."""
    corrected = h_min + correlation_factor(depth, d0, corr) * (entropy - h_min)
    return corrected.clamp(min=h_min)


def equivalent_depth(
    eq_weights: Float[Tensor, " S"],
    t_mid: Float[Tensor, " S"],
    ray_idx: Int[Tensor, " S"],
    n_rays: int,
    depth_mode: str = "pixel",
    pixel_index: Int[Tensor, " R"] | None = None,
    chunk_rays: int = 4096,
) -> Float[Tensor, " R"]:
    """(M15) ``d = sum_i w_bar_i t_m,i / (sum_i w_bar_i + 1e-10)`` with the equivalent weights (M8).

    ``depth_mode="pixel"``: per ray (0 for a ray without samples). ``"chunk"`` reproduces the
    reference bug (D3): one weighted-mean depth shared by all rays whose row-major ``pixel_index``
    falls in the same ``chunk_rays`` block (``pixel_index`` is required).
    """
    if depth_mode == "pixel":
        group, n_groups = ray_idx, n_rays
    elif depth_mode == "chunk":
        if pixel_index is None:
            raise ValueError("depth_mode='chunk' needs the rays' row-major pixel_index")
        chunk = torch.div(pixel_index, chunk_rays, rounding_mode="floor")
        n_groups = int(chunk.max()) + 1 if n_rays > 0 else 0
        group = chunk[ray_idx]
    else:
        raise ValueError(f"unknown depth_mode {depth_mode!r} (pixel | chunk)")
    total = ray_sum(eq_weights * t_mid, group, n_groups)
    mass = ray_sum(eq_weights, group, n_groups)
    depth = total / (mass + DEPTH_EPS)
    return depth if depth_mode == "pixel" else depth[chunk]
