"""nvf/uncertainty/entropy.py: the bounds (M10, M12) against Monte-Carlo and exact entropies, the
test-value table (METHOD 7.4), the floor (M11), the correction (M13, M14) and the depth (M15)."""

import math

import pytest
import torch

from nvf.config import EntropyConfig
from nvf.uncertainty import H_MIN, gmm_entropy_upper_bound, moment_matched_entropy, ray_mixture
from nvf.uncertainty.entropy import (
    corrected_entropy,
    correlation_factor,
    entropy_floor,
    equivalent_depth,
    mixture_entropy_upper_bound,
    mixture_moment_matched_entropy,
)

LOG_2PIE = math.log(2 * math.pi * math.e)


def random_mixtures(n_rays, n_comp, seed):
    """Padded diagonal mixtures with Dirichlet weights, means in [0,1]^3, variances in [1e-4, 1]."""
    g = torch.Generator().manual_seed(seed)
    weights = torch.distributions.Dirichlet(torch.ones(n_comp)).sample((n_rays,)).double()
    means = torch.rand(n_rays, n_comp, 3, generator=g, dtype=torch.float64)
    variances = 10.0 ** (-4.0 + 4.0 * torch.rand(n_rays, n_comp, 3, generator=g, dtype=torch.float64))
    return weights, means, variances


def monte_carlo_entropy(weights, means, variances, n=30_000):
    """-E[ln p(z)] per mixture by sampling, with its standard error."""
    mix = torch.distributions.MixtureSameFamily(
        torch.distributions.Categorical(probs=weights),
        torch.distributions.Independent(torch.distributions.Normal(means, variances.sqrt()), 1),
    )
    log_p = mix.log_prob(mix.sample((n,)))  # [n, R]
    return -log_p.mean(0), log_p.std(0) / math.sqrt(n)


def test_floor_value():
    """(M11) H_min = (3/2) ln(2 pi e) + (3/2) ln 1e-4 = -9.558695 nats."""
    assert H_MIN == pytest.approx(-9.558695, abs=1e-6)
    assert entropy_floor(1e-4) == H_MIN


def test_upper_bound_exact_for_a_single_gaussian():
    """(M10) One component, c = 1/2: the bound is the Gaussian's entropy (up to the 1e-9 in the logs)."""
    q = torch.tensor([[[0.01, 0.2, 1.5]]], dtype=torch.float64)
    exact = torch.distributions.Normal(torch.zeros(3), q.reshape(3).sqrt()).entropy().sum()
    ones = torch.ones(1, 1, dtype=torch.float64)
    assert gmm_entropy_upper_bound(ones, torch.zeros_like(q), q).item() == pytest.approx(exact.item(), abs=1e-6)
    assert moment_matched_entropy(ones, torch.zeros_like(q), q).item() == pytest.approx(exact.item(), abs=1e-9)


@pytest.mark.parametrize("n_comp", [2, 5])
def test_bounds_above_monte_carlo_entropy(n_comp):
    """(M10, M12) Both bounds are >= the true mixture entropy (Monte-Carlo, 5 standard errors)."""
    weights, means, variances = random_mixtures(8, n_comp, seed=n_comp)
    truth, stderr = monte_carlo_entropy(weights, means, variances)
    margin = 5 * stderr + 1e-6
    assert (gmm_entropy_upper_bound(weights, means, variances) >= truth - margin).all()
    assert (moment_matched_entropy(weights, means, variances) >= truth - margin).all()


def test_upper_bound_tight_for_separated_components():
    """(M10) Far-apart components: the bound equals H(pi) + sum pi H_k, the true entropy (MC check)."""
    weights = torch.tensor([[0.2, 0.3, 0.5]], dtype=torch.float64)
    means = torch.tensor([[[0.0, 0, 0], [10, 0, 0], [0, 10, 0]]], dtype=torch.float64)
    variances = torch.full((1, 3, 3), 0.01, dtype=torch.float64)
    truth, stderr = monte_carlo_entropy(weights, means, variances)
    bound = gmm_entropy_upper_bound(weights, means, variances)
    assert abs(bound - truth).item() < 5 * stderr.item() + 1e-5


