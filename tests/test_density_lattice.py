"""nvf.density_lattice: M17's density read from a lattice (``train.label_lattice``), its kernel and its labels."""

import math

import pytest
import torch

from nvf import kernels
from nvf.cameras import Intrinsics, look_at
from nvf.config import SamplerConfig, TrainConfig
from nvf.density_lattice import DensityLattice, lattice_vertices
from nvf.occupancy import OccupancyGrid
from nvf.visibility import segment_transmittance, visibility_labels

AABB = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


def affine(x: torch.Tensor) -> torch.Tensor:
    return 2.0 + x @ torch.tensor([0.3, -0.5, 0.7])


def shell(x: torch.Tensor) -> torch.Tensor:
    """A smooth opaque shell of radius 0.5 in a thin fog."""
    return 30.0 * torch.exp(-(((x.norm(dim=-1) - 0.5) / 0.08) ** 2)) + 0.5


def grid_of(density, resolution: int) -> OccupancyGrid:
    grid = OccupancyGrid(AABB, SamplerConfig(grid_resolution=resolution))
    grid.occupied[:] = density(grid.cell_centers()) > 1.0
    return grid


def masked(density, grid: OccupancyGrid):
    return lambda x: torch.where(grid.is_occupied(x), density(x), 0.0)


def support_box(grid: OccupancyGrid) -> torch.Tensor:
    lo, hi = grid.occupied_box()
    return torch.stack([lo - 0.5 * grid.cell_size, hi + 0.5 * grid.cell_size])


def test_lattice_reads_a_trilinear_density_exactly_and_empty_cells_as_zero():
    """(M17) A density that trilinear interpolation reproduces is read back to rounding in the occupied cells, 0
    in the others, and only the occupied cells' vertices are evaluated."""
    grid = OccupancyGrid(AABB, SamplerConfig(grid_resolution=16))
    grid.occupied[torch.rand(16**3, generator=torch.Generator().manual_seed(0)) < 0.3] = True
    lattice = DensityLattice(affine, grid, 3, grid.occupied)
    x = torch.rand(50_000, 3, generator=torch.Generator().manual_seed(1)) * 2 - 1
    want = masked(affine, grid)(x)
    assert torch.allclose(lattice(x), want, atol=1e-5)
    assert (lattice(x)[~grid.is_occupied(x)] == 0).all() and (want[grid.is_occupied(x)] > 0).all()
    assert 0 < lattice.evaluated < lattice_vertices(16, 3)


def test_lattice_bounds_are_one_clear_error():
    grid = OccupancyGrid(AABB, SamplerConfig(grid_resolution=16))
    with pytest.raises(ValueError, match="subdivisions must be in 1..8"):
        DensityLattice(affine, grid, 0, grid.occupied)
    big = OccupancyGrid(AABB, SamplerConfig(grid_resolution=128))
    with pytest.raises(ValueError, match="fewer subdivisions"):
        DensityLattice(affine, big, 8, big.occupied)


@pytest.mark.skipif(kernels.labels() is None, reason="the label kernel did not build")
@pytest.mark.parametrize("cutoff", [0.0, 1e-3])
def test_kernel_sums_are_the_lattice_read_through_torch(cutoff):
    """(M17) On the CPU the kernel's one-pass sums are the transmittance the torch path gets from the same lattice
    (``grid_sample``) on the same samples: to rounding without the early stop; with it, each within the cutoff
    (the kernel stops per sample, torch per 32 bins)."""
    grid = grid_of(shell, 32)
    lattice = DensityLattice(shell, grid, 4, grid.occupied)
    points = torch.rand(3000, 3, generator=torch.Generator().manual_seed(3)) * 2 - 1
    origin, box = torch.tensor([0.1, -3.0, 0.2]), support_box(grid)
    out = {}
    for name, density in (("kernel", lattice), ("torch", lambda x: lattice(x))):
        draw = torch.Generator().manual_seed(1)
        out[name] = segment_transmittance(density, origin, points, 200, draw, box, 1 << 18, 0.0, grid, cutoff)
    assert (out["kernel"] - out["torch"]).abs().max() <= max(cutoff, 1e-6)
    assert (out["kernel"] < 0.01).any() and (out["kernel"] > 0.99).any()  # segments through the shell and beside it


def test_lattice_labels_stay_within_the_tolerance_of_the_exact_labels():
    """(M17, M18) Labels through a 4-times finer lattice against the field's own labels on the same samples: mean
    absolute difference <= 0.005 and none off by more than 0.05 (the paper-size speed-ups' tolerance), six cameras
    around a smooth shell; a 1-cell lattice is further off than a 4-times finer one."""
    grid = grid_of(shell, 32)
    cams = [[0.1, -3.0, 0.2], [3.0, 0.2, 0.1], [-2.0, 2.0, 1.0], [0.0, 0.5, 3.0], [-3.0, -0.5, 0.3], [0.4, 3.0, -0.6]]
    c2w = torch.stack([look_at(torch.tensor(p), torch.zeros(3)) for p in cams])
    points = torch.rand(3000, 3, generator=torch.Generator().manual_seed(10)) * 2 - 1
    intr, cfg, box = Intrinsics.from_fov(64, 64, 90.0), TrainConfig(label_samples=200), support_box(grid)

    def labels(density) -> torch.Tensor:
        return visibility_labels(density, points, c2w, intr, cfg, torch.Generator().manual_seed(1), box, grid=grid)

    exact = labels(masked(shell, grid))
    diff = {s: (labels(DensityLattice(shell, grid, s, grid.occupied)) - exact).abs() for s in (1, 4)}
    assert diff[4].mean() <= 0.005 and diff[4].max() <= 0.05
    assert diff[1].mean() > diff[4].mean()
    assert 0.05 < (exact < 0.5).float().mean() < 0.5  # the points inside the shell are hidden from every camera


def test_model_label_density_is_the_model_density_unless_asked():
    """``train.label_lattice=0`` keeps M17's density as it was (``SceneModel.density`` itself); above 0 the lattice
    reads the model's density at its vertices."""
    from nvf.config import FieldConfig
    from nvf.model import SceneModel

    model = SceneModel(AABB, FieldConfig(), SamplerConfig(grid_resolution=16))
    model.grid.occupied[: 16**3 // 2] = True
    assert model.label_density(0) == model.density
    lattice = model.label_density(2)
    assert isinstance(lattice, DensityLattice)
    vertex = AABB[0] + torch.tensor([[2, 3, 4], [5, 1, 9]], dtype=torch.float32) * (2.0 / 32)  # in occupied cells
    with torch.no_grad():
        assert torch.allclose(lattice(vertex), model.density(vertex), rtol=1e-4)
    assert math.isfinite(float(lattice.values.sum()))
