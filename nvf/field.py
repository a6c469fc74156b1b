"""The NVF field: hash-grid (or dense-grid) NeRF with colour-variance and visibility heads (METHOD section 3).

``u = normalize(x)`` in ``[0,1]^3`` by the object AABB -> encoding -> density MLP ``-> 64 -> 16``
(``sigma = trunc_exp(h_0)``, geometry feature ``g = h_1..15``). Colour ``mu = sigmoid(MLP[SH(d), g])``;
variance ``q = max(softplus(MLP[SH(d), g].detach()), 1e-4)``; visibility
``v = sigmoid(MLP[g.detach(), P(u.detach())])`` with a position MLP ``P: 3 -> 128 -> 128 -> 32`` on the
raw point. ReLU hidden activations, no biases by default (tiny-cuda-nn). Outside the AABB (any
coordinate of ``u`` outside ``(0,1)``) ``sigma = 0`` and ``v = 1``. The detachments make stage 2
train only the variance head and stage 3 only the visibility head (METHOD section 10).
"""

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from jaxtyping import Bool, Float, Int
from torch import Tensor, nn

from nvf.config import FieldConfig
from nvf.densegrid import DenseGridEncoding
from nvf.encoding import HashEncoding

HEADS = frozenset({"rgb", "variance", "visibility"})
SH_DIM = 16  # real spherical harmonics, degrees 0-3
VIS_POSITION_WIDTH = 128
VIS_POSITION_FEATURES = 32
APPEARANCE_DIM = 32
MIN_VARIANCE = 1e-4  # q >= 1e-4 (METHOD section 3, section 15.4)
# Rows per block of an MLP evaluated without autograd: a 2048 x 128 float activation is 1 MiB, the two
# cores' L2, so a block's activations stay in cache.
INFERENCE_BLOCK = 2048
# A low-precision MLP on the CPU pads its rows to a multiple of LOW_PRECISION_ROWS and runs inference in
# blocks of LOW_PRECISION_BLOCK rows (see MLP._forward_in).
LOW_PRECISION_ROWS = 1024
LOW_PRECISION_BLOCK = 16384


@dataclass
class FieldOutput:
    """Per-sample field values; heads that were not requested are ``None``.

    ``vis_logit`` is the raw head output (for the BCE loss, M19); ``visibility`` is its sigmoid,
    set to 1 outside the AABB.
    """

    sigma: Float[Tensor, " S"]
    geo: Float[Tensor, "S G"]
    rgb: Float[Tensor, "S 3"] | None = None
    variance: Float[Tensor, "S 3"] | None = None
    visibility: Float[Tensor, " S"] | None = None
    vis_logit: Float[Tensor, " S"] | None = None


class _TruncExp(torch.autograd.Function):
    """``exp(x)`` whose gradient is ``exp(clamp(x, -15, 15))`` (METHOD section 3)."""

    @staticmethod
    def forward(ctx, x: Tensor) -> Tensor:
        ctx.save_for_backward(x)
        return torch.exp(x)

    @staticmethod
    def backward(ctx, grad: Tensor) -> Tensor:
        (x,) = ctx.saved_tensors
        return grad * torch.exp(x.clamp(-15.0, 15.0))


def trunc_exp(x: Float[Tensor, "*B"]) -> Float[Tensor, "*B"]:
    """Truncated exponential: forward ``exp(x)``, backward ``exp(clamp(x, -15, 15))``."""
    return _TruncExp.apply(x)


