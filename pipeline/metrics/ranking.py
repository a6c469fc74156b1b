"""How view scores rank candidate poses, and where a score's ranking comes from (diagnostics of METHOD 13
and M16; `python -m pipeline.bench visibility`, `python -m pipeline.experiments.visibility_study`).

NVF's view reward ``R(p)`` (M16) is the mean over the planning image of ``H'``, which
``NVFEntropyScorer.pixel_terms`` splits into ``H_min + seen + unknown + background + mixing + correction``.
Over a candidate set, the term that decides the ranking is the one whose spread moves ``R``: its share of
``R``'s variance, ``cov(term, R) / var(R)`` (the shares of all terms add up to 1), beside its Spearman
correlation with ``R``.
"""

import dataclasses

import numpy as np
import torch
from jaxtyping import Float
from scipy import stats
from torch import Tensor

from nvf.cameras import Intrinsics, pixel_rays
from nvf.model import RenderResult
from nvf.uncertainty.nvf_entropy import NVFEntropyScorer


def auc(positive: np.ndarray, negative: np.ndarray) -> float | None:
    """P(a positive scores above a negative), ties counted half; None if a class is empty."""
    if len(positive) == 0 or len(negative) == 0:
        return None
    return float(stats.mannwhitneyu(positive, negative).statistic / (len(positive) * len(negative)))


def spearman(a: np.ndarray, b: np.ndarray) -> float | None:
    """Spearman's rank correlation; None when undefined (fewer than two values, or a constant one)."""
    if len(a) < 2 or np.ptp(a) == 0 or np.ptp(b) == 0:
        return None
    return float(stats.spearmanr(a, b).statistic)


def ties_at_max(scores: np.ndarray) -> int:
    """How many candidates share the maximum score exactly (METHOD 13 takes the first of them)."""
    return int((scores == scores.max()).sum()) if len(scores) else 0


def view_terms(
    scorer: NVFEntropyScorer, result: RenderResult, visibility: Float[Tensor, " S"] | None = None
) -> dict[str, float]:
    """Mean over a view's rays of each of ``scorer.pixel_terms`` (nats): summed with ``H_min``, the view
    reward R(p) (M16). ``visibility`` replaces the head's ``v`` of ``result`` (a visibility source)."""
    if visibility is not None:
        result = dataclasses.replace(result, visibility=visibility)
    return {name: float(values.double().mean()) for name, values in scorer.pixel_terms(result).items()}


@torch.no_grad()
def render_for_terms(
    model, c2w: Float[Tensor, "4 4"], intr: Intrinsics, sampler: str = "occupancy"
) -> tuple[RenderResult, Tensor, Tensor]:
    """One planning view rendered with the variance and visibility heads (deterministic, ``train=False``)
    with the scorer's ``sampler`` (``nvf.entropy.sampler``): the render, and the rays' origins and
    directions ``[R, 3]``."""
    origins, dirs = pixel_rays(c2w, intr)
    return model.render(origins, dirs, heads=frozenset({"variance", "visibility"}), sampler=sampler), origins, dirs


def term_sum(terms: dict[str, np.ndarray]) -> np.ndarray:
    """The per-candidate sum of ``terms`` (name -> ``[m]``, at least one): the reward, up to a constant."""
    total = sum(terms.values())
    assert isinstance(total, np.ndarray), "at least one term"
    return total


def term_attribution(terms: dict[str, np.ndarray]) -> dict:
    """Over ``m`` candidates, each term's mean and spread, its share of the reward's variance and its
    Spearman correlation with the reward; ``decisive``: the term with the largest share. ``terms``: name ->
    ``[m]`` per-candidate means whose sum (plus a constant) is the reward."""
    reward = term_sum(terms)
    variance = float(np.var(reward))
    per_term = {
        name: {
            "mean": float(np.mean(values)),
            "std": float(np.std(values)),
            "share": float(np.mean((values - values.mean()) * (reward - reward.mean())) / variance)
            if variance > 0
            else None,
            "spearman": spearman(values, reward),
        }
        for name, values in terms.items()
    }
    shares = {name: t["share"] for name, t in per_term.items() if t["share"] is not None}
    return {
        "terms": per_term,
        "decisive": max(shares, key=lambda name: shares[name]) if shares else None,
        "reward_std": variance**0.5,
    }
