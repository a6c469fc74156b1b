"""Occupancy grid and ray marching, a pure-torch nerfacc ``OccGridEstimator`` (METHOD.md section 4, M5, M6).

One level only: the grid covers the object AABB. nerfacc's coarser levels (the AABB scaled by
``2^l``) never become occupied where a point would be looked up in them, because the field has
``sigma = 0`` outside the AABB, so marching is unchanged. The one difference is that nerfacc's
``mean(occ)`` (occupancy threshold of M5, alpha-skipping threshold) averages over all four levels;
here it averages over level 0.

Cells are indexed ``(ix * res + iy) * res + iz`` (x-major) over the AABB ``[lo, hi]``.
"""

import math
from collections.abc import Callable

import torch
from jaxtyping import Bool, Float, Int
from torch import Tensor, nn

from nvf.config import SamplerConfig
from nvf.rendering import Samples

# Marching and grid updates handle at most this many steps / probe points at once (memory bound).
_STEP_BUDGET = 1 << 21
_PROBE_CHUNK = 1 << 15
# Empty-space skipping: block edge in cells, and the longest run of steps tested against one block.
_BLOCK = 8
_MAX_RUN = 32.0


def ray_aabb(
    origins: Float[Tensor, "R 3"], dirs: Float[Tensor, "R 3"], lo: Float[Tensor, "3"], hi: Float[Tensor, "3"]
) -> tuple[Float[Tensor, " R"], Float[Tensor, " R"]]:
    """Entry and exit ``t`` of each ray through the box ``[lo, hi]`` (slab test); exit < entry on a miss."""
    tiny = torch.where(dirs >= 0, 1e-12, -1e-12)
    inv = 1.0 / torch.where(dirs.abs() > 1e-12, dirs, tiny)
    t1, t2 = (lo - origins) * inv, (hi - origins) * inv
    return torch.minimum(t1, t2).amax(-1), torch.maximum(t1, t2).amin(-1)


