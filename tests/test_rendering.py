"""Packed volume rendering invariants (METHOD.md section 2, M1-M3)."""

import torch

from nvf.rendering import Samples, alpha_from_density, expected_depth, ray_sum, weights_from_alpha


def _uniform_samples(n_rays: int, n: int, t_far: float) -> Samples:
    edges = torch.linspace(0.0, t_far, n + 1)
    return Samples(
        torch.arange(n_rays).repeat_interleave(n),
        edges[:-1].repeat(n_rays),
        edges[1:].repeat(n_rays),
        n_rays,
    )


def _reference_weights(alpha: torch.Tensor, ray_idx: torch.Tensor, n_rays: int) -> tuple[torch.Tensor, torch.Tensor]:
    trans = torch.empty_like(alpha)
    for r in range(n_rays):
        idx = torch.nonzero(ray_idx == r)[:, 0]
        t = 1.0
        for i in idx.tolist():
            trans[i] = t
            t *= 1.0 - float(alpha[i])
    return trans * alpha, trans


def test_weights_match_loop_reference() -> None:
    """M2: segmented exclusive transmittance equals the per-ray product, rays of varying lengths."""
    counts = torch.tensor([3, 0, 5, 1, 0, 7])
    ray_idx = torch.arange(6).repeat_interleave(counts)
    alpha = torch.rand(int(counts.sum()))
    w, trans = weights_from_alpha(alpha, ray_idx, 6)
    w_ref, trans_ref = _reference_weights(alpha, ray_idx, 6)
    torch.testing.assert_close(trans, trans_ref)
    torch.testing.assert_close(w, w_ref)
    assert torch.all(trans[torch.cat([torch.zeros(1, dtype=torch.long), counts.cumsum(0)[:-1]])[counts > 0]] == 1.0)


def test_long_packed_batch_keeps_precision() -> None:
    """M2: many opaque rays before a ray do not degrade its transmittance (no global float32 drift)."""
    n_rays, n = 20000, 20
    ray_idx = torch.arange(n_rays).repeat_interleave(n)
    alpha = torch.full((n_rays * n,), 0.7)
    _, trans = weights_from_alpha(alpha, ray_idx, n_rays)
    expected = 0.3 ** torch.arange(n, dtype=torch.float64)
    torch.testing.assert_close(trans[-n:].double(), expected, rtol=1e-5, atol=1e-12)


def test_opaque_sample_takes_all_remaining_mass() -> None:
    """M2: alpha = 1 gives w = T at that sample and ~0 afterwards, finite values and gradients."""
    alpha = torch.tensor([0.5, 1.0, 0.3, 0.9], requires_grad=True)
    ray_idx = torch.zeros(4, dtype=torch.long)
    w, trans = weights_from_alpha(alpha, ray_idx, 1)
    assert torch.allclose(w[:2], torch.tensor([0.5, 0.5]))
    assert torch.all(w[2:].abs() < 1e-9) and torch.all(trans[2:] < 1e-9)
    w.sum().backward()
    assert torch.isfinite(alpha.grad).all()


def test_constant_colour_and_opaque_slab() -> None:
    """M1-M3: a constant colour comes out scaled by A; a thick dense slab has A ~ 1 and black background."""
    samples = _uniform_samples(4, 64, 4.0)
    sigma = torch.where((samples.t_mid > 1.0) & (samples.t_mid < 3.0), 50.0, 0.0)
    alpha = alpha_from_density(sigma, samples.deltas)
    w, _ = weights_from_alpha(alpha, samples.ray_idx, 4)
    colour = torch.tensor([0.2, 0.5, 0.9])
    rgb = ray_sum(w[:, None] * colour.expand(samples.num_samples, 3), samples.ray_idx, 4)
    acc = ray_sum(w, samples.ray_idx, 4)
    assert torch.allclose(acc, torch.ones(4), atol=1e-5)
    assert torch.allclose(rgb, colour.expand(4, 3), atol=1e-5)
    # Semi-transparent: colour out = A * colour (nothing added for the background).
    w_half, _ = weights_from_alpha(alpha_from_density(sigma * 1e-3, samples.deltas), samples.ray_idx, 4)
    acc_half = ray_sum(w_half, samples.ray_idx, 4)
    assert torch.all(acc_half < 0.2)
    rgb_half = ray_sum(w_half[:, None] * colour.expand(samples.num_samples, 3), samples.ray_idx, 4)
    torch.testing.assert_close(rgb_half, acc_half[:, None] * colour)


def test_expected_depth_of_a_plane() -> None:
    """M3: an opaque plane at t = 2.345 gives D ~ 2.345 (within a sample spacing)."""
    samples = _uniform_samples(3, 1000, 5.0)
    sigma = torch.where(samples.t_end > 2.345, 1e4, 0.0)
    w, _ = weights_from_alpha(alpha_from_density(sigma, samples.deltas), samples.ray_idx, 3)
    depth = expected_depth(w, samples.t_mid, samples.ray_idx, 3)
    assert torch.allclose(depth, torch.full((3,), 2.345), atol=5.0 / 1000)


def test_rays_without_samples_and_empty_batches() -> None:
    """M3: rays with no samples give 0 depth / acc / rgb; S = 0 works; no NaN."""
    ray_idx = torch.tensor([1, 1, 3])
    samples = Samples(ray_idx, torch.tensor([0.0, 1.0, 0.5]), torch.tensor([1.0, 2.0, 1.5]), 5)
    alpha = alpha_from_density(torch.tensor([0.5, 2.0, 1.0]), samples.deltas)
    w, _ = weights_from_alpha(alpha, ray_idx, 5)
    depth = expected_depth(w, samples.t_mid, ray_idx, 5)
    acc = ray_sum(w, ray_idx, 5)
    assert torch.all(depth[[0, 2, 4]] == 0) and torch.all(acc[[0, 2, 4]] == 0)
    assert torch.isfinite(depth).all()
    empty = Samples(torch.zeros(0, dtype=torch.long), torch.zeros(0), torch.zeros(0), 3)
    w0, t0 = weights_from_alpha(torch.zeros(0), empty.ray_idx, 3)
    assert w0.shape == (0,) and t0.shape == (0,)
    assert torch.equal(expected_depth(w0, empty.t_mid, empty.ray_idx, 3), torch.zeros(3))
    assert ray_sum(torch.zeros(0, 3), empty.ray_idx, 3).shape == (3, 3)


def test_select_and_positions_gradients() -> None:
    """Section 1: x = o + t_m d is differentiable in o and d, never in t; select keeps order."""
    samples = _uniform_samples(2, 4, 2.0)
    sub = samples.select(samples.t_mid > 0.6)
    assert sub.n_rays == 2 and sub.num_samples == 6
    assert torch.all(sub.ray_idx[1:] >= sub.ray_idx[:-1])
    origins = torch.zeros(2, 3, requires_grad=True)
    dirs = torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]], requires_grad=True)
    sub.positions(origins, dirs).sum().backward()
    assert torch.allclose(origins.grad, torch.full((2, 3), 3.0))
    assert torch.isfinite(dirs.grad).all() and dirs.grad.abs().sum() > 0
