"""The NVF field (METHOD.md section 3): layer sizes, heads, detachments, clamps and the outside-AABB rule."""

import pytest
import torch

from nvf.config import FieldConfig, FieldKind
from nvf.field import HEADS, INFERENCE_BLOCK, MLP, RadianceField, spherical_harmonics, trunc_exp

AABB = torch.tensor([[-1.0, -2.0, 0.0], [1.0, 2.0, 1.0]])
SMALL = dict(num_levels=4, log2_hashmap_size=12, base_resolution=4, max_resolution=32)
KINDS = {
    "hashgrid": FieldConfig(**SMALL),
    "densegrid": FieldConfig(kind=FieldKind.densegrid, dense_resolution=8, dense_features=8),
}


def _inputs(n: int = 64) -> tuple[torch.Tensor, torch.Tensor]:
    u = torch.rand(n, 3) * 0.98 + 0.01
    return AABB[0] + u * (AABB[1] - AABB[0]), torch.nn.functional.normalize(torch.randn(n, 3), dim=-1)


def _shapes(module: torch.nn.Module) -> list[tuple[int, ...]]:
    return [tuple(p.shape) for p in module.parameters()]


def test_layer_sizes_follow_method_table():
    """METHOD 3 table: 32-64-16, 31-64-64-3 (x2), 3-128-128-32, 47-64-64-1; no biases by default."""
    field = RadianceField(AABB, FieldConfig())
    assert _shapes(field.density_mlp) == [(64, 32), (16, 64)]
    assert _shapes(field.color_head) == [(64, 31), (64, 64), (3, 64)]
    assert _shapes(field.variance_head) == [(64, 31), (64, 64), (3, 64)]
    assert _shapes(field.vis_position) == [(128, 3), (128, 128), (32, 128)]
    assert _shapes(field.vis_head) == [(64, 47), (64, 64), (1, 64)]
    assert field.encoding.out_dim == 32
    biased = RadianceField(AABB, FieldConfig(mlp_bias=True, **SMALL))
    assert (64,) in _shapes(biased.density_mlp)


@pytest.mark.parametrize("kind", KINDS)
def test_heads_shapes_and_only_requested(kind):
    """forward computes exactly the requested heads; both backbones carry all heads."""
    field = RadianceField(AABB, KINDS[kind])
    x, d = _inputs()
    out = field(x, d, HEADS)
    assert out.sigma.shape == (64,) and out.geo.shape == (64, 15)
    assert out.rgb.shape == (64, 3) and out.variance.shape == (64, 3)
    assert out.visibility.shape == (64,) and out.vis_logit.shape == (64,)
    assert ((out.rgb > 0) & (out.rgb < 1)).all() and ((out.visibility >= 0) & (out.visibility <= 1)).all()
    only = field(x, d, frozenset({"variance"}))
    assert only.rgb is None and only.visibility is None and only.variance is not None
    assert field(x, d, frozenset()).rgb is None
    sigma, geo = field.density(x)
    torch.testing.assert_close(sigma, out.sigma)
    with pytest.raises(ValueError):
        field(x, d, frozenset({"depth"}))


def test_outside_aabb_rule_and_clamps():
    """Outside the AABB sigma = 0 and v = 1; sigma >= 0 and q >= 1e-4 everywhere (METHOD 3, 15.4)."""
    field = RadianceField(AABB, FieldConfig(**SMALL))
    with torch.no_grad():
        field.variance_head[-1].weight.fill_(-50.0)  # drives softplus to ~0: the clamp must hold
        field.vis_head[-1].weight.fill_(-5.0)
    x, d = _inputs(40)
    x[:20, 0] = AABB[1, 0] + 0.5  # outside in x
    x[20:25, 2] = AABB[0, 2]  # on the boundary: u = 0 is outside (0,1)
    out = field(x, d, HEADS)
    assert (out.sigma[:25] == 0).all() and (out.visibility[:25] == 1).all()
    assert (out.sigma[25:] > 0).all() and (out.visibility[25:] < 1).all()
    assert (out.variance >= 1e-4).all() and (out.variance == 1e-4).any()
    torch.testing.assert_close(field.normalize(AABB), torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]))


def _grads(field: RadianceField, loss: torch.Tensor) -> dict[str, bool]:
    field.zero_grad(set_to_none=True)
    loss.backward()
    return {
        group: any(p.grad is not None and p.grad.abs().sum() > 0 for p in params)
        for group, params in field.parameter_groups().items()
    }