def one_sample_mixture(v):
    """METHOD 7.4: beta = 0.95, one sample with alpha = 1 and q = 0.01 per channel."""
    rgb, q = torch.full((1, 3), 0.5), torch.full((1, 3), 0.01)
    return ray_mixture(torch.ones(1), rgb, q, torch.tensor([v]), torch.zeros(1, dtype=torch.long), 1, EntropyConfig())[
        0
    ]


@pytest.mark.parametrize(
    "v, weights, h_half, h_one",
    [(0.0, (0.0, 0.049502, 0.950498), 3.769962, 3.086060), (1.0, (1.0, 0.0, 0.0), -2.650940, -9.558695)],
)
def test_table_one_sample(v, weights, h_half, h_one):
    """METHOD 7.4 (M7-M10): mixture weights (seen, bg, un) and H for c = 0.5 and c = 1.0, to 1e-5."""
    mix = one_sample_mixture(v)
    seen, unknown, background = mix.weights.tolist()
    assert (seen, background, unknown) == pytest.approx(weights, abs=1e-6)
    assert mixture_entropy_upper_bound(mix, 0.5).item() == pytest.approx(h_half, abs=1e-5)
    assert mixture_entropy_upper_bound(mix, 1.0).item() == pytest.approx(h_one, abs=1e-5)


def test_table_no_samples():
    """METHOD 7.4, "no samples": pi_bg = 1. The table's -9.558695 (c = 0.5) and -23.374206 (c = 1)
    omit M10's +1e-9 inside ln(sigma_bg^2), which adds 3c ln(1 + 1e-5) (1.5e-5, 3e-5 nats); both
    end at H_min after M14 (d = 0), c = 1's "-> clamped" included."""
    none, none3 = torch.zeros(0), torch.zeros(0, 3)
    mix = ray_mixture(none, none3, none3, none, torch.zeros(0, dtype=torch.long), 1, EntropyConfig())[0]
    assert mix.weights.tolist() == [0.0, 1.0]  # (un, bg)
    for c, table in ((0.5, -9.558695), (1.0, -23.374206)):
        h = mixture_entropy_upper_bound(mix, c)
        assert h.item() - 3 * c * math.log1p(1e-5) == pytest.approx(table, abs=1e-5)
        assert corrected_entropy(h, torch.zeros(1), 1.0, "quadratic").item() == torch.tensor(H_MIN).item()


def test_logdet_coefficient_only_scales_the_variance_term():
    """(M10, D1) c = 1 minus c = 0.5 is 0.5 sum_k pi_k sum_ch ln(q + 1e-9)."""
    weights, means, variances = random_mixtures(4, 3, seed=1)
    diff = gmm_entropy_upper_bound(weights, means, variances, 1.0) - gmm_entropy_upper_bound(weights, means, variances)
    assert torch.allclose(diff, 0.5 * (weights * torch.log(variances + 1e-9).sum(-1)).sum(-1), atol=1e-12)


def test_nan_bracket_counts_as_zero():
    """(M10) A NaN inside the bracket (here a zero-weight component with q = NaN or q < 0) becomes 0."""
    weights = torch.tensor([[1.0, 0.0, 0.0]])
    variances = torch.tensor([[[0.01] * 3, [math.nan] * 3, [-1.0] * 3]])
    got = gmm_entropy_upper_bound(weights, torch.zeros(1, 3, 3), variances)
    assert got.item() == pytest.approx(1.5 * LOG_2PIE + 1.5 * math.log(0.01), abs=1e-5)


