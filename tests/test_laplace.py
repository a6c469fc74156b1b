"""nvf/uncertainty/laplace.py: Bayes' Rays' perturbation-field Hessian (M34), variance (M35) and rendered
uncertainty (M36)."""

import torch

from nvf.cameras import Intrinsics, look_at, pixel_rays
from nvf.config import FieldConfig, SamplerConfig
from nvf.model import SceneModel
from nvf.observations import Observations
from nvf.uncertainty.laplace import BayesRaysScorer, PerturbationGrid, ray_hessian, ray_uncertainty

AABB = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
INTR = Intrinsics.from_fov(6, 6)


def ball_model() -> SceneModel:
    """A small model whose density is a soft ball, every grid cell occupied (no training needed)."""
    torch.manual_seed(0)
    model = SceneModel(
        AABB,
        FieldConfig(log2_hashmap_size=10, num_levels=4, max_resolution=32),
        SamplerConfig(grid_resolution=16),
    )
    model.grid.occupied[:] = True
    with torch.no_grad():
        model.field.encoding.table.normal_(0.0, 1.0)
    return model


def test_hessian_is_the_squared_jacobian_of_the_colours_with_respect_to_the_field():
    """(M34) The accumulated diagonal equals sum_r sum_ch sum_k (dC_{r,ch} / d theta_{v,k})^2 from autograd through
    an explicit perturbation field theta [V, 3] read trilinearly at every sample."""
    model, grid = ball_model(), PerturbationGrid(AABB, 2)
    origins, dirs = pixel_rays(look_at(torch.tensor([0.3, -2.5, 0.4]), torch.zeros(3)), INTR)
    got = ray_hessian(model, grid, origins, dirs)
    theta = torch.zeros(grid.vertices, 3, dtype=torch.float32, requires_grad=True)

    def perturbed(positions: torch.Tensor) -> torch.Tensor:
        index, weight = grid.corners(positions.detach())
        return positions + (weight[:, :, None] * theta[index]).sum(1)

    rgb = model.render(origins, dirs, displacement=perturbed).rgb
    expected = torch.zeros(grid.vertices, dtype=torch.float64)
    for r in range(rgb.shape[0]):
        for channel in range(3):
            (grad,) = torch.autograd.grad(rgb[r, channel], theta, retain_graph=True)
            expected += grad.to(torch.float64).square().sum(-1)
    assert expected.sum() > 0 and (expected > 0).sum() > 1
    torch.testing.assert_close(got, expected, rtol=1e-4, atol=1e-12)


def test_uncertainty_falls_where_a_view_is_added():
    """(M35, M36) A view's rendered uncertainty after it joins the training views is lower than before (on average
    and for most of its object rays: M35 divides the Hessian by the training pixels, so a vertex the new view
    hardly constrains can lose precision), and a view's score is the mean of its rays'."""
    model = ball_model()
    seen = torch.stack([look_at(torch.tensor([0.0, -2.6, 0.3]), torch.zeros(3))])
    new = look_at(torch.tensor([2.6, 0.0, 0.3]), torch.zeros(3))
    images = torch.zeros(2, 6, 6, 4)
    scorer = BayesRaysScorer(4)
    before = scorer.prepare(model, Observations(images[:1], seen, INTR), lambda purpose: torch.Generator(), 16)
    after = scorer.prepare(
        model, Observations(images, torch.cat([seen, new[None]]), INTR), lambda purpose: torch.Generator(), 16
    )
    origins, dirs = pixel_rays(new, INTR)
    u_before = ray_uncertainty(model, before.grid, before.variance, origins, dirs)
    u_after = ray_uncertainty(model, after.grid, after.variance, origins, dirs)
    assert ((u_before >= 0) & (u_before <= 1)).all()
    hit = u_before > 0
    assert hit.sum() > 4 and u_after.mean() < u_before.mean() - 0.01
    assert (u_after[hit] < u_before[hit]).float().mean() > 0.8
    assert torch.isclose(before.view_score(model, origins, dirs, 7), u_before.mean(), rtol=1e-6)


def test_a_perturbation_grid_too_large_to_allocate_is_one_line(capsys):
    """``method.cells_per_grid_cell=1000`` made M34's grid 2.6e14 vertices and died allocating it (262 TB); now the
    setting is refused before any work, naming the key."""
    import pytest

    from pipeline.config.validation import compose_run

    with pytest.raises(SystemExit) as exit_:
        compose_run(["method=bayesrays", "method.cells_per_grid_cell=1000"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "cells_per_grid_cell=1000" in err and "2^28" in err and err.count("\n") == 1
    assert compose_run(["method=bayesrays", "budget=paper"]).method.unsupported() is None  # the paper's 256^3