def spherical_harmonics(d: Float[Tensor, "S 3"]) -> Float[Tensor, "S 16"]:
    """Real spherical harmonics of degrees 0-3 of unit directions ``d`` (METHOD section 3, SH(d))."""
    x, y, z = d.unbind(-1)
    xx, yy, zz = x * x, y * y, z * z
    return torch.stack(
        [
            torch.full_like(x, 0.28209479177387814),
            0.4886025119029199 * y,
            0.4886025119029199 * z,
            0.4886025119029199 * x,
            1.0925484305920792 * x * y,
            1.0925484305920792 * y * z,
            0.9461746957575601 * zz - 0.31539156525251999,
            1.0925484305920792 * x * z,
            0.5462742152960396 * (xx - yy),
            0.5900435899266435 * y * (3.0 * xx - yy),
            2.890611442640554 * x * y * z,
            0.4570457994644658 * y * (5.0 * zz - 1.0),
            0.3731763325901154 * z * (5.0 * zz - 3.0),
            0.4570457994644658 * x * (5.0 * zz - 1.0),
            1.445305721320277 * z * (xx - yy),
            0.5900435899266435 * x * (xx - 3.0 * yy),
        ],
        dim=-1,
    )


class MLP(nn.Sequential):
    """Linear layers ``sizes[0] -> ... -> sizes[-1]`` with ReLU between them, none after the last.

    On the CPU without autograd, ``[N, sizes[0]]`` inputs run in blocks of ``INFERENCE_BLOCK`` rows, so
    every hidden activation of a block stays in the cores' caches instead of streaming ``N x width``
    floats through memory at every layer. Each row's values are unchanged (a row's dot products do not
    depend on the other rows). With autograd, or on CUDA, the whole batch runs at once.

    ``train_dtype`` and ``infer_dtype`` (float32 unless set, see ``RadianceField.mlp_precision``): the
    precision of calls with and without autograd. A lower one (bfloat16, float16) runs every layer in it,
    what autocast does to linear layers: the input and the float32 parameters are cast (with autograd
    the parameters' gradients come back in float32), and the output is returned in float32, so what
    follows (activations, rendering, losses) stays float32.
    The parameters are cast at every call (once, not per block): a cast kept between calls could not
    tell that fused Adam changed them, as it updates them without bumping their version counters.
    """

    def __init__(self, sizes: list[int], bias: bool):
        layers: list[nn.Module] = []
        for i, (fan_in, fan_out) in enumerate(zip(sizes[:-1], sizes[1:], strict=True)):
            layers.append(nn.Linear(fan_in, fan_out, bias=bias))
            if i < len(sizes) - 2:
                layers.append(nn.ReLU(inplace=True))
        super().__init__(*layers)
        self.train_dtype = self.infer_dtype = torch.float32

    def forward(self, x: Float[Tensor, "N I"]) -> Float[Tensor, "N O"]:
        dtype = self.train_dtype if torch.is_grad_enabled() else self.infer_dtype
        if dtype != torch.float32:
            return self._forward_in(dtype, x)
        if torch.is_grad_enabled() or x.device.type != "cpu" or x.shape[0] <= INFERENCE_BLOCK:
            return super().forward(x)
        return torch.cat([super(MLP, self).forward(block) for block in x.split(INFERENCE_BLOCK)])

    def _forward_in(self, dtype: torch.dtype, x: Float[Tensor, "N I"]) -> Float[Tensor, "N O"]:
        """The layers in ``dtype`` on ``x`` cast to it (with autograd, differentiable casts); the output
        cast back to float32.

        On the CPU the rows are zero-padded to a multiple of ``LOW_PRECISION_ROWS`` and, without
        autograd, run in blocks of ``LOW_PRECISION_BLOCK`` rows: oneDNN builds a kernel for every new
        matrix shape (about 0.5 ms, more than the product itself), so the shapes must repeat, and its
        low-precision products pay a fixed cost per call that small blocks do not amortise. Padded rows
        are dropped from the output; their gradients are zero, so they add nothing to the weights'.
        """
        params = [
            (layer.weight.to(dtype), None if layer.bias is None else layer.bias.to(dtype))
            for layer in self
            if isinstance(layer, nn.Linear)
        ]
        n = x.shape[0]
        h = x.to(dtype)
        if x.device.type == "cpu":
            h = F.pad(h, (0, 0, 0, -n % LOW_PRECISION_ROWS))
        blocks = h.split(LOW_PRECISION_BLOCK) if not torch.is_grad_enabled() and x.device.type == "cpu" else (h,)
        outputs = []
        for block in blocks:
            for i, (weight, bias) in enumerate(params):
                block = F.linear(block, weight, bias)
                if i < len(params) - 1:
                    block = block.relu_()
            outputs.append(block)
        return (outputs[0] if len(outputs) == 1 else torch.cat(outputs))[:n].float()


