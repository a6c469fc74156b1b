"""pipeline/metrics/correlation.py: uncertainty-error correlation (PROTOCOL 4.4): patch- and
view-level Pearson r and AUSE (an addition), NaN when undefined."""

import math

import numpy as np
import pytest
import torch

from pipeline.metrics.correlation import ause, patch_pearson, view_pearson


def test_patch_pearson_pools_32x32_patches():
    """Average-pool to 2 x 2 patches per view, then Pearson over all V * 4 pairs."""
    g = torch.Generator().manual_seed(0)
    error = torch.rand(3, 64, 64, generator=g)
    score = torch.rand(3, 64, 64, generator=g)
    pooled = [m.double().reshape(3, 2, 32, 2, 32).mean((2, 4)).reshape(-1).numpy() for m in (error, score)]
    assert patch_pearson(error, score) == pytest.approx(np.corrcoef(*pooled)[0, 1], abs=1e-12)
    # mirroring the score inside each patch does not change the patch-level r
    mirrored = score.reshape(3, 2, 32, 2, 32).flip(2, 4).reshape(3, 64, 64)
    assert patch_pearson(error, mirrored) == pytest.approx(patch_pearson(error, score), abs=1e-9)
    assert patch_pearson(error, 3 * error + 1) == pytest.approx(1.0)
    assert patch_pearson(error, -error) == pytest.approx(-1.0)


def test_view_pearson_uses_per_view_sums():
    g = torch.Generator().manual_seed(1)
    error = torch.rand(5, 8, 8, generator=g)
    score = torch.rand(5, 8, 8, generator=g)
    sums = [m.double().sum((1, 2)).numpy() for m in (error, score)]
    assert view_pearson(error, score) == pytest.approx(np.corrcoef(*sums)[0, 1], abs=1e-12)


def test_constant_input_gives_nan():
    """Pearson r is undefined for a constant side: NaN, not an exception."""
    error = torch.rand(2, 32, 32)
    assert math.isnan(patch_pearson(error, torch.full_like(error, -9.5)))
    assert math.isnan(view_pearson(torch.zeros_like(error), error))
    assert math.isnan(view_pearson(error[:1], error[:1]))  # one view: a single pair


def test_ause():
    """AUSE (addition): 0 for the oracle ranking, positive for the reversed ranking, hand value."""
    error = torch.arange(100.0).reshape(1, 10, 10)
    assert ause(error, error) == pytest.approx(0.0)
    assert ause(error, 2 * error - 5) == pytest.approx(0.0)
    # removing k of the 100 pixels (f = k/100): the oracle removes the largest errors (mean of the
    # rest (99-k)/2), the reversed ranking the smallest (mean (99+k)/2): gap k, AUSE = mean_k k = 49.5
    assert ause(error, -error) == pytest.approx(49.5)
