"""SceneModel rendering: sampling, alpha skipping / early stop and M1-M3 composites (METHOD.md sections 2, 4)."""

from dataclasses import dataclass

import pytest
import torch
from torch import Tensor, nn

from nvf.cameras import Intrinsics, look_at, pixel_rays
from nvf.config import FieldConfig, HashBackend, SamplerConfig
from nvf.model import SceneModel

AABB = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
RADIUS = 0.5
COLOUR = torch.tensor([0.2, 0.5, 0.9])


@dataclass
class _Output:
    sigma: Tensor
    geo: Tensor
    rgb: Tensor | None = None
    variance: Tensor | None = None
    visibility: Tensor | None = None
    vis_logit: Tensor | None = None


class SphereField(nn.Module):
    """Analytic stand-in with RadianceField's API: a smooth opaque sphere of constant colour."""

    def density(self, x: Tensor) -> tuple[Tensor, Tensor]:
        sigma = 500.0 * torch.sigmoid((RADIUS - x.norm(dim=-1)) * 200.0)
        inside = (x.abs() < 1.0).all(-1)
        return torch.where(inside, sigma, 0.0), torch.zeros(x.shape[0], 15, device=x.device)

    def density_and_encoding(self, x: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        return *self.density(x), torch.zeros(x.shape[0], 0, device=x.device)

    def forward(
        self,
        x: Tensor,
        d: Tensor,
        heads: frozenset[str],
        image_idx: Tensor | None = None,
        density: _Output | None = None,
        encoded: Tensor | None = None,
    ) -> _Output:
        sigma, geo = self.density(x) if density is None else (density.sigma, density.geo)
        n = x.shape[0]
        return _Output(
            sigma,
            geo,
            rgb=COLOUR.expand(n, 3) if "rgb" in heads else None,
            variance=torch.full((n, 3), 0.01) if "variance" in heads else None,
            visibility=torch.full((n,), 0.7) if "visibility" in heads else None,
        )


def small_configs() -> tuple[FieldConfig, SamplerConfig]:
    field_cfg = FieldConfig(num_levels=4, log2_hashmap_size=12, max_resolution=64, hidden_dim=16)
    return field_cfg, SamplerConfig(grid_resolution=32)


def sphere_model() -> SceneModel:
    model = SceneModel(AABB, *small_configs())
    model.field = SphereField()
    model.update_grid(0, torch.Generator().manual_seed(0))
    return model


def front_rays() -> tuple[Tensor, Tensor]:
    """Rays from z = 3 along -z at lateral offsets 0, 0.3 (both hit at z = sqrt(r^2 - x^2)) and 0.8 (miss)."""
    xs = torch.tensor([0.0, 0.3, 0.8])
    origins = torch.stack([xs, torch.zeros(3), torch.full((3,), 3.0)], dim=-1)
    return origins, torch.tensor([[0.0, 0.0, -1.0]]).expand(3, 3).contiguous()


def test_render_sphere_colour_depth_and_misses() -> None:
    """M3: constant colour in gives it out with A ~ 1; depth matches the analytic sphere; misses give zeros."""
    model = sphere_model()
    origins, dirs = front_rays()
    result = model.render(origins, dirs)
    depth_true = 3.0 - torch.sqrt(RADIUS**2 - origins[:2, 0] ** 2)
    torch.testing.assert_close(result.acc[:2], torch.ones(2), atol=1e-3, rtol=0)
    torch.testing.assert_close(result.rgb[:2], COLOUR.expand(2, 3), atol=1e-3, rtol=0)
    torch.testing.assert_close(result.depth[:2], depth_true, atol=0.02, rtol=0)
    assert result.acc[2] == 0 and result.depth[2] == 0 and torch.all(result.rgb[2] == 0)
    assert torch.isfinite(result.depth).all() and torch.isfinite(result.rgb).all()


def test_alpha_skipping_and_early_stop() -> None:
    """Section 4: kept samples have alpha >= min(0.01, mean occ) and T >= 1e-4; opaque rays stop early."""
    model = sphere_model()
    origins, dirs = front_rays()
    result = model.render(origins, dirs)
    cfg = model.sampler_cfg
    assert torch.all(result.alpha >= min(cfg.alpha_threshold, model.grid.mean_occupancy))
    assert torch.all(result.trans >= cfg.early_stop_eps)
    marched = model.grid.march(origins, dirs, jitter=False)
    assert result.samples.num_samples < marched.num_samples
    assert result.rgb_s is not None and result.variance is None and result.visibility is None


def test_deterministic_inference_jittered_training() -> None:
    """Section 4 / pitfall 1: inference renders are deterministic; train=True jitters the march."""
    model = sphere_model()
    origins, dirs = front_rays()
    a, b = model.render(origins, dirs), model.render(origins, dirs)
    assert torch.equal(a.depth, b.depth) and torch.equal(a.samples.t_start, b.samples.t_start)
    c = model.render(origins, dirs, train=True, generator=torch.Generator().manual_seed(1))
    assert not torch.equal(a.samples.t_start, c.samples.t_start)


def test_gradients_flow_into_origins_and_dirs() -> None:
    """-OPT (section 14): x = o + t_m d; depth and colour are differentiable in o and d, never via t."""
    model = sphere_model()
    origins, dirs = front_rays()
    origins = origins.clone().requires_grad_(True)
    dirs = dirs.clone().requires_grad_(True)
    result = model.render(origins, dirs, heads=frozenset({"rgb", "variance", "visibility"}))
    assert not result.samples.t_start.requires_grad
    (result.depth.sum() + result.acc.sum()).backward()
    assert torch.isfinite(origins.grad).all() and torch.isfinite(dirs.grad).all()
    assert origins.grad[:2].abs().sum() > 0
    assert result.variance is not None and result.visibility is not None


def test_uniform_sampler() -> None:
    """Section 4 (uniform alternative): 50 stratified samples per ray on [0, 10], fixed midpoints at inference."""
    model = sphere_model()
    origins, dirs = front_rays()
    result = model.render(origins, dirs, sampler="uniform")
    s = result.samples
    assert torch.equal(torch.bincount(s.ray_idx, minlength=3), torch.full((3,), 50))
    torch.testing.assert_close(s.t_mid[:50], (torch.arange(50) + 0.5) * 0.2)
    gen = torch.Generator().manual_seed(0)
    jittered = model.render(origins, dirs, sampler="uniform", train=True, generator=gen).samples
    assert torch.all(jittered.t_start >= 0) and torch.all(jittered.t_end <= 10.0) and torch.all(jittered.deltas >= 0)
    assert not torch.equal(jittered.t_start, s.t_start)
    with pytest.raises(ValueError):
        model.render(origins, dirs, sampler="bogus")


def test_render_image_matches_render() -> None:
    """render_image: chunked, row-major [H,W] maps equal to rendering the pixel rays at once."""
    model = sphere_model()
    intr = Intrinsics.from_fov(12, 10, 60.0)
    c2w = look_at(torch.tensor([0.0, -3.0, 0.5]), torch.zeros(3))
    image = model.render_image(c2w, intr, chunk=37)
    assert image["rgb"].shape == (10, 12, 3) and image["depth"].shape == (10, 12) and image["acc"].shape == (10, 12)
    origins, dirs = pixel_rays(c2w, intr)
    direct = model.render(origins, dirs)
    torch.testing.assert_close(image["depth"].reshape(-1), direct.depth)
    assert image["acc"][5, 6] > 0.99 and image["acc"][0, 0] == 0


def test_empty_grid_renders_black() -> None:
    """Pitfall 5: a model whose grid has no occupied cell renders zeros without NaN."""
    model = SceneModel(AABB, *small_configs())
    model.field = SphereField()
    origins, dirs = front_rays()
    result = model.render(origins, dirs)
    assert result.samples.num_samples == 0
    assert torch.all(result.rgb == 0) and torch.all(result.depth == 0) and torch.all(result.acc == 0)


def test_real_radiance_field() -> None:
    """The real RadianceField through update_grid (M5) and render (M1-M3): finite outputs, gradients into the rays."""
    field_cfg, _ = small_configs()
    model = SceneModel(AABB, field_cfg, SamplerConfig(grid_resolution=16))
    origins, dirs = front_rays()
    assert torch.all(model.render(origins, dirs).acc == 0)  # empty grid before the first update
    model.update_grid(0, torch.Generator().manual_seed(0))
    assert model.grid.occupied.any()
    origins = origins.clone().requires_grad_(True)
    heads = frozenset({"rgb", "variance", "visibility"})
    result = model.render(origins, dirs, heads=heads, train=True, generator=torch.Generator().manual_seed(0))
    assert result.samples.num_samples > 0
    assert torch.isfinite(result.rgb).all() and torch.isfinite(result.depth).all()
    result.rgb.sum().backward()
    assert torch.isfinite(origins.grad).all()


def test_inference_reuses_the_skipping_density() -> None:
    """Under no_grad the kept samples' density comes from the skipping pass (section 4): every
    output equals a render with autograd on (a second field evaluation)."""
    field_cfg, _ = small_configs()
    model = SceneModel(AABB, field_cfg, SamplerConfig(grid_resolution=16))
    model.update_grid(0, torch.Generator().manual_seed(0))
    origins, dirs = front_rays()
    heads = frozenset({"rgb", "variance", "visibility"})
    with torch.no_grad():
        reused = model.render(origins, dirs, heads=heads)
    evaluated = model.render(origins, dirs, heads=heads)
    assert reused.samples.num_samples > 0 and evaluated.sigma.requires_grad and not reused.sigma.requires_grad
    for key in ("sigma", "rgb_s", "variance", "visibility", "rgb", "depth", "acc"):
        torch.testing.assert_close(getattr(reused, key), getattr(evaluated, key).detach(), rtol=1e-5, atol=1e-6)


def test_training_render_reuses_the_skipping_encoding(monkeypatch) -> None:
    """With autograd the kept samples' encoding comes from the skipping pass: the encoding runs once
    without a known output (the skipping pass) and once with it (the training forward)."""
    field_cfg, _ = small_configs()
    model = SceneModel(AABB, field_cfg, SamplerConfig(grid_resolution=16))
    model.update_grid(0, torch.Generator().manual_seed(0))
    calls = []
    encode = model.field.encoding.forward
    monkeypatch.setattr(
        model.field.encoding, "forward", lambda u, known=None: calls.append(known is not None) or encode(u, known)
    )
    result = model.render(*front_rays(), train=True, generator=torch.Generator().manual_seed(0))
    assert result.samples.num_samples > 0 and calls == [False, True]
    result.rgb.sum().backward()
    assert model.field.encoding.table.grad.abs().sum() > 0


def test_density_reads_zero_in_empty_grid_cells():
    """Labels and filters see the density the renderer sees: 0 in cells the grid marks empty."""
    from nvf.config import FieldConfig, SamplerConfig
    from nvf.model import SceneModel

    aabb = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    field_cfg = FieldConfig(
        num_levels=2, log2_hashmap_size=10, max_resolution=32, hidden_dim=16, backend=HashBackend.torch
    )
    model = SceneModel(aabb, field_cfg, SamplerConfig(grid_resolution=8))
    x = torch.tensor([[0.1, 0.1, 0.1], [-0.9, 0.5, 0.3], [2.0, 0.0, 0.0]])
    raw = model.field.density(x)[0]
    assert (raw[:2] > 0).all()
    assert torch.equal(model.density(x), torch.zeros(3))  # empty grid: nothing rendered, nothing occludes
    model.grid.occupied[:] = True
    assert torch.equal(model.density(x)[:2], raw[:2]) and model.density(x)[2] == 0  # outside the AABB: 0
    model.grid.occupied[:] = False
    cell = torch.floor((x[0] - aabb[0]) / model.grid.cell_size).long()
    model.grid.occupied[(cell[0] * 8 + cell[1]) * 8 + cell[2]] = True  # only the first point's cell
    assert torch.allclose(model.density(x), torch.stack([raw[0], torch.tensor(0.0), torch.tensor(0.0)]))
    model.sampler_cfg.mask_density_with_grid = False
    model.grid.occupied[:] = False
    assert torch.equal(model.density(x)[:2], raw[:2])


def test_observed_density_reads_zero_in_unobserved_cells():
    """M29 deviation (``planner.los_unobserved_free``): the rendered density, 0 where no training
    sample was kept."""
    from nvf.config import FieldConfig, SamplerConfig
    from nvf.model import SceneModel

    aabb = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    field_cfg = FieldConfig(
        num_levels=2, log2_hashmap_size=10, max_resolution=32, hidden_dim=16, backend=HashBackend.torch
    )
    model = SceneModel(aabb, field_cfg, SamplerConfig(grid_resolution=8))
    model.grid.occupied[:] = True
    x = torch.tensor([[0.1, 0.1, 0.1], [-0.9, 0.5, 0.3], [2.0, 0.0, 0.0]])
    rendered = model.density(x)
    assert (rendered[:2] > 0).all()
    assert torch.equal(model.observed_density(x), torch.zeros(3))
    model.grid.mark_observed(x[:1])
    assert torch.equal(model.observed_density(x), torch.stack([rendered[0], torch.tensor(0.0), torch.tensor(0.0)]))
    model.grid.occupied[:] = False  # observed but empty: still the rendered density, 0
    assert torch.equal(model.observed_density(x), torch.zeros(3))