def test_packed_equals_padded():
    """(M9, M10, M12) The packed functions agree with the padded public ones, empty rays included."""
    g = torch.Generator().manual_seed(3)
    ray_idx = torch.repeat_interleave(torch.arange(4), torch.tensor([3, 0, 1, 6]))
    s = ray_idx.numel()
    alpha, vis = torch.rand(s, generator=g), torch.rand(s, generator=g)
    rgb, q = torch.rand(s, 3, generator=g), 1e-4 + torch.rand(s, 3, generator=g)
    mix, _ = ray_mixture(alpha, rgb, q, vis, ray_idx, 4, EntropyConfig())
    padded = mix.padded()
    for c in (0.5, 1.0):
        assert torch.allclose(mixture_entropy_upper_bound(mix, c), gmm_entropy_upper_bound(*padded, c), atol=1e-5)
    assert torch.allclose(mixture_moment_matched_entropy(mix), moment_matched_entropy(*padded), atol=1e-5)
    assert mixture_moment_matched_entropy(mix)[1].item() == pytest.approx(H_MIN, abs=1e-5)  # empty ray


def test_bound_gradients_finite():
    """Both bounds are differentiable in weights, means and variances (for -OPT)."""
    weights, means, variances = (t.float().requires_grad_() for t in random_mixtures(3, 4, seed=2))
    weights.data[0, 0] = 0.0
    total = gmm_entropy_upper_bound(weights, means, variances) + moment_matched_entropy(weights, means, variances)
    total.sum().backward()
    for t in (weights, means, variances):
        assert torch.isfinite(t.grad).all()


def test_correlation_factor_m13():
    """(M13) quadratic min(d/d0, 1)^2, exp 1 - exp(-d/d0); d0 = 0 disables (factor 1)."""
    d = torch.tensor([0.0, 0.5, 1.0, 3.0])
    assert torch.allclose(correlation_factor(d, 1.0, "quadratic"), torch.tensor([0.0, 0.25, 1.0, 1.0]))
    assert torch.allclose(correlation_factor(d, 2.0, "exp"), 1 - torch.exp(-d / 2))
    assert torch.equal(correlation_factor(d, 0.0, "quadratic"), torch.ones(4))
    with pytest.raises(ValueError):
        correlation_factor(d, 1.0, "linear")
    with pytest.raises(ValueError):
        correlation_factor(d, -1.0, "quadratic")


def test_corrected_entropy_m14():
    """(M14) H' = H_min + (1 - rho)(H - H_min), floored at H_min; d0 = 0 gives max(H, H_min)."""
    h = torch.tensor([2.0, 2.0, -12.0, -5.0])
    d = torch.tensor([0.5, 2.0, 0.5, 0.0])
    got = corrected_entropy(h, d, 1.0, "quadratic")
    want = torch.tensor([H_MIN + 0.25 * (2.0 - H_MIN), 2.0, H_MIN, H_MIN])
    assert torch.allclose(got, want, atol=1e-5)
    assert torch.allclose(corrected_entropy(h, d, 0.0, "quadratic"), h.clamp(min=H_MIN))


def test_equivalent_depth_pixel_and_chunk():
    """(M15) Per pixel: sum w t / (sum w + 1e-10), 0 without samples. chunk (D3): one weighted mean
    per row-major chunk of pixel ids, shared by its rays (including a ray with no samples)."""
    w = torch.tensor([0.5, 0.25, 1.0, 0.2])
    t = torch.tensor([1.0, 2.0, 4.0, 3.0])
    ray_idx = torch.tensor([0, 0, 2, 3])
    pixel = equivalent_depth(w, t, ray_idx, 4)
    assert torch.allclose(pixel, torch.tensor([(0.5 + 0.5) / 0.75, 0.0, 4.0, 3.0]))
    chunk = equivalent_depth(w, t, ray_idx, 4, "chunk", torch.tensor([10, 11, 12, 13]), chunk_rays=2)
    first = (0.5 + 0.5) / 0.75
    second = (4.0 + 0.6) / 1.2
    assert torch.allclose(chunk, torch.tensor([first, first, second, second]))
    with pytest.raises(ValueError, match="pixel_index"):
        equivalent_depth(w, t, ray_idx, 4, "chunk")
