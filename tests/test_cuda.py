"""Each numeric kernel on CUDA against its CPU result (``-m cuda``; skipped where torch sees no CUDA device).

Inputs are drawn on the CPU and copied, so both devices compute from the same numbers. Everything is
float32 and differs only by rounding: fused multiply-adds, another order of a reduction, atomic adds in
scatters (``index_add_``). Tolerances: elementwise kernels ``rtol 1e-5``; reductions, scatters and
gradients ``rtol 1e-4``; a whole render (marching, field MLPs, compositing) ``atol 1e-4``. The marched
samples must be the same samples (a midpoint that rounds across a cell boundary would change them).
"""

import math

import pytest
import torch

from nvf.cameras import Intrinsics, look_at, matrix_to_pose, pixel_rays
from nvf.config import EntropyConfig, FieldConfig, HashBackend, SamplerConfig, TrainConfig
from nvf.density_lattice import DensityLattice
from nvf.device import resolve_device
from nvf.encoding import HashEncoding, cpp_extension
from nvf.model import SceneModel
from nvf.planning import score_poses, score_poses_together
from nvf.rendering import alpha_from_density, expected_depth, ray_sum, weights_from_alpha
from nvf.uncertainty.entropy import upper_bound_and_depth
from nvf.uncertainty.fisher import colour_parameters, exact_fisher_diagonal, probe_fisher_diagonal, rademacher
from nvf.uncertainty.nvf_entropy import NVFEntropyScorer
from nvf.visibility import visibility_labels

pytestmark = [
    pytest.mark.cuda,
    pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device: torch.cuda.is_available() is False"),
]
CPU = torch.device("cpu")
AABB = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
SMALL_FIELD = FieldConfig(num_levels=8, log2_hashmap_size=14, max_resolution=128, backend=HashBackend.torch)
SMALL_GRID = SamplerConfig(grid_resolution=32, warmup_iters=8)


def cuda() -> torch.device:
    device = resolve_device("auto")
    assert device.type == "cuda", "device=auto picks CUDA where torch sees it"
    return device


def on(device: torch.device, *tensors: torch.Tensor) -> list[torch.Tensor]:
    return [t.to(device) for t in tensors]


