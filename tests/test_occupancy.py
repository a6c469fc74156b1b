"""Occupancy grid update (M5) and ray marching (M6), METHOD.md section 4."""

import math

import pytest
import torch

import nvf.occupancy as occupancy
from nvf.config import SamplerConfig
from nvf.occupancy import OccupancyGrid, ray_aabb

AABB = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
RADIUS = 0.5


def sphere_density(x: torch.Tensor) -> torch.Tensor:
    return torch.where(x.norm(dim=-1) < RADIUS, 200.0, 0.0)


def sphere_grid(**overrides) -> OccupancyGrid:
    grid = OccupancyGrid(AABB, SamplerConfig(grid_resolution=32, **overrides))
    grid.update(0, sphere_density, torch.Generator().manual_seed(0))
    return grid


def random_rays(n: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """Rays from 0.5-5.5 units off the centre aimed near it (some start inside, some miss the box)."""
    gen = torch.Generator().manual_seed(seed)
    distance = 0.5 + torch.rand(n, 1, generator=gen) * 5.0
    origins = torch.nn.functional.normalize(torch.randn(n, 3, generator=gen), dim=-1) * distance
    target = (torch.rand(n, 3, generator=gen) - 0.5) * 3.0
    return origins, torch.nn.functional.normalize(target - origins, dim=-1)


def cell_of(grid: OccupancyGrid, x: torch.Tensor) -> torch.Tensor:
    res = grid.resolution
    c = torch.floor((x - AABB[0]) / grid.cell_size).long().clamp(0, res - 1)
    return (c[:, 0] * res + c[:, 1]) * res + c[:, 2]


def reference_march(grid: OccupancyGrid, o: torch.Tensor, d: torch.Tensor, t0: float) -> list[tuple[float, float]]:
    """M6 by iteration, one ray, float64: t_{k+1} = t_k + max(step, cone t_k)."""
    cfg = grid.cfg
    _, t_max = ray_aabb(o[None], d[None], AABB[0], AABB[1])
    t_max = min(float(t_max), cfg.far)
    out, t = [], t0
    while True:
        t_next = t + max(cfg.step_size, cfg.cone_angle * t)
        if t_next > t_max:
            return out
        mid = o.double() + 0.5 * (t + t_next) * d.double()
        if bool(grid.occupied[cell_of(grid, mid[None].float())]) and bool(((mid > -1) & (mid < 1)).all()):
            out.append((t, t_next))
        t = t_next


def test_update_marks_sphere_cells() -> None:
    """M5: after a warm-up update the sphere's cells are occupied and empty space is not."""
    grid = sphere_grid()
    centers = grid.cell_centers()
    r = centers.norm(dim=-1)
    half_diag = float(grid.cell_size.norm()) / 2
    assert grid.occupied[r < RADIUS - half_diag].all()
    assert not grid.occupied[r > RADIUS + half_diag].any()
    assert math.isclose(grid.mean_occupancy, float(grid.occ.mean()))
    inside = r < RADIUS - half_diag
    torch.testing.assert_close(grid.occ[inside], torch.full_like(grid.occ[inside], 200.0 * grid.cfg.step_size))


def test_mark_observed_marks_exactly_the_cells_of_the_points() -> None:
    """``observed`` (read by M29 with ``planner.los_unobserved_free``): the cells holding the points, none
    for points outside the AABB, and it only grows."""
    grid = OccupancyGrid(AABB, SamplerConfig(grid_resolution=8))
    x = torch.tensor([[0.1, 0.1, 0.1], [0.12, 0.13, 0.11], [-0.9, 0.5, 0.3], [1.5, 0.0, 0.0]])
    assert not grid.is_observed(x).any()
    grid.mark_observed(x)
    expected = torch.zeros(8**3, dtype=torch.bool)
    expected[cell_of(grid, x[:3])] = True
    assert torch.equal(grid.observed, expected) and int(grid.observed.sum()) == 2
    assert grid.is_observed(x).tolist() == [True, True, True, False]
    grid.mark_observed(torch.tensor([[0.9, 0.9, 0.9]]))
    assert int(grid.observed.sum()) == 3 and grid.observed[expected].all()


def test_update_schedule_decay_and_threshold() -> None:
    """M5: no-op off the update period; occ <- max(decay occ, sigma step); occupied = occ > min(mean, thr)."""
    grid = sphere_grid()
    before = grid.occ.clone()
    grid.update(3, lambda x: torch.zeros(x.shape[0]), None)  # 3 % 16 != 0
    assert torch.equal(grid.occ, before)
    grid.update(16, lambda x: torch.zeros(x.shape[0]), None)  # warm-up: every cell, decayed
    torch.testing.assert_close(grid.occ, before * grid.cfg.occ_decay)
    threshold = min(float(grid.occ.mean()), grid.cfg.occ_threshold)
    assert torch.equal(grid.occupied, grid.occ > threshold)
    # After warm-up: cells/4 uniform + cells/4 among occupied; an unevaluated cell keeps its value.
    gen = torch.Generator().manual_seed(1)
    grid.update(grid.cfg.warmup_iters, lambda x: torch.zeros(x.shape[0]), gen)
    changed = grid.occ != before * grid.cfg.occ_decay
    assert 0 < int(changed.sum()) < grid.occ.numel()
    assert torch.all(grid.occ[changed] < before[changed] * grid.cfg.occ_decay)


def test_march_samples_are_valid() -> None:
    """M6: samples sorted, inside the box, midpoints in occupied cells, dt = max(step, cone t)."""
    grid = sphere_grid()  # step / cone = 1.73: both regimes of dt occur
    origins, dirs = random_rays(400)
    s = grid.march(origins, dirs, jitter=False)
    assert s.num_samples > 1000 and s.n_rays == 400
    assert (s.t_start < 1.7).any() and (s.t_start > 1.8).any()
    key = s.ray_idx.double() * 1e4 + s.t_start.double()
    assert torch.all(key[1:] > key[:-1])
    x = origins[s.ray_idx] + s.t_mid[:, None] * dirs[s.ray_idx]
    assert torch.all(x.abs() <= 1.0)
    assert grid.occupied[cell_of(grid, x)].all()
    expected_dt = torch.clamp(grid.cfg.cone_angle * s.t_start, min=grid.cfg.step_size)
    torch.testing.assert_close(s.deltas, expected_dt, rtol=1e-4, atol=1e-6)
    assert torch.all(s.t_start >= grid.cfg.near)


@pytest.mark.parametrize("cone_angle", [0.0, 0.004, 0.05])
def test_march_matches_iterative_reference(cone_angle: float) -> None:
    """M6: the closed-form step grid equals stepping t_{k+1} = t_k + max(step, cone t_k) from the box entry."""
    grid = sphere_grid(cone_angle=cone_angle)
    origins, dirs = random_rays(12, seed=3)
    s = grid.march(origins, dirs, jitter=False)
    t_entry, _ = ray_aabb(origins, dirs, AABB[0], AABB[1])
    for r in range(12):
        ref = reference_march(grid, origins[r], dirs[r], max(float(t_entry[r]), grid.cfg.near))
        got = s.select(s.ray_idx == r)
        assert got.num_samples == len(ref)
        if ref:
            torch.testing.assert_close(got.t_start, torch.tensor([a for a, _ in ref]), rtol=1e-5, atol=1e-5)
            torch.testing.assert_close(got.t_end, torch.tensor([b for _, b in ref]), rtol=1e-5, atol=1e-5)


def test_march_misses_jitter_and_near() -> None:
    """M6: rays missing the box or pointing away get nothing; jitter shifts the start by U[0, step)."""
    grid = sphere_grid()
    origins = torch.tensor([[0.0, 0.0, 3.0], [0.0, 0.0, 3.0], [0.0, 3.0, 3.0], [0.0, 0.0, 0.0]])
    dirs = torch.tensor([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    s = grid.march(origins, dirs, jitter=False)
    counts = torch.bincount(s.ray_idx, minlength=4)
    assert counts[0] > 0 and counts[1] == 0 and counts[2] == 0 and counts[3] > 0
    # A ray starting inside the sphere starts at the near plane.
    assert math.isclose(float(s.t_start[s.ray_idx == 3][0]), grid.cfg.near, rel_tol=1e-6)
    again = grid.march(origins, dirs, jitter=False)
    assert torch.equal(s.t_start, again.t_start) and torch.equal(s.ray_idx, again.ray_idx)
    gen = torch.Generator().manual_seed(0)
    jittered = grid.march(origins[:1], dirs[:1], jitter=True, generator=gen)
    offset = (float(jittered.t_start[0]) - 2.0) % grid.cfg.step_size  # box entry at t = 2
    assert 0 < offset < grid.cfg.step_size and not torch.equal(jittered.t_start, s.t_start[: jittered.num_samples])


def test_march_empty_grid_and_no_rays() -> None:
    """M6: an empty grid (before any update) or R = 0 gives S = 0."""
    grid = OccupancyGrid(AABB, SamplerConfig(grid_resolution=16))
    origins, dirs = random_rays(10)
    assert grid.march(origins, dirs, jitter=False).num_samples == 0
    s = sphere_grid().march(torch.zeros(0, 3), torch.zeros(0, 3), jitter=False)
    assert s.num_samples == 0 and s.n_rays == 0


def test_march_chunking_and_cap(monkeypatch: pytest.MonkeyPatch) -> None:
    """Memory-bounded chunks give the same samples; the per-ray cap keeps the first samples."""
    grid = sphere_grid()
    origins, dirs = random_rays(300)
    full = grid.march(origins, dirs, jitter=False)
    monkeypatch.setattr(occupancy, "_STEP_BUDGET", 997)
    chunked = grid.march(origins, dirs, jitter=False)
    assert torch.equal(full.ray_idx, chunked.ray_idx) and torch.equal(full.t_start, chunked.t_start)
    capped_grid = sphere_grid(max_samples_per_ray=7)
    capped = capped_grid.march(origins, dirs, jitter=False)
    counts = torch.bincount(full.ray_idx, minlength=300)
    assert torch.equal(torch.bincount(capped.ray_idx, minlength=300), counts.clamp(max=7))
    first = full.select(torch.arange(full.num_samples) - (counts.cumsum(0) - counts)[full.ray_idx] < 7)
    assert torch.equal(first.t_start, capped.t_start)


@pytest.mark.parametrize("distance", [1.5, 40.0])
def test_empty_space_skipping_is_exact_on_scattered_cells(distance: float) -> None:
    """M6: block-level skipping never drops a step whose midpoint is in an isolated occupied cell."""
    grid = OccupancyGrid(AABB, SamplerConfig(grid_resolution=32))
    gen = torch.Generator().manual_seed(5)
    grid.occupied.copy_(torch.rand(grid.occupied.shape, generator=gen) < 0.02)
    origins, dirs = random_rays(10, seed=7)
    origins = origins / origins.norm(dim=-1, keepdim=True) * distance
    dirs = torch.nn.functional.normalize((torch.rand(10, 3, generator=gen) - 0.5) * 1.2 - origins, dim=-1)
    s = grid.march(origins, dirs, jitter=False)
    t_entry, _ = ray_aabb(origins, dirs, AABB[0], AABB[1])
    total = 0
    for r in range(10):
        ref = reference_march(grid, origins[r], dirs[r], max(float(t_entry[r]), grid.cfg.near))
        got = s.select(s.ray_idx == r)
        assert got.num_samples == len(ref)
        total += len(ref)
        if ref:
            torch.testing.assert_close(got.t_start, torch.tensor([a for a, _ in ref]), rtol=1e-5, atol=1e-5)
    assert total > 0


def test_march_follows_grid_changes_after_caching() -> None:
    """The cached skipping structures are rebuilt when ``occupied`` changes (update, load_state_dict)."""
    o, d = random_rays(256)
    grid = sphere_grid()
    grid.march(o, d, jitter=False)  # fills the cache
    grid.update(16, lambda x: torch.where(x[:, 0] > 0.0, 200.0, 0.0), torch.Generator().manual_seed(1))
    fresh = OccupancyGrid(AABB, grid.cfg)
    fresh.load_state_dict(grid.state_dict())
    updated, expected = grid.march(o, d, jitter=False), fresh.march(o, d, jitter=False)
    assert torch.equal(updated.t_start, expected.t_start) and torch.equal(updated.ray_idx, expected.ray_idx)
    grid.load_state_dict(sphere_grid().state_dict())
    reloaded, original = grid.march(o, d, jitter=False), sphere_grid().march(o, d, jitter=False)
    assert torch.equal(reloaded.t_start, original.t_start) and torch.equal(reloaded.ray_idx, original.ray_idx)