class OccupancyGrid(nn.Module):
    """Binary occupancy over the object AABB with the M5 update and the M6 marcher.

    Buffers: ``occ`` (float ``[res^3]``, the running ``sigma * step_size`` maxima), ``occupied``
    (bool ``[res^3]``) and ``observed`` (bool ``[res^3]``, cells that held a kept training sample,
    see :meth:`mark_observed`). All start at zero / empty, as in nerfacc: nothing is marched before
    the first :meth:`update`.
    """

    aabb: Tensor  # buffers (typed here: nn.Module's attribute lookup does not know them)
    occ: Tensor
    occupied: Tensor
    observed: Tensor

    def __init__(self, aabb: Float[Tensor, "2 3"], cfg: SamplerConfig):
        super().__init__()
        self.cfg = cfg
        self.resolution = cfg.grid_resolution
        cells = self.resolution**3
        self.register_buffer("aabb", aabb.detach().clone().to(torch.float32))
        self.register_buffer("occ", torch.zeros(cells, device=aabb.device))
        self.register_buffer("occupied", torch.zeros(cells, dtype=torch.bool, device=aabb.device))
        self.register_buffer("observed", torch.zeros(cells, dtype=torch.bool, device=aabb.device))
        self._skip_cache: tuple[tuple[int, int], tuple] | None = None

    @property
    def mean_occupancy(self) -> float:
        """``mean(occ)``: enters the M5 threshold and the alpha-skipping threshold (section 4)."""
        return float(self.occ.mean())

    @property
    def cell_size(self) -> Float[Tensor, "3"]:
        return (self.aabb[1] - self.aabb[0]) / self.resolution

    def cell_centers(self) -> Float[Tensor, "N 3"]:
        """World positions of all cell centres, in cell-index order."""
        return self._cell_points(torch.arange(self.resolution**3, device=self.occ.device), 0.5)

    def cell_index(self, x: Float[Tensor, "N 3"]) -> tuple[Int[Tensor, " N"], Bool[Tensor, " N"]]:
        """Flat index of the cell holding each point (clamped to the grid) and whether it is inside."""
        res = self.resolution
        cell = torch.floor((x - self.aabb[0]) / self.cell_size).long()
        inside = ((cell >= 0) & (cell < res)).all(dim=-1)
        cell = cell.clamp(0, res - 1)
        return (cell[:, 0] * res + cell[:, 1]) * res + cell[:, 2], inside

    def is_occupied(self, x: Float[Tensor, "N 3"]) -> Bool[Tensor, " N"]:
        """Whether each point lies in an occupied cell (False outside the AABB)."""
        flat, inside = self.cell_index(x)
        return inside & self.occupied[flat]

    def is_observed(self, x: Float[Tensor, "N 3"]) -> Bool[Tensor, " N"]:
        """Whether each point lies in a cell marked by :meth:`mark_observed` (False outside the AABB)."""
        flat, inside = self.cell_index(x)
        return inside & self.observed[flat]

    @torch.no_grad()
    def mark_observed(self, x: Float[Tensor, "N 3"]) -> None:
        """Mark the cells holding ``x`` (a training batch's kept samples) as observed: some training
        ray reached them before its transmittance fell below ``early_stop_eps``."""
        flat, inside = self.cell_index(x.detach())
        self.observed[flat[inside]] = True

    def _cell_points(self, idx: Int[Tensor, " N"], offset: Float[Tensor, "N 3"] | float) -> Float[Tensor, "N 3"]:
        res = self.resolution
        coords = torch.stack([idx // (res * res), (idx // res) % res, idx % res], dim=-1).to(torch.float32)
        return self.aabb[0] + (coords + offset) * self.cell_size

    @torch.no_grad()
    def update(
        self, iteration: int, density_fn: Callable[[Tensor], Tensor], generator: torch.Generator | None = None
    ) -> None:
        """(M5) Refresh the grid; a no-op unless ``iteration % cfg.update_every == 0`` (nerfacc's
        ``update_every_n_steps``), so call it at every training iteration.

        Evaluates every cell while ``iteration < warmup_iters``, afterwards ``cells/4`` uniformly drawn
        cells plus ``cells/4`` drawn among the occupied ones (all of them if fewer). Each evaluated cell
        is probed at one uniform random point: ``occ <- max(decay * occ, sigma(x) * step_size)``, then
        ``occupied = occ > min(mean(occ), occ_threshold)``. ``density_fn``: ``[N,3] -> sigma [N]``.
        """
        cfg = self.cfg
        if iteration % cfg.update_every != 0:
            return
        device = self.occ.device
        cells = self.occ.shape[0]
        if iteration < cfg.warmup_iters:
            idx = torch.arange(cells, device=device)
        else:
            quarter = cells // 4
            uniform = torch.randint(cells, (quarter,), generator=generator, device=device)
            occupied = torch.nonzero(self.occupied)[:, 0]
            if quarter < occupied.shape[0]:
                pick = torch.randint(occupied.shape[0], (quarter,), generator=generator, device=device)
                occupied = occupied[pick]
            idx = torch.cat([uniform, occupied])
        offsets = torch.rand((idx.shape[0], 3), generator=generator, device=device)
        sigma = torch.cat(
            [
                density_fn(self._cell_points(idx[i : i + _PROBE_CHUNK], offsets[i : i + _PROBE_CHUNK])).reshape(-1)
                for i in range(0, idx.shape[0], _PROBE_CHUNK)
            ]
        )
        values = torch.maximum(self.occ[idx] * cfg.occ_decay, sigma.to(self.occ.dtype) * cfg.step_size)
        # amax over duplicate draws of one cell: deterministic, decay applied once per update.
        self.occ.scatter_reduce_(0, idx, values, reduce="amax", include_self=False)
        threshold = torch.clamp(self.occ.mean(), max=cfg.occ_threshold)
        self.occupied.copy_(self.occ > threshold)

    def _skip_structures(self) -> tuple[tuple[Float[Tensor, "3"], Float[Tensor, "3"]] | None, Bool[Tensor, "B B B"]]:
        """The occupied cells' bounding box and the dilated block grid, recomputed only when
        ``occupied`` changed (keyed by its storage and in-place version counter: updates,
        ``load_state_dict`` and device moves all invalidate it)."""
        key = (self.occupied.data_ptr(), self.occupied._version)
        if self._skip_cache is None or self._skip_cache[0] != key:
            self._skip_cache = (key, (self._occupied_box(), self._block_grid()))
        return self._skip_cache[1]

    def occupied_box(self) -> tuple[Float[Tensor, "3"], Float[Tensor, "3"]] | None:
        """World bounds of the occupied cells (None if no cell is occupied), kept until ``occupied`` changes."""
        return self._skip_structures()[0]

    def _occupied_box(self) -> tuple[Float[Tensor, "3"], Float[Tensor, "3"]] | None:
        """World bounds of the occupied cells (None if no cell is occupied)."""
        res = self.resolution
        grid = self.occupied.view(res, res, res)
        bounds = []
        for axes in ((1, 2), (0, 2), (0, 1)):
            nz = torch.nonzero(grid.any(dim=axes[1]).any(dim=axes[0]))[:, 0]
            if nz.shape[0] == 0:
                return None
            bounds.append((nz[0], nz[-1] + 1))
        first = torch.stack([b[0] for b in bounds]).to(torch.float32)
        last = torch.stack([b[1] for b in bounds]).to(torch.float32)
        lo = self.aabb[0]
        return lo + first * self.cell_size, lo + last * self.cell_size

    def _t_of_k(
        self, k: Float[Tensor, "*#N"], t0: Float[Tensor, "*#N"], k1: Float[Tensor, "*#N"], t1: Float[Tensor, "*#N"]
    ) -> Float[Tensor, "*#N"]:
        """(M6) Knot ``t_k`` of the step grid ``t_{k+1} = t_k + max(step, cone * t_k)`` from ``t_0``.

        Closed form: ``t_0 + k step`` up to the knot ``k1`` (the first with ``t >= step / cone``, at
        ``t1``), then geometric ``t1 (1 + cone)^(k - k1)``.
        """
        linear = t0 + k * self.cfg.step_size
        if self.cfg.cone_angle <= 0:
            return linear
        return torch.where(k <= k1, linear, t1 * torch.exp((k - k1) * math.log1p(self.cfg.cone_angle)))

    def _k_of_t(
        self, t: Float[Tensor, " R"], t0: Float[Tensor, " R"], k1: Float[Tensor, " R"], t1: Float[Tensor, " R"]
    ) -> Float[Tensor, " R"]:
        """Index of the step containing ``t`` (inverse of :meth:`_t_of_k`, up to rounding), ``>= 0``."""
        step, cone = self.cfg.step_size, self.cfg.cone_angle
        k = torch.floor((t - t0) / step)
        if cone > 0:
            geometric = k1 + torch.floor(torch.log(torch.clamp(t / t1, min=1.0)) / math.log1p(cone))
            k = torch.where(t < t1, k, geometric)
        return torch.clamp(k, min=0.0)

    def _block_grid(self) -> Bool[Tensor, "B B B"]:
        """Occupancy of ``8^3``-cell blocks, dilated by one block (3x3x3 max-pool)."""
        res, b = self.resolution, _BLOCK
        n = -(-res // b)
        grid = self.occupied.view(res, res, res)
        if n * b != res:
            grid = nn.functional.pad(grid, (0, n * b - res, 0, n * b - res, 0, n * b - res))
        blocks = grid.view(n, b, n, b, n, b).any(dim=5).any(dim=3).any(dim=1)
        dilated = nn.functional.max_pool3d(blocks[None, None].to(torch.float32), 3, stride=1, padding=1)
        return dilated[0, 0] > 0

    def _scan(
        self, params: Float[Tensor, "U 13"], knots: Int[Tensor, " U"], grid: Bool[Tensor, "N N N"], coarse: bool
    ) -> tuple[Int[Tensor, " K"], Float[Tensor, " K"], Float[Tensor, " K"], Float[Tensor, " K"], Float[Tensor, " K"]]:
        """Steps between consecutive knots of each unit whose midpoint lies in an occupied ``grid`` cell.

        A unit is a run of knots ``k_j = min(k_start + stride j, k_end)``, ``j < knots``, of one ray
        (``params`` columns: origin and direction in cell units (6), ``t_0, k1, t1, t_max, k_start,
        stride, k_end``). ``coarse``: ``grid`` is the dilated block grid, looked up with clamped block
        coordinates and no ``t_max`` test. Units are padded to the longest one and processed in chunks
        of at most ``_STEP_BUDGET`` knots. Returns (unit, t_start, t_end, k_start, k_end) of the kept
        steps, sorted by unit then ``k``.
        """
        device = params.device
        res = grid.shape[0]
        scale = 1.0 / _BLOCK if coarse else 1.0
        flat_grid = grid.reshape(-1)
        width = int(knots.max()) if knots.shape[0] else 0
        outputs = []
        if width >= 2:
            local = torch.arange(width, device=device, dtype=torch.float32)
            rows = max(1, _STEP_BUDGET // width)
            for a in range(0, knots.shape[0], rows):
                p = params[a : a + rows].t()[:, :, None]  # 13 x [U, 1]
                k = torch.minimum(p[10] + p[11] * local, p[12])
                t = self._t_of_k(k, p[6], p[7], p[8])
                # Step j = [t_j, t_{j+1}] for j < knots - 1.
                t_start, t_end = t[:, :-1], t[:, 1:]
                valid = local[:-1] < (knots[a : a + rows, None] - 1)
                if not coarse:
                    valid &= t_end <= p[9]
                mid = 0.5 * (t_start + t_end)
                flat = torch.zeros_like(mid)
                for axis in range(3):
                    cell = torch.floor((p[axis] + mid * p[3 + axis]) * scale)
                    if not coarse:
                        valid &= (cell >= 0) & (cell < res)
                    flat = flat * res + cell.clamp_(0, res - 1)
                valid &= flat_grid.index_select(0, flat.reshape(-1).long()).view_as(valid)
                sel = torch.nonzero(valid.reshape(-1))[:, 0]
                unit = a + torch.div(sel, width - 1, rounding_mode="floor")
                values = (x.reshape(-1).index_select(0, sel) for x in (t_start, t_end, k[:, :-1], k[:, 1:]))
                outputs.append((unit, *values))
        if not outputs:
            empty = torch.zeros(0, device=device)
            return torch.zeros(0, dtype=torch.long, device=device), empty, empty, empty, empty
        unit, t_start, t_end, k_start, k_end = (torch.cat(parts) for parts in zip(*outputs, strict=True))
        return unit, t_start, t_end, k_start, k_end

    @torch.no_grad()
    def march(
        self,
        origins: Float[Tensor, "R 3"],
        dirs: Float[Tensor, "R 3"],
        jitter: bool,
        generator: torch.Generator | None = None,
    ) -> Samples:
        """(M6) Packed samples of the rays ``o + t d`` (unit ``d``) through occupied cells.

        Each ray is clipped to the AABB and to ``[near, far]`` giving ``[t_min, t_max]``, and stepped
        from ``t_0 = t_min`` (plus ``U[0, step_size)`` when ``jitter``, nerfacc's stratified offset) by
        ``dt(t) = max(step_size, cone_angle * t)``. Step ``[t_k, t_{k+1}]`` (with ``t_{k+1} <= t_max``)
        is a sample if its midpoint lies in an occupied cell; at most ``max_samples_per_ray`` (the
        first ones) per ray. Deterministic unless ``jitter``.

        Empty-space skipping (exact, same samples): only steps within the bounding box of the occupied
        cells are considered, first in runs of up to 32 steps short enough that every midpoint of a
        run lies in the dilated block (``8^3`` cells) of the run's midpoint; the steps of runs whose
        dilated block is occupied are then tested cell by cell. At most ``2^21`` steps at once.
        """
        cfg = self.cfg
        device = origins.device
        n_rays = origins.shape[0]
        empty = Samples(
            torch.zeros(0, dtype=torch.long, device=device),
            torch.zeros(0, device=device),
            torch.zeros(0, device=device),
            n_rays,
        )
        box, block_grid = self._skip_structures()
        if box is None or n_rays == 0:
            return empty
        origins, dirs = origins.detach().to(torch.float32), dirs.detach().to(torch.float32)
        t_min, t_max = ray_aabb(origins, dirs, self.aabb[0], self.aabb[1])
        t_min = torch.clamp(t_min, min=cfg.near)
        t_max = torch.clamp(t_max, max=cfg.far)
        t0 = t_min
        if jitter:
            t0 = t0 + torch.rand(n_rays, generator=generator, device=device) * cfg.step_size
        if cfg.cone_angle > 0:
            k1 = torch.clamp(torch.ceil((cfg.step_size / cfg.cone_angle - t0) / cfg.step_size), min=0.0)
        else:
            k1 = torch.zeros_like(t0)
        t1 = t0 + k1 * cfg.step_size
        # Steps whose midpoint can be occupied lie in [s_min, s_max]; one step of margin for rounding.
        s_min, s_max = ray_aabb(origins, dirs, box[0], box[1])
        s_min, s_max = torch.maximum(s_min, t0), torch.minimum(s_max, t_max)
        hit = s_max > s_min
        k_lo = torch.clamp(self._k_of_t(s_min, t0, k1, t1) - 1.0, min=0.0)
        k_hi = torch.where(hit, self._k_of_t(s_max, t0, k1, t1) + 2.0, k_lo)
        # Run length: half a run (<= stride * dt_max / 2) must move less than one block (8 cells) along
        # every axis; dt_max bounds the steps up to k_hi (<= 3 steps past s_max).
        inv_cell = 1.0 / self.cell_size
        far_t = s_max * (1.0 + cfg.cone_angle) ** 3 + 3.0 * cfg.step_size
        dt_max = torch.clamp(cfg.cone_angle * far_t, min=cfg.step_size)
        reach = 0.99 * 2.0 * _BLOCK / (dirs.abs() * inv_cell).amax(-1).clamp(min=1e-12)
        stride = torch.clamp(torch.floor(reach / dt_max), 1.0, _MAX_RUN)
        params = torch.cat(
            [
                (origins - self.aabb[0]) * inv_cell,  # origin in cell units
                dirs * inv_cell,  # direction in cell units
                torch.stack([t0, k1, t1, t_max, k_lo, stride, k_hi], dim=-1),
            ],
            dim=-1,
        )
        runs = torch.ceil((k_hi - k_lo) / stride).long()
        knots = torch.where(hit, runs + 1, 0)
        run_ray, _, _, run_start, run_end = self._scan(params, knots, block_grid, coarse=True)
        fine = params.index_select(0, run_ray)
        fine[:, 10], fine[:, 11], fine[:, 12] = run_start, 1.0, run_end
        unit, t_start, t_end, _, _ = self._scan(fine, (run_end - run_start).long() + 1, self._fine_grid(), coarse=False)
        return self._cap(Samples(run_ray.index_select(0, unit), t_start, t_end, n_rays))

    def _fine_grid(self) -> Bool[Tensor, "N N N"]:
        """``occupied`` as a ``[res, res, res]`` view."""
        res = self.resolution
        return self.occupied.view(res, res, res)

    def _cap(self, samples: Samples) -> Samples:
        """Keep the first ``max_samples_per_ray`` samples of each ray."""
        limit = self.cfg.max_samples_per_ray
        counts = torch.bincount(samples.ray_idx, minlength=samples.n_rays)
        if samples.num_samples == 0 or int(counts.max()) <= limit:
            return samples
        first = torch.cumsum(counts, 0) - counts
        rank = torch.arange(samples.num_samples, device=counts.device) - first[samples.ray_idx]
        return samples.select(rank < limit)