def encode(enc: HashEncoding, u: torch.Tensor, grad_out: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """Output, table gradient and point gradient of ``enc`` at ``u``."""
    u = u.clone().requires_grad_(True)
    out = enc(u)
    table_grad, u_grad = torch.autograd.grad(out, [enc.table, u], grad_out)
    return out.detach(), table_grad, u_grad


@pytest.mark.parametrize("cpu_backend", ["torch", "cpp"])
def test_hash_encoding_matches_the_cpu(cpu_backend):
    """METHOD 3 on CUDA (the torch backend, the one CUDA has) against the CPU's torch and C++ backends."""
    if cpu_backend == "cpp" and cpp_extension() is None:
        pytest.skip("the C++ hash-grid kernel did not build here")
    generator = torch.Generator().manual_seed(1)
    u = torch.rand(4096, 3, generator=generator) * 0.9 + 0.05
    grad_out = torch.randn(4096, 16, generator=generator)
    enc = HashEncoding(8, 2, 14, 16, 128, backend=cpu_backend)
    expected = encode(enc, u, grad_out)
    enc.backend = "torch"
    got = encode(enc.to(cuda()), *on(cuda(), u, grad_out))
    for name, want, have in zip(("output", "table gradient", "point gradient"), expected, got, strict=True):
        torch.testing.assert_close(have.cpu(), want, rtol=1e-4, atol=1e-6, msg=lambda m, n=name: f"{n}: {m}")


def trained_like_model(device: torch.device) -> SceneModel:
    """A small model with a non-trivial density (a ball) and an occupancy grid updated on the CPU, moved to
    ``device``: both devices then hold the same weights and the same occupied cells."""
    torch.manual_seed(3)
    model = SceneModel(AABB, SMALL_FIELD, SMALL_GRID)
    with torch.no_grad():
        model.field.encoding.table.normal_(0.0, 0.5)
    generator = torch.Generator().manual_seed(4)
    model.update_grid(0, generator)
    return model.to(device)


def rays(n: int = 64) -> tuple[torch.Tensor, torch.Tensor]:
    """Pixel rays of an ``n x n`` view of the AABB from outside it."""
    c2w = look_at(torch.tensor([2.5, 1.5, 1.0]), torch.zeros(3))
    return pixel_rays(c2w, Intrinsics.from_fov(n, n))


def test_marching_gives_the_same_samples():
    """M6: the same occupied cells and rays march the same packed samples on CUDA."""
    cpu_model, cuda_model = trained_like_model(CPU), trained_like_model(cuda())
    assert 0 < int(cpu_model.grid.occupied.sum()) < cpu_model.grid.occupied.numel()
    origins, dirs = rays()
    expected = cpu_model.grid.march(origins, dirs, jitter=False)
    got = cuda_model.grid.march(*on(cuda(), origins, dirs), jitter=False)
    assert expected.num_samples > 0
    torch.testing.assert_close(got.ray_idx.cpu(), expected.ray_idx, rtol=0, atol=0)
    torch.testing.assert_close(got.t_start.cpu(), expected.t_start, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(got.t_end.cpu(), expected.t_end, rtol=1e-5, atol=1e-6)


def test_compositing_matches_the_cpu():
    """M1-M3 on random packed samples: alpha, weights, transmittance, colour sums and expected depth."""
    generator = torch.Generator().manual_seed(5)
    n_rays, per_ray = 512, 96
    ray_idx = torch.arange(n_rays).repeat_interleave(per_ray)
    sigma = torch.rand(n_rays * per_ray, generator=generator) * 20.0
    deltas = torch.rand(n_rays * per_ray, generator=generator) * 0.02
    t_mid = torch.cumsum(deltas.view(n_rays, per_ray), -1).view(-1) + 1.0
    rgb = torch.rand(n_rays * per_ray, 3, generator=generator)

    def composite(sigma, deltas, t_mid, rgb, ray_idx):
        alpha = alpha_from_density(sigma, deltas)
        weights, trans = weights_from_alpha(alpha, ray_idx, n_rays)
        colour = ray_sum(weights[:, None] * rgb, ray_idx, n_rays)
        return alpha, weights, trans, colour, expected_depth(weights, t_mid, ray_idx, n_rays)

    expected = composite(sigma, deltas, t_mid, rgb, ray_idx)
    got = composite(*on(cuda(), sigma, deltas, t_mid, rgb, ray_idx))
    for want, have in zip(expected, got, strict=True):
        torch.testing.assert_close(have.cpu(), want, rtol=1e-4, atol=1e-6)


def test_whole_render_matches_the_cpu():
    """``SceneModel.render`` (marching, skipping, field, compositing) with every head, deterministic."""
    heads = frozenset({"rgb", "variance", "visibility"})
    origins, dirs = rays()
    expected = trained_like_model(CPU).render(origins, dirs, heads=heads)
    got = trained_like_model(cuda()).render(*on(cuda(), origins, dirs), heads=heads)
    assert expected.samples.num_samples == got.samples.num_samples > 0
    for key in ("rgb", "depth", "acc", "variance", "visibility"):
        torch.testing.assert_close(getattr(got, key).cpu(), getattr(expected, key), rtol=1e-4, atol=1e-4)


def test_entropy_bound_matches_the_cpu():
    """M9, M10, M15: the bound and the per-pixel depth from the same packed weights."""
    generator = torch.Generator().manual_seed(6)
    n_rays, per_ray = 256, 64
    ray_idx = torch.arange(n_rays).repeat_interleave(per_ray)
    weights = torch.rand(n_rays * per_ray, generator=generator) / per_ray
    visibility = torch.rand(n_rays * per_ray, generator=generator)
    variance = torch.rand(n_rays * per_ray, 3, generator=generator) * 0.1 + 1e-4
    t_mid = torch.rand(n_rays * per_ray, generator=generator) * 4.0
    cfg = EntropyConfig()
    expected = upper_bound_and_depth(weights, visibility, variance, t_mid, ray_idx, n_rays, cfg)
    got = upper_bound_and_depth(*on(cuda(), weights, visibility, variance, t_mid, ray_idx), n_rays, cfg)
    for want, have in zip(expected, got, strict=True):
        torch.testing.assert_close(have.cpu(), want, rtol=1e-4, atol=1e-5)


def test_fisher_probes_match_the_cpu():
    """M30 and M31 (FisherRF's probes, the same signs on both devices) on the same model and rays."""
    origins, dirs = rays(16)
    signs = rademacher(2, origins.shape[0], torch.Generator().manual_seed(7))
    probe, exact = [], []  # the CPU's, then CUDA's
    for device in (CPU, cuda()):
        model = trained_like_model(device)
        o, d, s = on(device, origins, dirs, signs)
        params = colour_parameters(model)
        probe.append(probe_fisher_diagonal(model, params, o, d, s, chunk_rays=128).cpu())
        centre = slice(8 * 16 + 4, 8 * 16 + 12)  # eight rays of the middle row, through the ball
        exact.append(exact_fisher_diagonal(model, params, o[centre], d[centre]).cpu())
    assert probe[0].sum() > 0 and exact[0].sum() > 0
    torch.testing.assert_close(probe[1], probe[0], rtol=1e-3, atol=1e-9)
    torch.testing.assert_close(exact[1], exact[0], rtol=1e-3, atol=1e-9)
    draws = rademacher(4, 1000, torch.Generator(device=cuda()).manual_seed(8))
    assert draws.device.type == "cuda" and set(draws.unique().tolist()) == {-1.0, 1.0}
    assert math.isclose(float(draws.mean()), 0.0, abs_tol=0.05)


def test_visibility_labels_inside_the_density_support_match_the_cpu():
    """M17-M18 with the density support (the occupied cells' box and cells): CUDA's torch path labels the same
    points as the CPU's C++ kernel, within rounding."""
    generator = torch.Generator().manual_seed(9)
    points = torch.rand(3000, 3, generator=generator) * 2.0 - 1.0
    cams = torch.stack([look_at(torch.tensor(p), torch.zeros(3)) for p in ([0.2, -2.5, 0.4], [2.5, 0.3, 0.0])])
    intr = Intrinsics.from_fov(32, 32)
    cfg = TrainConfig(label_samples=64)
    found = []
    for device in (CPU, cuda()):
        model = trained_like_model(device)
        support = model.density_support()
        x, c2w = on(device, points, cams)

        def density(y: torch.Tensor, model: SceneModel = model) -> torch.Tensor:  # dense enough to occlude
            return 50.0 * model.density(y)

        labels = visibility_labels(density, x, c2w, intr, cfg, aabb=support.box, grid=support.grid)
        found.append(labels.cpu())
    assert 0 < int((found[0] > 0.5).sum()) < points.shape[0]
    torch.testing.assert_close(found[1], found[0], rtol=1e-4, atol=1e-5)


def test_density_lattice_labels_match_the_cpu_kernel():
    """M17's density lattice (``train.label_lattice``): CUDA builds the same lattice from the same model and reads
    it through ``grid_sample``; its labels are the CPU kernel's one-pass sums', within rounding."""
    generator = torch.Generator().manual_seed(9)
    points = torch.rand(3000, 3, generator=generator) * 2.0 - 1.0
    cams = torch.stack([look_at(torch.tensor(p), torch.zeros(3)) for p in ([0.2, -2.5, 0.4], [2.5, 0.3, 0.0])])
    intr, cfg = Intrinsics.from_fov(32, 32), TrainConfig(label_samples=64)
    found = []
    for device in (CPU, cuda()):
        model = trained_like_model(device)
        support, (x, c2w) = model.density_support(), on(device, points, cams)
        dense = model.label_density(2)  # the model's own lattice, then ten times denser to occlude
        assert isinstance(dense, DensityLattice)
        lattice = DensityLattice(lambda y, m=model: 50.0 * m.field.density(y)[0], model.grid, 2, model.grid.occupied)
        torch.testing.assert_close(lattice.values, 50.0 * dense.values, rtol=1e-5, atol=1e-5)
        labels = visibility_labels(lattice, x, c2w, intr, cfg, aabb=support.box, grid=support.grid)
        found.append(labels.cpu())
    assert 0 < int((found[0] > 0.5).sum()) < points.shape[0]
    torch.testing.assert_close(found[1], found[0], rtol=1e-4, atol=1e-4)


def test_scorers_scored_together_match_their_own_renders():
    """M16: NVF's and w/o Vis.'s rewards from one render on CUDA equal each scorer's own render there, within
    the rounding of CUDA's atomic segment sums, and the CPU's."""
    model = trained_like_model(cuda())
    scorers = [NVFEntropyScorer(EntropyConfig(), 1.0), NVFEntropyScorer(EntropyConfig(use_visibility=False), 1.0)]
    poses = torch.stack([matrix_to_pose(look_at(torch.tensor([2.5, y, 0.5]), torch.zeros(3))) for y in (-1.0, 1.0)])
    intr = Intrinsics.from_fov(16, 16)
    together = score_poses_together(model, scorers, poses.to(cuda()), intr, 128)
    cpu = score_poses_together(trained_like_model(CPU), scorers, poses, intr, 128)
    for scorer, scores, on_cpu in zip(scorers, together, cpu, strict=True):
        alone = score_poses(model, scorer, poses.to(cuda()), intr, 128)
        torch.testing.assert_close(scores, alone, rtol=1e-6, atol=1e-9)
        torch.testing.assert_close(scores.cpu(), on_cpu, rtol=1e-4, atol=1e-6)
