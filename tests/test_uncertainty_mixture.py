"""nvf/uncertainty/mixture.py: equivalent occupancy (M7), weights (M8), the ray mixture (M9), the
ablation switches on it (METHOD.md 11) and its log-density (M21)."""

import math
from dataclasses import replace

import pytest
import torch

from nvf.config import EntropyConfig
from nvf.rendering import weights_from_alpha
from nvf.uncertainty import RayMixture, mixture_log_density, ray_mixture
from nvf.uncertainty.mixture import equivalent_alpha

CFG = EntropyConfig()


def random_rays(counts, seed=0):
    """Packed per-sample inputs for rays with ``counts`` samples each (a count may be 0)."""
    g = torch.Generator().manual_seed(seed)
    ray_idx = torch.repeat_interleave(torch.arange(len(counts)), torch.tensor(counts))
    s = ray_idx.numel()
    return dict(
        alpha=torch.rand(s, generator=g),
        rgb_s=torch.rand(s, 3, generator=g),
        variance=1e-4 + torch.rand(s, 3, generator=g) * 0.1,
        visibility=torch.rand(s, generator=g),
        ray_idx=ray_idx,
        n_rays=len(counts),
    )


def build(inputs, cfg=CFG):
    return ray_mixture(
        inputs["alpha"],
        inputs["rgb_s"],
        inputs["variance"],
        inputs["visibility"],
        inputs["ray_idx"],
        inputs["n_rays"],
        cfg,
    )


def per_ray_weight_sum(mix):
    return torch.zeros(mix.n_rays).index_add(0, mix.ray_idx, mix.weights)


def test_equivalent_alpha_m7():
    """(M7) alpha_bar = [v + beta(1-v)] alpha + (1-beta)(1-v) alpha_un; v=1 gives alpha, v=0 the prior mix."""
    alpha = torch.tensor([0.3, 0.3, 0.3, 0.0])
    v = torch.tensor([1.0, 0.0, 0.4, 0.0])
    got = equivalent_alpha(alpha, v, CFG)
    b, a_un = 0.95, 1.0 - math.exp(-0.01)
    want = [0.3, b * 0.3 + (1 - b) * a_un, (0.4 + b * 0.6) * 0.3 + (1 - b) * 0.6 * a_un, (1 - b) * a_un]
    assert torch.allclose(got, torch.tensor(want), atol=1e-7)
    assert torch.equal(equivalent_alpha(alpha, v, replace(CFG, use_visibility=False)), alpha)


def test_ray_mixture_hand_computed():
    """(M8, M9) Two rays by hand, one without samples: reference split, merged unknown, clipped bg."""
    alpha = torch.tensor([0.5, 0.4])
    v = torch.tensor([1.0, 0.25])
    rgb = torch.tensor([[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]])
    q = torch.tensor([[0.01, 0.02, 0.03], [0.04, 0.05, 0.06]])
    mix, eq_w = ray_mixture(alpha, rgb, q, v, torch.tensor([0, 0]), 2, CFG)
    a_bar2 = (0.25 + 0.95 * 0.75) * 0.4 + 0.05 * 0.75 * (1.0 - math.exp(-0.01))
    w = [0.5, 0.5 * a_bar2]
    assert torch.allclose(eq_w, torch.tensor(w), atol=1e-7)
    # layout: seen (2), unknown (ray 0, ray 1), background (ray 0, ray 1)
    want_weights = [w[0] * 1.0, w[1] * 0.25, w[1] * 0.75, 0.0, 1.0 - w[0] - w[1], 1.0]
    assert torch.allclose(mix.weights, torch.tensor(want_weights), atol=1e-7)
    assert mix.ray_idx.tolist() == [0, 0, 0, 1, 0, 1]
    assert torch.equal(mix.means[:2], rgb) and torch.equal(mix.variances[:2], q)
    assert torch.allclose(mix.means[2:4], torch.full((2, 3), 0.5))
    assert torch.allclose(mix.variances[2:4], torch.full((2, 3), 1.0))
    assert torch.equal(mix.means[4:], torch.zeros(2, 3))
    assert torch.allclose(mix.variances[4:], torch.full((2, 3), 1e-4))


def test_weights_sum_to_one_and_match_rendering_weights():
    """(M8, M9) Per-ray weights sum to 1; w_bar equals the M2 weights of alpha_bar."""
    inputs = random_rays([5, 0, 1, 30, 2])
    mix, eq_w = build(inputs)
    assert torch.allclose(per_ray_weight_sum(mix), torch.ones(5), atol=1e-6)
    alpha_bar = equivalent_alpha(inputs["alpha"], inputs["visibility"], CFG)
    want, _ = weights_from_alpha(alpha_bar, inputs["ray_idx"], 5)
    assert torch.allclose(eq_w, want, atol=1e-6)
    assert (mix.weights >= 0).all()


def test_opaque_samples_are_finite():
    """METHOD 15.4: alpha_bar = 1 needs no -ln(1 - alpha_bar) round trip: no inf/NaN, later weights 0."""
    ones = torch.ones(3)
    mix, eq_w = ray_mixture(ones, torch.rand(3, 3), torch.full((3, 3), 0.01), ones, torch.tensor([0, 0, 0]), 1, CFG)
    assert torch.isfinite(mix.weights).all() and torch.isfinite(eq_w).all()
    assert eq_w[0] == 1.0 and (eq_w[1:] < 1e-6).all()
    assert mix.weights[-1] == 0.0  # pi_bg


