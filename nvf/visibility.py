"""Visibility labels from the training cameras: noisy-OR of camera-to-point transmittance (M17, M18).

Labels are computed under ``no_grad`` with the **current** stage-1 density (METHOD.md 9.1, 15.8).
"""

import math
from collections.abc import Callable

import torch
from jaxtyping import Bool, Float, Int
from torch import Tensor

from nvf import kernels
from nvf.cameras import Intrinsics, project
from nvf.config import TrainConfig
from nvf.density_lattice import DensityLattice
from nvf.occupancy import OccupancyGrid, ray_aabb

SATURATION = 0.01  # M18: a point whose running product is <= this skips the remaining cameras
STOP_BLOCK = 32  # M17's early stop (``cutoff``): bins evaluated per segment between two transmittance checks

DensityFn = Callable[[Tensor], Tensor]  # positions [S,3] -> density sigma [S] (0 outside the AABB)


def frustum_mask(
    points: Float[Tensor, "N 3"], c2w: Float[Tensor, "4 4"], intrinsics: Intrinsics, max_depth: float
) -> Bool[Tensor, " N"]:
    """Frustum test of M17: ``0 < camera depth < max_depth`` and projecting inside the image
    (``0 <= u < W``, ``0 <= v < H``)."""
    uv, depth = project(points, c2w, intrinsics)
    u, v = uv.unbind(-1)
    return (depth > 0) & (depth < max_depth) & (u >= 0) & (u < intrinsics.width) & (v >= 0) & (v < intrinsics.height)


def segment_fractions(
    origin: Float[Tensor, "3"], seg: Float[Tensor, "P 3"], box: Float[Tensor, "2 3"]
) -> tuple[Float[Tensor, " P"], Float[Tensor, " P"]]:
    """Where ``origin + f seg`` lies inside ``box`` for ``f`` in ``[0, 1]``: ``[f_in, f_out]`` (slab test);
    ``f_out < f_in`` when the segment misses the box."""
    f_in, f_out = ray_aabb(origin.expand_as(seg), seg, box[0], box[1])
    return f_in.clamp(min=0.0), f_out.clamp(max=1.0)


def _bin_range(
    origin: Float[Tensor, "3"], seg: Float[Tensor, "C 3"], num_samples: int, box: Float[Tensor, "2 3"]
) -> tuple[Int[Tensor, " C"], Int[Tensor, " C"]]:
    """First bin and bin count per segment: the bins between its entry into and exit from ``box``, with one
    bin of margin at each end for rounding."""
    n_bins = num_samples - 1
    f_in, f_out = segment_fractions(origin, seg, box)
    first = torch.floor(f_in * num_samples).long().sub_(1).clamp_(0, n_bins)
    count = (torch.ceil(f_out * num_samples).long().add_(1).clamp_(0, n_bins) - first).clamp_(min=0)
    return first, count


