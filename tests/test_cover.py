"""nvf/cover.py: COVER's direction bins (M37), an element's coverage from a candidate (M38) and a view's score
(M39); ``method=cover`` at the smoke budget."""

import dataclasses

import torch

from nvf.cameras import Intrinsics, look_at, pixel_rays
from nvf.config import FieldConfig, SamplerConfig
from nvf.cover import ALPHA_FLOOR, CoverScorer, element_coverage, fibonacci_sphere, observed_bins
from nvf.model import SceneModel
from nvf.observations import Observations
from nvf.seeding import generator_factory
from pipeline.config.validation import compose_run
from pipeline.episode.runner import run_episode

AABB = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
INTR = Intrinsics.from_fov(8, 8)


def ball_model() -> SceneModel:
    """A small untrained model, a cube of occupied cells at the centre of its box (no training needed)."""
    torch.manual_seed(0)
    model = SceneModel(
        AABB, FieldConfig(log2_hashmap_size=10, num_levels=4, max_resolution=32), SamplerConfig(grid_resolution=8)
    )
    centres = model.grid.cell_centers()
    model.grid.occupied[:] = (centres.abs() < 0.5).all(dim=-1)
    return model


def test_fibonacci_sphere_spreads_unit_directions_over_the_whole_sphere():
    u = fibonacci_sphere(128)
    torch.testing.assert_close(u.norm(dim=-1), torch.ones(128))
    assert u[:, 2].min() < -0.99 and u[:, 2].max() > 0.99 and u.mean(0).abs().max() < 0.02
    nearest = (u @ u.T - 2 * torch.eye(128)).amax(dim=1)  # no two bins coincide
    assert nearest.max() < 0.99


def test_an_element_is_seen_from_the_bin_nearest_the_camera_and_only_in_the_frustum():
    """(M37) A camera on +x looking at the origin sees the points in its frustum from the bin nearest -x (the
    direction from the camera to them); a point behind it is not seen."""
    u = fibonacci_sphere(64)
    camera = look_at(torch.tensor([3.0, 0.0, 0.0]), torch.zeros(3))
    points = torch.tensor([[0.0, 0.0, 0.0], [0.2, 0.3, 0.1], [5.0, 0.0, 0.0]])
    seen = observed_bins(points, camera[None], INTR, u)
    assert seen.sum(dim=1).tolist() == [1, 1, 0]
    assert seen[0, (u @ torch.tensor([-1.0, 0.0, 0.0])).argmax()]


