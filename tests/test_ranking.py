"""pipeline/metrics/ranking.py: ties, rank correlation and the attribution of a ranking to the reward's terms
(M16 split by ``NVFEntropyScorer.pixel_terms``)."""

import numpy as np
import pytest

from pipeline.metrics.ranking import auc, spearman, term_attribution, ties_at_max


def test_ties_at_max_counts_exact_ties():
    assert ties_at_max(np.array([1.0, 3.0, 3.0, 2.0])) == 2
    assert ties_at_max(np.full(5, -9.558695)) == 5  # a score constant over the candidates: a pick by index
    assert ties_at_max(np.array([1.0, 2.0])) == 1


def test_shares_add_up_to_one_and_name_the_term_that_moves_the_reward():
    """cov(term, R) / var(R) over the candidates adds up to 1; a term constant over the candidates has share 0,
    however large its mean; a term that cancels part of another has a negative share."""
    rng = np.random.default_rng(0)
    coverage = rng.uniform(0, 1, 64)
    terms = {
        "unknown": 8.0 * coverage,
        "mixing": 2.0 * coverage + rng.normal(0, 0.01, 64),
        "background": np.full(64, 100.0),
        "correction": -1.0 * coverage,
    }
    report = term_attribution(terms)
    shares = {name: t["share"] for name, t in report["terms"].items()}
    assert sum(shares.values()) == pytest.approx(1.0)
    assert report["decisive"] == "unknown" and shares["unknown"] == pytest.approx(8 / 9, abs=0.01)
    assert shares["background"] == 0.0 and shares["correction"] < 0
    assert report["terms"]["background"]["spearman"] is None  # constant: undefined


def test_constant_reward_has_no_decisive_term():
    report = term_attribution({"seen": np.zeros(4), "mixing": np.ones(4)})
    assert report["decisive"] is None and report["reward_std"] == 0.0


def test_auc_and_spearman():
    assert auc(np.array([0.9, 0.8]), np.array([0.1, 0.2])) == 1.0
    assert auc(np.array([0.5]), np.array([0.5])) == 0.5
    assert auc(np.array([]), np.array([0.1])) is None
    assert spearman(np.array([1.0, 2.0, 3.0]), np.array([3.0, 5.0, 9.0])) == pytest.approx(1.0)
    assert spearman(np.array([1.0, 1.0]), np.array([1.0, 2.0])) is None
