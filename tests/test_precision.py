"""nvf/precision.py and the low-precision MLP path of nvf/field.py (``train.precision``): the layers run
in bfloat16 / float16 with float32 outputs and float32 parameter gradients, within a stated tolerance of
float32; padded rows add nothing; kept casts follow the parameters; the device support check."""

import pytest
import torch
import torch.nn.functional as F

import nvf.precision as precision
from nvf.field import LOW_PRECISION_ROWS, MLP
from nvf.precision import PRECISIONS, precision_dtype, supported_precisions, unsupported_reason

LOW = [torch.bfloat16, torch.float16]
# A layer in bfloat16 rounds its inputs and weights to 8 significant bits (relative error 2^-9 each); three
# layers of width 64 stay well within 2% of the output scale (float16: 11 bits, tighter still).
RELATIVE_TOLERANCE = 0.02


def reference_forward(mlp: MLP, x: torch.Tensor, dtype: torch.dtype) -> torch.Tensor:
    """The MLP's layers in ``dtype`` on unpadded rows, without the module's blocking or kept casts."""
    linears = [layer for layer in mlp if isinstance(layer, torch.nn.Linear)]
    h = x.to(dtype)
    for i, layer in enumerate(linears):
        h = F.linear(h, layer.weight.to(dtype), None if layer.bias is None else layer.bias.to(dtype))
        h = F.relu(h) if i < len(linears) - 1 else h
    return h.float()


def mlp_and_rows(rows: int = 3000, bias: bool = True) -> tuple[MLP, torch.Tensor]:
    torch.manual_seed(0)
    return MLP([31, 64, 64, 3], bias=bias), torch.randn(rows, 31)


@pytest.mark.parametrize("dtype", LOW)
@pytest.mark.parametrize("grad", [False, True])
def test_low_precision_mlp_is_float32_out_and_within_tolerance(dtype, grad):
    mlp, x = mlp_and_rows()
    with torch.set_grad_enabled(grad):
        exact = mlp(x)
        mlp.train_dtype = mlp.infer_dtype = dtype
        low = mlp(x)
    assert low.dtype == torch.float32 and low.shape == exact.shape
    assert (low - exact).abs().max() <= RELATIVE_TOLERANCE * exact.abs().max()
    scale = float(exact.detach().abs().max())
    assert torch.allclose(low, reference_forward(mlp, x, dtype), rtol=1e-2, atol=1e-3 * scale)


@pytest.mark.parametrize("dtype", LOW)
def test_low_precision_gradients_are_float32_and_padded_rows_add_nothing(dtype):
    """Rows are padded to a multiple of LOW_PRECISION_ROWS on the CPU: the parameters' gradients are those
    of the unpadded rows (float32, like the parameters), and so is the input's."""
    rows = LOW_PRECISION_ROWS + 7
    mlp, x = mlp_and_rows(rows)
    mlp.train_dtype = dtype
    x.requires_grad_()
    mlp(x).square().sum().backward()
    padded = [p.grad.clone() for p in mlp.parameters()]
    x_grad = x.grad.clone()
    mlp.zero_grad()
    x.grad = None
    reference_forward(mlp, x, dtype).square().sum().backward()
    assert x_grad.dtype == torch.float32 and x_grad.shape == (rows, 31)
    assert torch.allclose(x_grad, x.grad, rtol=2e-2, atol=1e-3 * float(x.grad.abs().max()))
    for got, want in zip(padded, (p.grad for p in mlp.parameters()), strict=True):
        assert got.dtype == torch.float32
        assert torch.allclose(got, want, rtol=2e-2, atol=1e-2 * float(want.abs().max()))


def test_parameter_updates_are_seen_at_the_next_call():
    """The cast weights are never stale: a fused Adam step (in place, without bumping the parameters'
    version counters) and load_state_dict are seen by the next no-grad call."""
    mlp, x = mlp_and_rows(500)
    mlp.train_dtype = mlp.infer_dtype = torch.bfloat16
    with torch.no_grad():
        before = mlp(x)
    optimizer = torch.optim.Adam(mlp.parameters(), lr=0.1, fused=True)
    mlp(x).sum().backward()
    optimizer.step()
    with torch.no_grad():
        after = mlp(x)
        assert not torch.equal(before, after)
        assert torch.equal(after, reference_forward(mlp, x, torch.bfloat16))
        mlp.load_state_dict({k: torch.zeros_like(v) for k, v in mlp.state_dict().items()})
        assert torch.equal(mlp(x), torch.zeros(500, 3))


def test_float32_is_unchanged_and_the_context_restores_it():
    """``RadianceField.mlp_precision(train, infer)`` sets every MLP's dtypes inside the block only; calls
    without autograd use ``infer``; float32 runs the original path (bit for bit)."""
    from nvf.config import FieldConfig
    from nvf.field import RadianceField

    torch.manual_seed(0)
    field = RadianceField(torch.tensor([[-1.0] * 3, [1.0] * 3]), FieldConfig(num_levels=4, log2_hashmap_size=10))
    x, d = torch.rand(5000, 3) * 2 - 1, F.normalize(torch.randn(5000, 3), dim=-1)
    heads = frozenset({"rgb", "variance", "visibility"})
    mlps = [m for m in field.modules() if isinstance(m, MLP)]
    with torch.no_grad():
        exact = field(x, d, heads)
        with field.mlp_precision(torch.bfloat16):  # training's: no-grad calls stay float32
            assert all(m.train_dtype == torch.bfloat16 and m.infer_dtype == torch.float32 for m in mlps)
            assert torch.equal(field(x, d, heads).rgb, exact.rgb)
        with field.mlp_precision(torch.float32, infer=torch.bfloat16):
            low = field(x, d, heads)
        again = field(x, d, heads)
    assert all(m.train_dtype == m.infer_dtype == torch.float32 for m in mlps)
    for name in ("sigma", "geo", "rgb", "variance", "visibility"):
        assert torch.equal(getattr(exact, name), getattr(again, name)), name
        assert getattr(low, name).dtype == torch.float32, name  # activations, heads: float32 after the MLPs
    assert torch.allclose(low.rgb, exact.rgb, atol=RELATIVE_TOLERANCE)


def test_precision_names_and_dtypes():
    assert PRECISIONS == ("fp32", "bf16", "fp16")
    assert precision_dtype("bf16") == torch.bfloat16 and precision_dtype("fp32") == torch.float32
    with pytest.raises(ValueError, match="fp32, bf16, fp16"):
        precision_dtype("fp64")


def test_supported_precisions_follow_the_cpu(monkeypatch):
    cpu = torch.device("cpu")
    monkeypatch.setattr(precision, "_cpu_bf16", lambda: True)
    monkeypatch.setattr(precision, "_cpu_fp16", lambda: False)
    assert supported_precisions(cpu) == ("fp32", "bf16")
    assert unsupported_reason("bf16", cpu) is None and unsupported_reason("fp32", cpu) is None
    reason = unsupported_reason("fp16", cpu)
    assert "AVX512_FP16" in reason and reason.endswith("available here: fp32, bf16")
    monkeypatch.setattr(precision, "_cpu_bf16", lambda: False)
    assert supported_precisions(cpu) == ("fp32",)
    assert "AVX512_BF16" in unsupported_reason("bf16", cpu)
    assert supported_precisions(torch.device("meta")) == ("fp32",)