def _samples_in_box(
    origin: Float[Tensor, "3"],
    seg: Float[Tensor, "C 3"],
    offsets: Float[Tensor, "C B"],
    num_samples: int,
    box: Float[Tensor, "2 3"],
    grid: OccupancyGrid | None,
    first: Int[Tensor, " C"],
    count: Int[Tensor, " C"],
) -> tuple[Int[Tensor, " S"], Float[Tensor, "S 3"]]:
    """The samples of bins ``first .. first + count - 1`` of each segment that lie inside ``box`` and, with
    ``grid``, in its occupied cells, row-major: each one's flat bin index ``row * B + k`` and position. On the CPU
    with ``grid`` the C++ kernel (``nvf.kernels.labels``) finds them, elsewhere torch; both compute the same
    float32 operations, so the samples are bitwise the same."""
    n_bins = offsets.shape[1]
    kernel = kernels.labels() if grid is not None and seg.device.type == "cpu" and seg.dtype == torch.float32 else None
    if kernel is not None and grid is not None:
        flat, pos = kernel.occupied_bins(
            origin, seg, offsets, first, count, num_samples, box, grid.occupied, grid.aabb[0], grid.cell_size,
            grid.resolution,
        )  # fmt: skip
        return flat, pos
    row = torch.repeat_interleave(torch.arange(seg.shape[0], device=seg.device), count)
    start = torch.cumsum(count, 0) - count
    k = torch.arange(row.shape[0], device=seg.device) - start[row] + first[row]
    flat = row * n_bins + k
    frac = (k.to(seg.dtype) + offsets.view(-1)[flat]) / num_samples
    pos = origin + frac[:, None] * seg[row]
    keep = ((pos >= box[0]) & (pos <= box[1])).all(-1)
    if grid is not None:
        keep &= grid.is_occupied(pos)
    index = keep.nonzero().squeeze(1)
    return flat[index], pos[index]


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
    grid: OccupancyGrid | None = None,
    cutoff: float = 0.0,
) -> Float[Tensor, " P"]:
    """(M17) ``T(x) = exp(-sum_{k<K} sigma(y_k) delta)`` from ``origin`` to each point.

    ``K = num_samples`` stratified samples on ``[0, L]``, ``L = max(|x - o| - margin, 0)`` (``margin``
    0: METHOD's segment; above 0 it stops short of ``x``, a deviation, ``train.label_margin``), with
    ``delta = L / K``; the last interval is excluded, so ``K - 1`` densities per point. Sample ``k`` sits
    at the centre of bin ``k`` (``generator=None``) or uniformly inside it (one ``[chunk, K - 1]`` draw per
    chunk of points). ``aabb``: a box outside which the density is 0 (the object AABB, or the model's
    ``density_support``): only the bins between a segment's entry into and exit from the box are placed and
    tested, and with ``grid`` (the occupancy grid whose empty cells ``density_fn`` reads as 0,
    ``SceneModel.density``) only the samples in its occupied cells reach ``density_fn``; those are the samples,
    in the same order, that placing every bin and testing it gives (the code this replaced, kept for the
    benchmarks and tests: ``pipeline.bench._replaced_labels``), so the result is bitwise the same. At most
    ``chunk_samples`` samples per chunk of points.

    ``cutoff`` above 0 (with ``aabb``; M17's early stop, ``train.label_cutoff``): a segment's bins
    are evaluated from the camera outwards, ``STOP_BLOCK`` at a time, and a segment whose transmittance so far
    is below ``cutoff`` evaluates no more; its result is that transmittance, which is at least the exact one
    and below ``cutoff``, so each ``T`` is off by less than ``cutoff`` (and by rounding: the sums are taken
    in another order).

    ``density_fn`` a ``DensityLattice`` (``train.label_lattice``; with ``aabb``): on the CPU its kernel
    sums each segment's samples in one pass (``DensityLattice.segment_sums``, the early stop checked per sample),
    elsewhere the samples read the lattice through the paths above.
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
    per_chunk = max(1, chunk_samples // n_bins)
    for start in range(0, points.shape[0], per_chunk):
        stop = min(start + per_chunk, points.shape[0])
        if generator is None:
            offsets = torch.full((stop - start, n_bins), 0.5, dtype=points.dtype, device=points.device)
        else:
            offsets = torch.rand(stop - start, n_bins, generator=generator, device=generator.device)
            offsets = offsets.to(device=points.device, dtype=points.dtype)
        part = seg[start:stop]
        optical[start:stop] = _optical_depth(density_fn, origin, part, offsets, num_samples, aabb, grid, cutoff)
    return torch.exp(-optical)


def _optical_depth(
    density_fn: DensityFn,
    origin: Float[Tensor, "3"],
    seg: Float[Tensor, "C 3"],
    offsets: Float[Tensor, "C B"],
    num_samples: int,
    aabb: Float[Tensor, "2 3"] | None,
    grid: OccupancyGrid | None,
    cutoff: float,
) -> Float[Tensor, " C"]:
    """M17's optical depth ``sum_k sigma(y_k) delta`` of a chunk of segments by the path
    ``segment_transmittance`` describes: the lattice's kernel, the early stop, the in-box samples, or every bin."""
    delta = torch.linalg.norm(seg, dim=-1) / num_samples
    if aabb is not None and isinstance(density_fn, DensityLattice):
        first, count = _bin_range(origin, seg, num_samples, aabb)
        limit = -math.log(cutoff) if cutoff > 0 else math.inf
        sums = density_fn.segment_sums(origin, seg, offsets, first, count, num_samples, aabb, delta, limit)
        if sums is not None:
            return sums * delta
    if aabb is not None and cutoff > 0:
        return _stopped_optical_depth(density_fn, origin, seg, offsets, num_samples, aabb, grid, delta, cutoff)
    if aabb is not None:
        first, count = _bin_range(origin, seg, num_samples, aabb)
        flat, pos = _samples_in_box(origin, seg, offsets, num_samples, aabb, grid, first, count)
        sigma = torch.zeros(offsets.shape, dtype=seg.dtype, device=seg.device)
        if flat.numel():
            sigma.view(-1)[flat] = density_fn(pos).to(sigma.dtype)
    else:
        bins = torch.arange(offsets.shape[1], dtype=seg.dtype, device=seg.device)
        frac = (bins + offsets) / num_samples  # [C, K-1] in [0, (K-1)/K)
        pos = origin + frac[..., None] * seg[:, None, :]  # [C, K-1, 3]
        sigma = density_fn(pos.reshape(-1, 3)).reshape(frac.shape)
    return sigma.sum(-1) * delta


