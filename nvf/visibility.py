"""Visibility labels from the training cameras: noisy-OR of camera-to-point transmittance (M17, M18).

Labels are computed under ``no_grad`` with the **current** stage-1 density (METHOD.md 9.1, 15.8).
"""

from collections.abc import Callable

import torch
from jaxtyping import Bool, Float
from torch import Tensor

from nvf.cameras import Intrinsics, project
from nvf.config import TrainConfig

SATURATION = 0.01  # M18: a point whose running product is <= this skips the remaining cameras

DensityFn = Callable[[Tensor], Tensor]  # positions [S,3] -> density sigma [S] (0 outside the AABB)


def frustum_mask(
    points: Float[Tensor, "N 3"], c2w: Float[Tensor, "4 4"], intrinsics: Intrinsics, max_depth: float
) -> Bool[Tensor, " N"]:
    """Frustum test of M17: ``0 < camera depth < max_depth`` and projecting inside the image
    (``0 <= u < W``, ``0 <= v < H``)."""
    uv, depth = project(points, c2w, intrinsics)
    u, v = uv.unbind(-1)
    return (depth > 0) & (depth < max_depth) & (u >= 0) & (u < intrinsics.width) & (v >= 0) & (v < intrinsics.height)


@torch.no_grad()
def segment_transmittance(
    density_fn: DensityFn,
    origin: Float[Tensor, "3"],
    points: Float[Tensor, "P 3"],
    num_samples: int,
    generator: torch.Generator | None = None,
    aabb: Float[Tensor, "2 3"] | None = None,
    chunk_samples: int = 1 << 18,
    margin: float = 0.0,
) -> Float[Tensor, " P"]:
    """(M17) ``T(x) = exp(-sum_{k<K} sigma(y_k) delta)`` from ``origin`` to each point.

    ``K = num_samples`` stratified samples on ``[0, L]``, ``L = max(|x - o| - margin, 0)`` (``margin``
    0: METHOD's segment; above 0 it stops short of ``x``, a deviation, ``train.label_margin``), with
    ``delta = L / K``; the last interval is excluded, so ``K - 1`` densities per point. Sample ``k`` sits
    at the centre of bin ``k`` (``generator=None``) or uniformly inside it. Samples outside ``aabb``
    (if given) are not evaluated: the field's density is 0 there. At most ``chunk_samples``
    positions are evaluated at once.
    """
    if num_samples < 1:
        raise ValueError(f"label_samples must be >= 1, got {num_samples}")
    n_bins = num_samples - 1
    seg = points - origin  # [P,3]
    if margin > 0:
        length = torch.linalg.norm(seg, dim=-1, keepdim=True)
        seg = seg * ((length - margin).clamp(min=0.0) / length.clamp(min=1e-12))
    optical = torch.zeros(points.shape[0], dtype=points.dtype, device=points.device)
    if n_bins == 0:
        return torch.ones_like(optical)
    bins = torch.arange(n_bins, dtype=points.dtype, device=points.device)
    per_chunk = max(1, chunk_samples // n_bins)
    for start in range(0, points.shape[0], per_chunk):
        stop = min(start + per_chunk, points.shape[0])
        if generator is None:
            offsets = torch.full((stop - start, n_bins), 0.5, dtype=points.dtype, device=points.device)
        else:
            offsets = torch.rand(stop - start, n_bins, generator=generator, device=generator.device)
            offsets = offsets.to(device=points.device, dtype=points.dtype)
        frac = (bins + offsets) / num_samples  # [C, K-1] in [0, (K-1)/K)
        pos = origin + frac[..., None] * seg[start:stop, None, :]  # [C, K-1, 3]
        if aabb is None:
            sigma = density_fn(pos.reshape(-1, 3)).reshape(frac.shape)
        else:
            sigma = torch.zeros(frac.shape, dtype=points.dtype, device=points.device)
            inside = ((pos >= aabb[0]) & (pos <= aabb[1])).all(-1)
            if inside.any():
                sigma[inside] = density_fn(pos[inside]).to(sigma.dtype)
        delta = torch.linalg.norm(seg[start:stop], dim=-1) / num_samples
        optical[start:stop] = sigma.sum(-1) * delta
    return torch.exp(-optical)


@torch.no_grad()
def visibility_labels(
    density_fn: DensityFn,
    points: Float[Tensor, "N 3"],
    c2w: Float[Tensor, "M 4 4"],
    intrinsics: Intrinsics,
    cfg: TrainConfig,
    generator: torch.Generator | None = None,
    aabb: Float[Tensor, "2 3"] | None = None,
    chunk_samples: int = 1 << 18,
) -> Float[Tensor, " N"]:
    """(M18) Soft label ``V*(x) = 1 - prod_{j in F(x)} (1 - T_j(x))`` in ``[0, 1]``.

    ``F(x)``: the cameras whose frustum (``cfg.label_max_depth``) contains ``x``; points outside
    every frustum get 0. Cameras are processed in order and a point whose running product is
    ``<= 0.01`` skips the rest, so labels saturate near 0.99. ``T_j`` is (M17) with
    ``cfg.label_samples`` samples, stopping ``cfg.label_margin`` short of the point (see
    ``segment_transmittance`` for ``generator``, ``aabb`` and ``chunk_samples``); density is evaluated
    only for in-frustum, not yet saturated pairs.
    """
    prod = torch.ones(points.shape[0], dtype=points.dtype, device=points.device)
    for j in range(c2w.shape[0]):
        active = frustum_mask(points, c2w[j], intrinsics, cfg.label_max_depth) & (prod > SATURATION)
        idx = active.nonzero().squeeze(1)
        if idx.numel() == 0:
            continue
        trans = segment_transmittance(
            density_fn, c2w[j, :3, 3], points[idx], cfg.label_samples, generator, aabb, chunk_samples, cfg.label_margin
        )
        prod[idx] = prod[idx] * (1.0 - trans)
    return 1.0 - prod
