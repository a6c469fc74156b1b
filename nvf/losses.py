"""The training losses (METHOD.md section 10): the background composite (M4), the backbone's auxiliary variance
losses of ActiveNeRF (M25) and NeurAR (M27), the variance head's NLL (M21) and the visibility head's balanced BCE
(M19)."""

import math
from collections.abc import Callable

import torch
import torch.nn.functional as F
from jaxtyping import Float
from torch import Tensor

VAR_LOSS_SCALE = 0.01  # M21
VAR_P_FLOOR = 1e-7  # M21: -ln max(p, 1e-7)
AUX_VAR_EPS = 1e-9  # M25
NEURAR_SCALE = 0.01  # M27
BCE_POS_THRESHOLD = 0.5  # M19
# (rendered ray variance V_r [R, 3], squared residual [R, 3]) -> loss (M25, M27)
AuxLoss = Callable[[Float[Tensor, "R 3"], Float[Tensor, "R 3"]], Float[Tensor, ""]]


def composite(
    rgb: Float[Tensor, "R 3"], opacity: Float[Tensor, " R"], background: Float[Tensor, "R 3"]
) -> Float[Tensor, "R 3"]:
    """(M4) ``rgb + (1 - opacity) b``: the prediction with ``(C_hat, A)``, the ground truth with
    ``(c_gt alpha_gt, alpha_gt)``."""
    return rgb + (1.0 - opacity)[:, None] * background


def ground_truth(rgba: Float[Tensor, "R 4"], background: Float[Tensor, "R 3"]) -> Float[Tensor, "R 3"]:
    """(M4) ``c_gt alpha_gt + (1 - alpha_gt) b``."""
    alpha = rgba[:, 3]
    return composite(rgba[:, :3] * alpha[:, None], alpha, background)


def activenerf_loss(ray_variance: Float[Tensor, "R 3"], sq_residual: Float[Tensor, "R 3"]) -> Float[Tensor, ""]:
    """(M25) ``mean[ sg(res^2) / (2 (V + 1e-9)) + 0.5 ln(V + 1e-9) ]``; the residual is detached."""
    v = ray_variance + AUX_VAR_EPS
    return (sq_residual.detach() / (2.0 * v) + 0.5 * torch.log(v)).mean()


def neurar_loss(ray_variance: Float[Tensor, "R 3"], sq_residual: Float[Tensor, "R 3"]) -> Float[Tensor, ""]:
    """(M27) ``0.01 mean (V - sg(res^2))^2``; the residual is detached."""
    return NEURAR_SCALE * ((ray_variance - sq_residual.detach()) ** 2).mean()


def variance_nll(log_p: Float[Tensor, " R"]) -> Float[Tensor, ""]:
    """(M21) ``0.01 mean_{r: p_r > 0} [-ln max(p_r, 1e-7)]`` from ``ln p_r`` (``-inf`` when p_r = 0).

    NaN when no ray has ``p_r > 0`` (reported as divergence by the caller)."""
    valid = log_p > -math.inf
    return VAR_LOSS_SCALE * (-log_p[valid].clamp_min(math.log(VAR_P_FLOOR))).mean()


def balanced_bce_weights(labels: Float[Tensor, " N"]) -> Float[Tensor, " N"]:
    """(M19) ``w+ = 0.7/(2p) + 0.3``, ``w- = 0.7/(2(1-p)) + 0.3`` with ``p`` the fraction of
    ``labels > 0.5``; all ones if ``2p < 1e-7`` or ``2(1-p) < 1e-7``."""
    positive = labels > BCE_POS_THRESHOLD
    p = positive.float().mean().item()
    if 2.0 * p < 1e-7 or 2.0 * (1.0 - p) < 1e-7:
        return torch.ones_like(labels)
    w_pos, w_neg = 0.7 / (2.0 * p) + 0.3, 0.7 / (2.0 * (1.0 - p)) + 0.3
    return torch.where(positive, torch.full_like(labels, w_pos), torch.full_like(labels, w_neg))


def visibility_bce(logits: Float[Tensor, " N"], labels: Float[Tensor, " N"]) -> Float[Tensor, ""]:
    """(M19) ``mean_n [w_n BCEWithLogits(logit_n, V*_n)]`` (a plain mean, not normalised by sum w)."""
    bce = F.binary_cross_entropy_with_logits(logits, labels, reduction="none")
    return (balanced_bce_weights(labels) * bce).mean()
