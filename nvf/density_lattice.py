"""The density sampled once on a lattice finer than the occupancy grid and read by trilinear interpolation: the
density M17's labels read with ``train.label_lattice`` (a speed-up with a measured tolerance, docs/METHOD.md)."""

from collections.abc import Callable

import torch
import torch.nn.functional as F
from jaxtyping import Bool, Float, Int
from torch import Tensor

from nvf import kernels
from nvf.occupancy import OccupancyGrid

MAX_SUBDIVISIONS = 8
MAX_VERTICES = 1 << 28  # 1 GiB of float32 values
_CHUNK = 1 << 18  # vertices per density call


def lattice_vertices(resolution: int, subdivisions: int) -> int:
    """Vertices of the lattice ``subdivisions`` times finer than a ``resolution``³ grid: ``(res x s + 1)³``."""
    return (resolution * subdivisions + 1) ** 3


class DensityLattice:
    """``sigma`` read by trilinear interpolation between its values at the vertices of the lattice ``subdivisions``
    times finer than ``grid`` (over the grid's AABB), the density of ``field_density`` (``[N,3] -> [N]``, not
    masked) evaluated once at the vertices of the ``cells`` (bool ``[res³]``, the grid's cell order); a point
    outside those cells reads 0, as ``SceneModel.density`` reads the empty cells. Built for a density that no
    longer changes (stage 3 trains the visibility head only). Call: ``[N,3] -> [N]``."""

    def __init__(
        self,
        field_density: Callable[[Float[Tensor, "N 3"]], Float[Tensor, " N"]],
        grid: OccupancyGrid,
        subdivisions: int,
        cells: Bool[Tensor, " C"],
    ):
        if not 1 <= subdivisions <= MAX_SUBDIVISIONS:
            raise ValueError(f"subdivisions must be in 1..{MAX_SUBDIVISIONS}, got {subdivisions}")
        res, n = grid.resolution, grid.resolution * subdivisions + 1
        if n**3 > MAX_VERTICES:
            raise ValueError(f"a lattice of {n}³ vertices is above {MAX_VERTICES}; use fewer subdivisions")
        self.grid, self.cells, self.aabb = grid, cells, grid.aabb
        device = grid.occupied.device
        needed = torch.zeros(n, n, n, dtype=torch.bool, device=device)
        ijk = torch.stack(torch.unravel_index(cells.nonzero().squeeze(1), (res, res, res)), dim=-1)
        corner = ijk * subdivisions
        for a in range(subdivisions + 1):  # the vertices of each cell, one plane of its sub-lattice at a time
            for b in range(subdivisions + 1):
                for c in range(subdivisions + 1):
                    needed[corner[:, 0] + a, corner[:, 1] + b, corner[:, 2] + c] = True
        where = needed.view(-1).nonzero().squeeze(1)
        self.values = torch.zeros(n**3, dtype=torch.float32, device=device)
        scale = (self.aabb[1] - self.aabb[0]) / (n - 1)
        with torch.no_grad():
            for start in range(0, where.shape[0], _CHUNK):
                idx = where[start : start + _CHUNK]
                vertex = torch.stack(torch.unravel_index(idx, (n, n, n)), dim=-1).to(torch.float32)
                self.values[idx] = field_density(self.aabb[0] + vertex * scale).to(torch.float32)
        self.values = self.values.view(1, 1, n, n, n)
        self.evaluated = int(where.shape[0])  # the density calls the lattice took

    def segment_sums(
        self,
        origin: Float[Tensor, "3"],
        seg: Float[Tensor, "C 3"],
        offsets: Float[Tensor, "C B"],
        first: Int[Tensor, " C"],
        count: Int[Tensor, " C"],
        num_samples: int,
        box: Float[Tensor, "2 3"],
        delta: Float[Tensor, " C"],
        limit: float,
    ) -> Float[Tensor, " C"] | None:
        """M17's sum of densities over the samples of bins ``first .. first + count - 1`` of each segment
        (``nvf.visibility.segment_transmittance``'s samples, inside ``box`` and the lattice's cells), each read from
        the lattice, a segment's sum stopped once it times ``delta`` reaches ``limit`` (``math.inf``: never); by the
        C++ kernel in one pass, on the CPU in float32; ``None`` elsewhere (the caller reads the lattice through
        ``__call__``, to rounding the same)."""
        kernel = kernels.labels() if seg.device.type == "cpu" and seg.dtype == torch.float32 else None
        if kernel is None:
            return None
        n = self.values.shape[-1]
        step = (self.aabb[1] - self.aabb[0]) / (n - 1)
        return kernel.lattice_depth(
            origin, seg, offsets, first, count, num_samples, box, self.cells, self.grid.aabb[0], self.grid.cell_size,
            self.grid.resolution, self.values.view(-1), n, self.aabb[0], step, delta, limit,
        )  # fmt: skip

    def __call__(self, x: Float[Tensor, "N 3"]) -> Float[Tensor, " N"]:
        unit = (x.to(torch.float32) - self.aabb[0]) / (self.aabb[1] - self.aabb[0])
        # grid_sample's last axis is (W, H, D): the lattice's third, second, first index
        where = (unit * 2.0 - 1.0).flip(-1).view(1, 1, 1, -1, 3)
        sigma = F.grid_sample(self.values, where, mode="bilinear", align_corners=True).view(-1)
        flat, inside = self.grid.cell_index(x)
        return torch.where(inside & self.cells[flat], sigma, 0.0).to(x.dtype)