def test_without_visibility_switch():
    """(METHOD 11, w/o Vis.) v = 1: alpha_bar = alpha, pi_un = 0, seen weights = the M2 weights;
    means and variances unchanged; the visibility head is not needed."""
    inputs = random_rays([4, 0, 7])
    cfg = replace(CFG, use_visibility=False)
    mix, eq_w = build(inputs, cfg)
    want, _ = weights_from_alpha(inputs["alpha"], inputs["ray_idx"], 3)
    s = inputs["alpha"].numel()
    assert torch.allclose(eq_w, want, atol=1e-6)
    assert torch.equal(mix.weights[:s], eq_w)
    assert torch.equal(mix.weights[s : s + 3], torch.zeros(3))
    full, _ = build(dict(inputs, visibility=torch.ones(s)))  # = the default config with v = 1
    for field in ("weights", "means", "variances", "ray_idx"):
        assert torch.allclose(getattr(mix, field), getattr(full, field), atol=1e-7), field
    no_head, _ = build(dict(inputs, visibility=None), cfg)
    assert torch.equal(no_head.weights, mix.weights)


def test_without_variance_switch():
    """(METHOD 11, w/o Var.) q = var_bg for the seen components only; nothing else changes."""
    inputs = random_rays([4, 0, 7])
    s = inputs["alpha"].numel()
    base, base_w = build(inputs)
    mix, eq_w = build(inputs, replace(CFG, use_variance=False))
    assert torch.equal(eq_w, base_w)
    assert torch.equal(mix.weights, base.weights) and torch.equal(mix.means, base.means)
    assert torch.equal(mix.variances[:s], torch.full((s, 3), 1e-4))
    assert torch.equal(mix.variances[s:], base.variances[s:])
    no_head, _ = build(dict(inputs, variance=None), replace(CFG, use_variance=False))
    assert torch.equal(no_head.variances, mix.variances)


def test_missing_heads_raise():
    inputs = random_rays([2])
    with pytest.raises(ValueError, match="visibility"):
        build(dict(inputs, visibility=None))
    with pytest.raises(ValueError, match="variance"):
        build(dict(inputs, variance=None))


def test_padded_layout():
    """(M9) The padded view keeps each ray's components in packed order; padding has weight 0."""
    inputs = random_rays([3, 0, 1])
    mix, _ = build(inputs)
    w, mu, q = mix.padded()
    assert w.shape == (3, 5) and mu.shape == (3, 5, 3) and q.shape == (3, 5, 3)
    for r in range(3):
        mine = mix.ray_idx == r
        n = int(mine.sum())
        assert torch.equal(w[r, :n], mix.weights[mine]) and torch.equal(q[r, :n], mix.variances[mine])
        assert torch.equal(mu[r, :n], mix.means[mine])
        assert (w[r, n:] == 0).all() and (q[r, n:] == 1).all()


def reference_log_density(mix, z):
    """ln p_r by torch.distributions in float64, variances clamped to 1e-4 (M21)."""
    out = []
    for r in range(mix.n_rays):
        mine = mix.ray_idx == r
        comps = torch.distributions.Independent(
            torch.distributions.Normal(mix.means[mine].double(), mix.variances[mine].double().clamp(min=1e-4).sqrt()), 1
        )
        log_terms = comps.log_prob(z[r].double()) + mix.weights[mine].double().log()
        out.append(torch.logsumexp(log_terms, 0))
    return torch.stack(out)


def test_log_density_matches_direct_computation():
    """(M21) log-sum-exp of ln pi + ln N in float64, q clamped >= 1e-4, also where fp32 p underflows."""
    inputs = random_rays([3, 0, 2, 6])
    inputs["variance"][0] = 1e-6  # below the clamp
    mix, _ = build(inputs)
    z = torch.rand(4, 3)
    z[1] = torch.tensor([5.0, -4.0, 3.0])  # ray 1 is all background (q = 1e-4): p underflows in fp32
    got = mixture_log_density(mix, z)
    assert torch.isfinite(got).all() and got[1] < -1e5
    assert torch.allclose(got.double(), reference_log_density(mix, z), rtol=1e-5, atol=1e-5)


def test_log_density_zero_mixture_is_minus_inf_with_zero_gradient():
    """(M21) p_r = 0 gives -inf (so the ray can be left out of the mean), and never NaN gradients."""
    weights = torch.tensor([0.0, 0.0, 0.3, 0.7], requires_grad=True)
    variances = torch.full((4, 3), 0.01, requires_grad=True)
    mix = RayMixture(weights, torch.rand(4, 3), variances, torch.tensor([0, 0, 1, 1]), 2)
    log_p = mixture_log_density(mix, torch.rand(2, 3))
    assert log_p[0] == -math.inf and torch.isfinite(log_p[1])
    log_p[torch.isfinite(log_p)].sum().backward()
    assert torch.isfinite(weights.grad).all() and torch.isfinite(variances.grad).all()
    assert (weights.grad[:2] == 0).all()


def test_mixture_gradients_finite():
    """Differentiable in every per-sample input, including opaque and fully unseen samples."""
    inputs = random_rays([4, 0, 3])
    inputs["alpha"][0] = 1.0
    inputs["visibility"][1] = 0.0
    leaves = {k: inputs[k].clone().requires_grad_() for k in ("alpha", "rgb_s", "variance", "visibility")}
    mix, eq_w = build(dict(inputs, **leaves))
    (
        mixture_log_density(mix, torch.rand(3, 3)).sum() + eq_w.sum() + (mix.weights * mix.variances.sum(-1)).sum()
    ).backward()
    for name, leaf in leaves.items():
        assert leaf.grad is not None and torch.isfinite(leaf.grad).all(), name