@pytest.mark.parametrize("kind", KINDS)
def test_gradients_reach_only_their_group(kind):
    """Detachments (METHOD 3, section 10): variance and visibility losses never reach the backbone."""
    field = RadianceField(AABB, KINDS[kind])
    with torch.no_grad():
        field.encoding.table.normal_()
    x, d = _inputs()
    out = field(x, d, HEADS)
    assert _grads(field, out.rgb.sum() + out.sigma.sum()) == {"backbone": True, "variance": False, "visibility": False}
    out = field(x, d, HEADS)
    assert _grads(field, out.variance.sum()) == {"backbone": False, "variance": True, "visibility": False}
    out = field(x, d, HEADS)
    assert _grads(field, out.vis_logit.sum()) == {"backbone": False, "variance": False, "visibility": True}
    assert all(torch.isfinite(p.grad).all() for p in field.parameters() if p.grad is not None)


def test_parameter_groups_partition_parameters():
    """Every parameter belongs to exactly one stage's group."""
    field = RadianceField(AABB, FieldConfig(appearance_embedding=True, **SMALL), num_images=3)
    groups = field.parameter_groups()
    ids = [id(p) for params in groups.values() for p in params]
    assert len(ids) == len(set(ids)) == len(list(field.parameters()))


def test_gradients_wrt_points_for_opt():
    """-OPT (METHOD 14) differentiates the rendered values with respect to sample positions."""
    field = RadianceField(AABB, FieldConfig(**SMALL))
    with torch.no_grad():
        field.encoding.table.normal_()
    x, d = _inputs()
    x.requires_grad_()
    d.requires_grad_()
    out = field(x, d, frozenset({"rgb"}))
    (out.rgb.sum() + out.sigma.sum()).backward()
    assert torch.isfinite(x.grad).all() and x.grad.abs().sum() > 0 and d.grad.abs().sum() > 0


def test_appearance_embedding():
    """D8: colour/variance input 63 with a 32-d per-image embedding; inference uses image 0's."""
    field = RadianceField(AABB, FieldConfig(appearance_embedding=True, **SMALL), num_images=4)
    assert _shapes(field.color_head)[0] == (64, 63) and _shapes(field.variance_head)[0] == (64, 63)
    x, d = _inputs(8)
    default = field(x, d, HEADS)
    image0 = field(x, d, HEADS, image_idx=torch.zeros(8, dtype=torch.int64))
    torch.testing.assert_close(default.rgb, image0.rgb)
    assert not torch.allclose(field(x, d, HEADS, image_idx=torch.full((8,), 2)).rgb, default.rgb)
    with pytest.raises(ValueError):
        RadianceField(AABB, FieldConfig(appearance_embedding=True, **SMALL))


def test_trunc_exp_gradient_is_clamped():
    """trunc_exp: forward exp(x), backward exp(clamp(x, -15, 15)) (METHOD 3)."""
    x = torch.tensor([0.0, 20.0, -20.0], requires_grad=True)
    y = trunc_exp(x)
    torch.testing.assert_close(y, torch.exp(x.detach()))
    y.sum().backward()
    torch.testing.assert_close(x.grad, torch.exp(torch.tensor([0.0, 15.0, -15.0])))


def test_spherical_harmonics_are_orthonormal():
    """SH(d), degrees 0-3: 16 real harmonics, orthonormal over the sphere (Monte Carlo, 4 pi E[Y_i Y_j])."""
    d = torch.nn.functional.normalize(torch.randn(400_000, 3, dtype=torch.float64), dim=-1)
    y = spherical_harmonics(d)
    gram = 4 * torch.pi * (y.T @ y) / d.shape[0]
    torch.testing.assert_close(gram, torch.eye(16, dtype=torch.float64), atol=0.03, rtol=0)


def test_mlp_runs_in_row_blocks_without_autograd_with_the_same_values():
    """Inference runs ``INFERENCE_BLOCK`` rows at a time (cache-resident activations); the rows' values
    equal the one-batch forward that autograd uses."""
    torch.manual_seed(0)
    net = MLP([3, 128, 128, 32], bias=False)
    calls = []
    net[0].register_forward_hook(lambda module, args, out: calls.append(out.shape[0]))
    x = torch.rand(2 * INFERENCE_BLOCK + 7, 3)
    whole = net(x)
    assert calls == [x.shape[0]]
    with torch.no_grad():
        blocked = net(x)
    assert calls[1:] == [INFERENCE_BLOCK, INFERENCE_BLOCK, 7]
    torch.testing.assert_close(blocked, whole.detach(), rtol=1e-5, atol=1e-6)