def _stopped_optical_depth(
    density_fn: DensityFn,
    origin: Float[Tensor, "3"],
    seg: Float[Tensor, "C 3"],
    offsets: Float[Tensor, "C B"],
    num_samples: int,
    box: Float[Tensor, "2 3"],
    grid: OccupancyGrid | None,
    delta: Float[Tensor, " C"],
    cutoff: float,
) -> Float[Tensor, " C"]:
    """M17's optical depth ``sum_k sigma(y_k) delta`` of each segment with the early stop of
    ``segment_transmittance``: the in-box bins ``STOP_BLOCK`` at a time from the camera outwards, a segment
    dropped once its optical depth reaches ``-ln(cutoff)``."""
    first, count = _bin_range(origin, seg, num_samples, box)
    limit = -math.log(cutoff)
    optical = torch.zeros(seg.shape[0], dtype=seg.dtype, device=seg.device)
    rows = (count > 0).nonzero().squeeze(1)
    done = 0
    while rows.numel():
        block_count = (count[rows] - done).clamp(max=STOP_BLOCK)
        flat, pos = _samples_in_box(
            origin, seg[rows], offsets[rows], num_samples, box, grid, first[rows] + done, block_count
        )
        if flat.numel():
            sigma = density_fn(pos).to(seg.dtype)
            optical.index_add_(0, rows[flat // offsets.shape[1]], sigma * delta[rows[flat // offsets.shape[1]]])
        done += STOP_BLOCK
        rows = rows[(count[rows] > done) & (optical[rows] < limit)]
    return optical


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
    grid: OccupancyGrid | None = None,
) -> Float[Tensor, " N"]:
    """(M18) Soft label ``V*(x) = 1 - prod_{j in F(x)} (1 - T_j(x))`` in ``[0, 1]``.

    ``F(x)``: the cameras whose frustum (``cfg.label_max_depth``) contains ``x``; points outside
    every frustum get 0. Cameras are processed in order and a point whose running product is
    ``<= 0.01`` skips the rest, so labels saturate near 0.99. ``T_j`` is (M17) with
    ``cfg.label_samples`` samples, stopping ``cfg.label_margin`` short of the point, and with ``aabb`` a segment
    stops once its transmittance is below ``cfg.label_cutoff`` (see ``segment_transmittance`` for
    ``generator``, ``aabb``, ``chunk_samples``, ``grid`` and the cutoff; each label is then off by less
    than the cutoff times the number of cameras); density is evaluated only for in-frustum, not yet saturated
    pairs.
    """
    prod = torch.ones(points.shape[0], dtype=points.dtype, device=points.device)
    for j in range(c2w.shape[0]):
        active = frustum_mask(points, c2w[j], intrinsics, cfg.label_max_depth) & (prod > SATURATION)
        idx = active.nonzero().squeeze(1)
        if idx.numel() == 0:
            continue
        trans = segment_transmittance(
            density_fn,
            c2w[j, :3, 3],
            points[idx],
            cfg.label_samples,
            generator,
            aabb,
            chunk_samples,
            cfg.label_margin,
            grid,
            cfg.label_cutoff if aabb is not None else 0.0,
        )
        prod[idx] = prod[idx] * (1.0 - trans)
    return 1.0 - prod
