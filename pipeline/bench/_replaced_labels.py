"""The visibility labels as they were computed before their speed-ups (``python -m pipeline.bench speedups``
pairs each speed-up with the code it replaced): every bin of a segment placed and those inside the box evaluated
(``nvf.visibility.segment_transmittance`` places only the bins between a segment's entry into and exit from the box,
bitwise the same samples), no early stop. Kept here, beside the benchmark and the tests that compare against it,
not as a flag of the library."""

import torch
from jaxtyping import Float
from torch import Tensor

from nvf.cameras import Intrinsics
from nvf.config import TrainConfig
from nvf.visibility import SATURATION, DensityFn, frustum_mask


def every_sample_transmittance(
    density_fn: DensityFn,
    origin: Float[Tensor, "3"],
    points: Float[Tensor, "P 3"],
    num_samples: int,
    generator: torch.Generator | None = None,
    aabb: Float[Tensor, "2 3"] | None = None,
    chunk_samples: int = 1 << 18,
    margin: float = 0.0,
) -> Float[Tensor, " P"]:
    """(M17) ``segment_transmittance`` with every bin placed: the same stratified samples, drawn the same way per
    chunk of points, those outside ``aabb`` read as 0 density."""
    n_bins = num_samples - 1
    seg = points - origin
    if margin > 0:
        length = torch.linalg.norm(seg, dim=-1, keepdim=True)
        seg = seg * ((length - margin).clamp(min=0.0) / length.clamp(min=1e-12))
    optical = torch.zeros(points.shape[0], dtype=points.dtype, device=points.device)
    if n_bins == 0:
        return torch.ones_like(optical)
    per_chunk = max(1, chunk_samples // n_bins)
    for start in range(0, points.shape[0], per_chunk):
        stop = min(start + per_chunk, points.shape[0])
        if generator is None:
            offsets = torch.full((stop - start, n_bins), 0.5, dtype=points.dtype, device=points.device)
        else:
            offsets = torch.rand(stop - start, n_bins, generator=generator, device=generator.device)
            offsets = offsets.to(device=points.device, dtype=points.dtype)
        part = seg[start:stop]
        delta = torch.linalg.norm(part, dim=-1) / num_samples
        bins = torch.arange(n_bins, dtype=points.dtype, device=points.device)
        pos = origin + ((bins + offsets) / num_samples)[..., None] * part[:, None, :]
        sigma = torch.zeros(offsets.shape, dtype=points.dtype, device=points.device)
        inside = torch.ones(offsets.shape, dtype=torch.bool, device=points.device)
        if aabb is not None:
            inside = ((pos >= aabb[0]) & (pos <= aabb[1])).all(-1)
        if inside.any():
            sigma[inside] = density_fn(pos[inside]).to(sigma.dtype)
        optical[start:stop] = sigma.sum(-1) * delta
    return torch.exp(-optical)


@torch.no_grad()
def every_sample_labels(
    density_fn: DensityFn,
    points: Float[Tensor, "N 3"],
    c2w: Float[Tensor, "M 4 4"],
    intrinsics: Intrinsics,
    cfg: TrainConfig,
    generator: torch.Generator | None = None,
    aabb: Float[Tensor, "2 3"] | None = None,
    chunk_samples: int = 1 << 18,
) -> Float[Tensor, " N"]:
    """(M18) ``visibility_labels`` with ``every_sample_transmittance`` and no early stop."""
    prod = torch.ones(points.shape[0], dtype=points.dtype, device=points.device)
    for j in range(c2w.shape[0]):
        active = frustum_mask(points, c2w[j], intrinsics, cfg.label_max_depth) & (prod > SATURATION)
        idx = active.nonzero().squeeze(1)
        if idx.numel() == 0:
            continue
        trans = every_sample_transmittance(
            density_fn, c2w[j, :3, 3], points[idx], cfg.label_samples, generator, aabb, chunk_samples, cfg.label_margin
        )
        prod[idx] = prod[idx] * (1.0 - trans)
    return 1.0 - prod