def test_coverage_is_one_along_an_observed_bin_and_zero_opposite_or_unseen():
    """(M38) ``m = max_b (1 + d . u_b) / 2`` over observed bins: 1 looking along one, 0 from the opposite side, 0 for
    an element nobody saw."""
    u = torch.tensor([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    element = torch.zeros(2, 3)
    seen = torch.tensor([[True, False], [False, False]])
    behind = element_coverage(element, seen, u, torch.tensor([-2.0, 0.0, 0.0]))  # looks along +x: the observed bin
    front = element_coverage(element, seen, u, torch.tensor([2.0, 0.0, 0.0]))
    assert behind.tolist() == [1.0, 0.0] and front.tolist() == [0.0, 0.0]


def test_a_candidate_seeing_an_unseen_side_scores_above_one_seeing_covered_directions():
    """(M39) Training views from +x: a candidate beside them sees only covered directions and scores near 0; one
    from +y sees the ball from across the observed bins and scores more, one from -x (the unseen side) most; scores
    lie in [0, 1] (an untrained field is faint: its opacity, the most a pixel adds, stays far below 1)."""
    model = ball_model()
    train = torch.stack([look_at(torch.tensor([2.6, y, 0.3]), torch.zeros(3)) for y in (-0.5, 0.5)])
    obs = Observations(torch.zeros(2, 8, 8, 4), train, INTR)
    views = CoverScorer(bins=64).prepare(model, obs, generator_factory(0, 0, "cpu"), 4096)

    def score(position: list[float]) -> float:
        return float(views.view_score(model, *pixel_rays(look_at(torch.tensor(position), torch.zeros(3)), INTR), 16))

    covered, across, unseen = score([2.6, 0.0, 0.2]), score([0.0, 2.6, 0.2]), score([-2.6, 0.0, 0.2])
    assert 0.0 <= covered < across < unseen <= 1.0 and unseen > 10 * covered


def test_cells_no_training_view_holds_are_not_elements_and_a_view_of_them_alone_scores_nothing():
    """(M37, M39) Gaussians exist only where training views put geometry: an occupied cell outside every training
    frustum (a slab on the box's top, beyond narrow views of the ball from +x) is not an element, and a candidate
    that sees only such cells has nothing to cover and scores 0."""
    model = ball_model()
    model.grid.occupied |= model.grid.cell_centers()[:, 2] > 0.75
    narrow = Intrinsics.from_fov(8, 8, 20.0)
    train = torch.stack([look_at(torch.tensor([2.6, y, 0.0]), torch.zeros(3)) for y in (-0.2, 0.2)])
    obs = Observations(torch.zeros(2, 8, 8, 4), train, narrow)
    views = CoverScorer(bins=64).prepare(model, obs, generator_factory(0, 0, "cpu"), 4096)
    assert 0 < views.elements.shape[0] and views.elements[:, 2].max() < 0.75
    assert bool(views.seen.any(dim=-1).all())
    slab = look_at(torch.tensor([-2.6, 0.0, 0.875]), torch.tensor([0.0, 0.0, 0.875]))
    origins, dirs = pixel_rays(slab, Intrinsics.from_fov(8, 8, 10.0))
    assert model.render(origins, dirs, heads=frozenset({"rgb"})).samples.ray_idx.numel() > 0  # it sees the slab
    assert float(views.view_score(model, origins, dirs, 16)) == 0.0


def test_a_view_reads_the_coverage_of_the_elements_its_samples_reach_as_of_every_element():
    """(M39) ``view_score`` takes M38 only for the elements its samples reach; the score is bitwise the one that
    takes every element's coverage first and reads it at the samples the rasteriser would composite (in an
    element's cell, opacity at least 1/255; M39 as written)."""
    model = ball_model()
    train = torch.stack([look_at(torch.tensor([2.6, y, 0.3]), torch.zeros(3)) for y in (-0.5, 0.5)])
    obs = Observations(torch.zeros(2, 8, 8, 4), train, INTR)
    views = CoverScorer(bins=64).prepare(model, obs, generator_factory(0, 0, "cpu"), 4096)
    origins, dirs = pixel_rays(look_at(torch.tensor([-2.0, 1.0, 0.5]), torch.zeros(3)), INTR)
    every = element_coverage(views.elements, views.seen, views.directions, origins[0])
    result = model.render(origins, dirs, heads=frozenset({"rgb"}))
    x = origins[result.samples.ray_idx] + result.samples.t_mid[:, None] * dirs[result.samples.ray_idx]
    cell, inside = model.grid.cell_index(x)
    element = torch.where(inside, views.element_of[cell], -1)
    kept = (element >= 0) & (result.alpha >= ALPHA_FLOOR)
    m = torch.where(kept, every[element.clamp(min=0)], torch.zeros_like(result.weights)).to(torch.float64)
    w = torch.where(kept, result.weights, torch.zeros_like(result.weights)).to(torch.float64).detach()
    composite = torch.zeros(origins.shape[0], dtype=torch.float64).index_add_(0, result.samples.ray_idx, w * m)
    opacity = torch.zeros(origins.shape[0], dtype=torch.float64).index_add_(0, result.samples.ray_idx, w)
    assert bool((m > 0).any())
    assert torch.equal(views.view_score(model, origins, dirs, 4096), (opacity - composite).mean())  # mean A - M
    chunked = views.opacity_and_coverage(model, origins, dirs, 5)  # chunks of rays place their pixels alike
    torch.testing.assert_close(chunked, (opacity, composite), rtol=1e-12, atol=1e-12)


class Faint(torch.nn.Module):
    """``model`` rendering as if its density were scaled by ``scale`` (alphas and weights at first order)."""

    def __init__(self, model: SceneModel, scale: float):
        super().__init__()
        self.model, self.grid, self.scale = model, model.grid, scale

    def render(self, origins, dirs, heads):
        result = self.model.render(origins, dirs, heads=heads)
        return dataclasses.replace(result, alpha=result.alpha * self.scale, weights=result.weights * self.scale)


def test_samples_below_the_rasterisers_opacity_floor_are_not_composited():
    """(M39) The 3DGS rasteriser composites no Gaussian below opacity 1/255: a view through a field that faint
    everywhere has nothing to cover and scores 0, where the field as it is scores above 0."""
    model = ball_model()
    train = torch.stack([look_at(torch.tensor([2.6, y, 0.3]), torch.zeros(3)) for y in (-0.5, 0.5)])
    obs = Observations(torch.zeros(2, 8, 8, 4), train, INTR)
    views = CoverScorer(bins=64).prepare(model, obs, generator_factory(0, 0, "cpu"), 4096)
    origins, dirs = pixel_rays(look_at(torch.tensor([-2.6, 0.0, 0.2]), torch.zeros(3)), INTR)
    result = model.render(origins, dirs, heads=frozenset({"rgb"}))
    scale = 0.5 * ALPHA_FLOOR / float(result.alpha.detach().max())
    assert float(views.view_score(model, origins, dirs, 16)) > 0.01
    assert float(views.view_score(Faint(model, scale), origins, dirs, 16)) == 0.0


def test_cover_runs_an_episode_at_the_smoke_budget(tmp_path):
    run = compose_run(
        ["budget=smoke", "scene=default", "method=cover", "budget.horizon=2", f"paths.outputs={tmp_path}"]
    )
    assert run_episode(run).status == "done"
