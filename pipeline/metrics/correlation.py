"""Uncertainty quality: how well a per-pixel score predicts the per-pixel error (PROTOCOL.md 4.4).

``error`` is ``sum_ch |pred - gt|`` and ``score`` the method's per-pixel score (NVF: ``H'``, M14) on
the evaluation views, both ``[V, H, W]``. Every statistic is computed in float64 and returns NaN
(never raises) when it is undefined, e.g. for a constant input.
"""

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from jaxtyping import Float
from torch import Tensor

from pipeline.metrics.arrays import Array, as_tensor, clipped

AUSE_FRACTIONS = 100  # removal fractions f = 0, 0.01, ..., 0.99


def pearson(x: Float[Tensor, " N"], y: Float[Tensor, " N"]) -> float:
    """Pearson correlation of paired values; NaN if either side is constant (or ``N < 2``)."""
    x = x.to(torch.float64) - x.to(torch.float64).mean()
    y = y.to(torch.float64) - y.to(torch.float64).mean()
    denom = torch.sqrt(x.square().sum() * y.square().sum())
    if x.numel() < 2 or not denom > 0:
        return math.nan
    return float((x * y).sum() / denom)


def patch_pearson(error: Float[Tensor, "V H W"], score: Float[Tensor, "V H W"], patch: int = 32) -> float:
    """Patch-level r: average-pool both maps over ``patch x patch`` tiles (rows/columns that do not
    fill a whole tile are dropped), then Pearson over all ``V (H/patch) (W/patch)`` pairs."""
    pooled = [F.avg_pool2d(m.to(torch.float64)[:, None], patch).reshape(-1) for m in (error, score)]
    return pearson(*pooled)


def view_sums(
    error: Float[Tensor, "V H W"], score: Float[Tensor, "V H W"]
) -> tuple[Float[Tensor, " V"], Float[Tensor, " V"]]:
    """Per-view sums of ``error`` and ``score`` in float64: the ``V`` pairs of the view-level r."""
    return error.to(torch.float64).sum((1, 2)), score.to(torch.float64).sum((1, 2))


def view_pearson(error: Float[Tensor, "V H W"], score: Float[Tensor, "V H W"]) -> float:
    """View-level r: Pearson of the per-view sums of ``error`` and ``score`` (``V`` pairs)."""
    return pearson(*view_sums(error, score))


def ause(error: Float[Tensor, "V H W"], score: Float[Tensor, "V H W"]) -> float:
    """Area under the sparsification error (an addition, not in the paper or the reference code).

    For ``f = 0, 0.01, ..., 0.99`` remove the ``floor(f N)`` pixels of highest ``score`` and take the
    mean error of the rest; the oracle removes by highest error; AUSE is the mean over ``f`` of
    (curve - oracle). 0 is a perfect ranking. NaN for an empty input.
    """
    e = error.to(torch.float64).reshape(-1)
    n = e.numel()
    if n == 0:
        return math.nan
    removed = torch.arange(AUSE_FRACTIONS, dtype=torch.int64, device=e.device) * n // AUSE_FRACTIONS

    def curve(order: Tensor) -> Tensor:
        remaining = torch.flip(torch.cumsum(torch.flip(e[order], [0]), 0), [0])  # sum of e[order][m:]
        return remaining[removed] / (n - removed)

    by_score = torch.argsort(score.to(torch.float64).reshape(-1), descending=True, stable=True)
    by_error = torch.argsort(e, descending=True, stable=True)
    return float((curve(by_score) - curve(by_error)).mean())


@dataclass(frozen=True)
class UncertaintyCorrelation:
    """Pearson r between error and uncertainty over 32 x 32 patches and over views (4.4), and the per-view
    sums of error and score that the view-level r pairs (``[V]`` each)."""

    patch_pearson: float
    view_pearson: float
    ause: float
    view_error: tuple[float, ...]
    view_score: tuple[float, ...]


def uncertainty_correlation(
    pred: Float[Array, "V H W 3"], gt: Float[Array, "V H W 3"], scores: Float[Array, "V H W"], patch: int = 32
) -> UncertaintyCorrelation:
    """Correlation of the per-pixel error ``sum_ch |pred - gt|`` with the per-pixel score (4.4),
    computed by this module's statistics: patch level over ``patch`` x ``patch`` tiles, view
    level over per-view sums, and AUSE (an addition, labelled so). NaN where undefined."""
    err = (clipped(pred) - clipped(gt)).abs().sum(1)
    u = as_tensor(scores).to(err.device)
    view_error, view_score = view_sums(err, u)
    return UncertaintyCorrelation(
        patch_pearson=patch_pearson(err, u, patch),
        view_pearson=view_pearson(err, u),
        ause=ause(err, u),
        view_error=tuple(view_error.tolist()),
        view_score=tuple(view_score.tolist()),
    )