def make_encoding(cfg: FieldConfig) -> HashEncoding:
    """The backbone encoding selected by ``cfg.kind`` (hashgrid | densegrid)."""
    if cfg.kind == "hashgrid":
        return HashEncoding(
            cfg.num_levels,
            cfg.features_per_level,
            cfg.log2_hashmap_size,
            cfg.base_resolution,
            cfg.max_resolution,
            backend=cfg.backend,
        )
    if cfg.kind == "densegrid":
        return DenseGridEncoding(cfg.dense_resolution, cfg.dense_features, backend=cfg.backend)
    raise ValueError(f"field.kind must be hashgrid or densegrid, got {cfg.kind!r}")


class RadianceField(nn.Module):
    """NVF field over the object AABB ``[2,3]`` (min, max) with colour, variance and visibility heads."""

    aabb: Tensor

    def __init__(self, aabb: Float[Tensor, "2 3"], cfg: FieldConfig, num_images: int = 0) -> None:
        super().__init__()
        if cfg.appearance_embedding and num_images < 1:
            raise ValueError("field.appearance_embedding needs num_images >= 1")
        self.cfg = cfg
        self.register_buffer("aabb", aabb.detach().to(torch.float32).clone())
        width, geo = cfg.hidden_dim, cfg.geo_feat_dim
        self.encoding = make_encoding(cfg)
        self.density_mlp = MLP([self.encoding.out_dim, width, 1 + geo], cfg.mlp_bias)
        head_in = SH_DIM + geo + (APPEARANCE_DIM if cfg.appearance_embedding else 0)
        self.appearance = nn.Embedding(num_images, APPEARANCE_DIM) if cfg.appearance_embedding else None
        self.color_head = MLP([head_in, width, width, 3], cfg.mlp_bias)
        self.variance_head = MLP([head_in, width, width, 3], cfg.mlp_bias)
        self.vis_position = MLP([3, VIS_POSITION_WIDTH, VIS_POSITION_WIDTH, VIS_POSITION_FEATURES], cfg.mlp_bias)
        self.vis_head = MLP([geo + VIS_POSITION_FEATURES, width, width, 1], cfg.mlp_bias)

    @contextlib.contextmanager
    def mlp_precision(self, train: torch.dtype, infer: torch.dtype = torch.float32) -> Iterator[None]:
        """Inside the block every MLP of the field runs its layers in ``train`` when called with autograd
        and in ``infer`` without (``MLP.train_dtype``, ``MLP.infer_dtype``; float32 changes nothing);
        the encoding and everything after the MLPs stay float32."""
        mlps = [module for module in self.modules() if isinstance(module, MLP)]
        before = [(mlp.train_dtype, mlp.infer_dtype) for mlp in mlps]
        for mlp in mlps:
            mlp.train_dtype, mlp.infer_dtype = train, infer
        try:
            yield
        finally:
            for mlp, (previous_train, previous_infer) in zip(mlps, before, strict=True):
                mlp.train_dtype, mlp.infer_dtype = previous_train, previous_infer

    def normalize(self, x: Float[Tensor, "S 3"]) -> Float[Tensor, "S 3"]:
        """World points into ``[0,1]^3`` by the object AABB (no contraction)."""
        return (x - self.aabb[0]) / (self.aabb[1] - self.aabb[0])

    @staticmethod
    def inside(u: Float[Tensor, "S 3"]) -> Bool[Tensor, " S"]:
        """Whether every coordinate of ``u`` lies in the open interval ``(0,1)``."""
        return ((u > 0.0) & (u < 1.0)).all(dim=-1)

    def _density(
        self, u: Float[Tensor, "S 3"], inside: Bool[Tensor, " S"], encoded: Tensor | None = None
    ) -> tuple[Tensor, Tensor, Tensor]:
        """``sigma``, ``g`` and the encoding of ``u`` (``encoded``: its known value, see ``forward``)."""
        encoded = self.encoding(u, known=encoded)
        h = self.density_mlp(encoded)
        return torch.where(inside, trunc_exp(h[:, 0]), 0.0), h[:, 1:], encoded

    def density(self, x: Float[Tensor, "S 3"]) -> tuple[Float[Tensor, " S"], Float[Tensor, "S G"]]:
        """Density ``sigma >= 0`` (0 outside the AABB) and geometry feature ``g``."""
        return self.density_and_encoding(x)[:2]

    def density_and_encoding(
        self, x: Float[Tensor, "S 3"]
    ) -> tuple[Float[Tensor, " S"], Float[Tensor, "S G"], Float[Tensor, "S E"]]:
        """``density(x)`` plus the encoding of ``x``, which ``forward(..., encoded=)`` can reuse."""
        u = self.normalize(x)
        return self._density(u, self.inside(u))

    def forward(
        self,
        x: Float[Tensor, "S 3"],
        d: Float[Tensor, "S 3"],
        heads: frozenset[str] = frozenset({"rgb"}),
        image_idx: Int[Tensor, " S"] | None = None,
        density: FieldOutput | None = None,
        encoded: Float[Tensor, "S E"] | None = None,
    ) -> FieldOutput:
        """Density plus the requested ``heads`` (subset of ``HEADS``) at points ``x``, directions ``d``.

        ``image_idx`` selects the appearance embedding (only with ``appearance_embedding``); ``None``
        uses training image 0's, as the reference does at inference (D8). ``density``: the points'
        already computed ``sigma`` and ``geo`` (an inference render reuses its skipping pass's); the
        heads are added to it and it is returned. ``encoded``: the points' encoding computed without
        autograd with the current parameters (a training render's skipping pass); the density is then
        recomputed from it with autograd, and the encoding only runs its backward.
        """
        if not heads <= HEADS:
            raise ValueError(f"unknown field heads {sorted(heads - HEADS)}; expected a subset of {sorted(HEADS)}")
        u = self.normalize(x)
        inside = self.inside(u)
        if density is None:
            sigma, geo, _ = self._density(u, inside, encoded)
            density = FieldOutput(sigma=sigma, geo=geo)
        out, geo = density, density.geo
        if "rgb" in heads or "variance" in heads:
            parts = [spherical_harmonics(F.normalize(d, dim=-1)), geo]
            if self.appearance is not None:
                if image_idx is None:
                    parts.append(self.appearance.weight[0].expand(x.shape[0], APPEARANCE_DIM))
                else:
                    parts.append(self.appearance(image_idx))
            h = torch.cat(parts, dim=-1)
            if "rgb" in heads:
                out.rgb = torch.sigmoid(self.color_head(h))
            if "variance" in heads:
                out.variance = F.softplus(self.variance_head(h.detach())).clamp_min(MIN_VARIANCE)
        if "visibility" in heads:
            pos = self.vis_position(u.detach())
            logit = self.vis_head(torch.cat([geo.detach(), pos], dim=-1)).squeeze(-1)
            out.vis_logit = logit
            out.visibility = torch.where(inside, torch.sigmoid(logit), 1.0)
        return out

    def parameter_groups(self) -> dict[str, list[nn.Parameter]]:
        """Parameters trained by each stage: backbone (stage 1), variance (2), visibility (3)."""
        backbone = [*self.encoding.parameters(), *self.density_mlp.parameters(), *self.color_head.parameters()]
        if self.appearance is not None:
            backbone += list(self.appearance.parameters())
        return {
            "backbone": backbone,
            "variance": list(self.variance_head.parameters()),
            "visibility": [*self.vis_position.parameters(), *self.vis_head.parameters()],
        }
