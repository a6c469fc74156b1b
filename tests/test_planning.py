"""nvf/planning.py: candidates (METHOD 13), density filter (M28), line of sight (M29), argmax
selection, -OPT (METHOD 14) and determinism (PROTOCOL 3).

Uses analytic stand-ins: a field with a Gaussian blob and optional wall slabs (density 0 outside
the AABB), a model that renders packed samples at fixed t (differentiable in origins and dirs), a
scorer whose per-ray score is the accumulated opacity, and the real scorers of nvf.uncertainty.
"""

import math
from dataclasses import replace

import pytest
import torch
from torch import nn

from nvf.cameras import Intrinsics, look_at, matrix_to_pose
from nvf.config import (
    DepthMode,
    EntropyConfig,
    HashBackend,
    LineOfSightSource,
    OptConfig,
    Planner,
    PlannerConfig,
    PoseParam,
)
from nvf.model import RenderResult
from nvf.planning import (
    NoCandidatesError,
    argmax_first,
    candidate_poses,
    ray_subset,
    refine_poses,
    sample_poses,
    score_poses,
    select_next_view,
    top_k_first,
)
from nvf.rendering import Samples, alpha_from_density, expected_depth, ray_sum, weights_from_alpha
from nvf.seeding import generator_factory, seeded_generator
from nvf.uncertainty import ViewScorer
from pipeline.config.catalog import method_configs
from pipeline.config.method import build_method

AABB = torch.tensor([[-2.0, -2.0, -2.0], [2.0, 2.0, 2.0]])
BOX = torch.tensor([[-1.9, -1.9, -1.9], [1.9, 1.9, 1.9]])
INTR = Intrinsics.from_fov(8, 8)


class ToyField(nn.Module):
    """Gaussian blob (peak ``peak`` at ``centre``, std ``width``) plus slabs ``|x - wall| < 0.05``."""

    def __init__(self, peak=50.0, centre=(0.0, 0.0, 0.0), width=0.4, walls=(), wall_sigma=1e3):
        super().__init__()
        self.peak, self.width, self.walls, self.wall_sigma = peak, width, walls, wall_sigma
        self.register_buffer("centre", torch.tensor(centre))

    def density(self, x):
        sigma = self.peak * torch.exp(-((x - self.centre) ** 2).sum(-1) / (2 * self.width**2))
        for wall in self.walls:
            sigma = sigma + self.wall_sigma * ((x[:, 0] - wall).abs() < 0.05).to(x)
        inside = ((x >= AABB[0]) & (x <= AABB[1])).all(-1)
        return torch.where(inside, sigma, torch.zeros_like(sigma)), torch.zeros(x.shape[0], 15)


class ToyModel(nn.Module):
    """SceneModel stand-in: ``render`` packs 32 fixed samples per ray on t in [0.05, 4] into a
    RenderResult (M1-M3); rgb, variance and visibility are smooth functions of x."""

    def __init__(self, field, observed_below=math.inf):
        super().__init__()
        self.field = field
        self.observed_below = observed_below  # training samples reached only x < observed_below
        self.register_buffer("aabb", AABB.clone())
        self.calls = []

    def density(self, x):
        return self.field.density(x)[0]

    def observed_density(self, x):
        return torch.where(x[:, 0] < self.observed_below, self.density(x), torch.zeros(x.shape[0]))

    def render(self, origins, dirs, heads=frozenset({"rgb"}), train=False, generator=None, sampler="occupancy"):
        self.calls.append((heads, train, sampler))
        n_rays, n = origins.shape[0], 32
        edges = torch.linspace(0.05, 4.0, n + 1)
        samples = Samples(
            torch.arange(n_rays).repeat_interleave(n), edges[:-1].repeat(n_rays), edges[1:].repeat(n_rays), n_rays
        )
        x = samples.positions(origins, dirs)
        sigma = self.field.density(x)[0]
        alpha = alpha_from_density(sigma, samples.deltas)
        weights, trans = weights_from_alpha(alpha, samples.ray_idx, n_rays)
        rgb_s = torch.sigmoid(x + dirs[samples.ray_idx])
        return RenderResult(
            samples=samples,
            sigma=sigma,
            alpha=alpha,
            weights=weights,
            trans=trans,
            rgb_s=rgb_s,
            variance=0.01 + 0.05 * torch.sigmoid(x),
            visibility=torch.sigmoid(x.sum(-1)),
            rgb=ray_sum(weights[:, None] * rgb_s, samples.ray_idx, n_rays),
            depth=expected_depth(weights, samples.t_mid, samples.ray_idx, n_rays),
            acc=ray_sum(weights, samples.ray_idx, n_rays),
        )


class AccScorer:
    """ViewScorer stand-in: per-ray score = accumulated opacity (differentiable)."""

    name = "acc"
    heads = frozenset({"rgb", "visibility"})
    sampler = "uniform"

    def __init__(self):
        self.pixel_indices = []

    def pixel_scores(self, result, pixel_index=None):
        self.pixel_indices.append(pixel_index)
        return result.acc


class ConstScorer(AccScorer):
    def pixel_scores(self, result, pixel_index=None):
        return torch.zeros_like(result.acc) + 0.25


class NanGradScorer(AccScorer):
    """Finite scores, NaN gradients (sqrt at 0): every refined pose becomes NaN."""

    def pixel_scores(self, result, pixel_index=None):
        return result.acc + torch.sqrt(result.acc - result.acc)


def blob_model():
    return ToyModel(ToyField())


def cfg(n=16, **kw):
    if "name" in kw:
        kw["name"] = Planner(kw["name"])
    return PlannerConfig(**{"num_candidates": n, "score_chunk_rays": 24, **kw})


def gens(seed=100, step=0):
    return generator_factory(seed, step)


def pose_looking(position, target):
    return matrix_to_pose(look_at(torch.tensor(position), torch.tensor(target)))


# ---------------------------------------------------------------- candidates (METHOD 13)


def test_sample_poses_in_box_with_unit_quaternions():
    poses = sample_poses(500, BOX, seeded_generator(1, 0, "candidates"))
    assert poses.shape == (500, 7)
    assert ((poses[:, 4:] >= BOX[0]) & (poses[:, 4:] <= BOX[1])).all()
    torch.testing.assert_close(poses[:, :4].norm(dim=-1), torch.ones(500))
    # orientations are not looked at anything: both hemispheres of each quaternion axis occur
    assert (poses[:, :4] > 0).any(0).all() and (poses[:, :4] < 0).any(0).all()


def test_base_sampler_keeps_first_n_of_floor_oversample_draws():
    empty = ToyModel(ToyField(peak=0.0))
    c = cfg(n=20)
    out = candidate_poses(empty, c, BOX, None, 1e-4, False, seeded_generator(3, 1, "candidates"))
    drawn = sample_poses(math.floor(1.2 * 20), BOX, seeded_generator(3, 1, "candidates"))
    torch.testing.assert_close(out, drawn[:20])


def test_density_filter_m28_rejects_dense_centres():
    model = blob_model()
    c = cfg(n=100)
    tau = 1e-4  # the blob exceeds tau within about 2 units of the origin: most of the box
    out = candidate_poses(model, c, BOX, None, tau, False, seeded_generator(0, 0, "candidates"))
    assert 0 < out.shape[0] < 100  # some, not all, rejected: the test is not vacuous
    assert (model.field.density(out[:, 4:])[0] < tau).all()
    # without filters (Random), dense centres do occur
    raw = candidate_poses(model, c, BOX, None, tau, False, seeded_generator(0, 0, "candidates"), apply_filters=False)
    assert raw.shape[0] == 100 and (model.field.density(raw[:, 4:])[0] >= tau).any()


def test_density_filter_m28_passes_outside_the_aabb():
    model = ToyModel(ToyField(peak=1e6, width=100.0))  # dense everywhere inside the AABB
    box = torch.tensor([[2.5, 2.5, 2.5], [3.0, 3.0, 3.0]])
    out = candidate_poses(model, cfg(n=10), box, None, 1e-4, False, seeded_generator(0, 0, "candidates"))
    assert out.shape[0] == 10


def test_collision_filter_m29_two_rooms():
    """A wall at x = 0 splits the AABB into two rooms; the camera is in the left room."""
    model = ToyModel(ToyField(peak=0.0, walls=(0.0,)))
    current = pose_looking([-1.0, 0.2, 0.1], [0.0, 0.0, 0.0])
    c = cfg(n=64)
    out = candidate_poses(model, c, BOX, current, 1e-4, True, seeded_generator(5, 2, "candidates"))
    assert out.shape[0] == 64  # 3N draws, about half survive
    assert (out[:, 4] < 0.0).all(), "a candidate behind the wall passed the line-of-sight filter"
    free = candidate_poses(model, c, BOX, current, 1e-4, False, seeded_generator(5, 2, "candidates"))
    assert (free[:, 4] > 0.05).any()  # without M29 the other room is sampled


def test_collision_filter_m29_unobserved_wall_is_free_only_with_the_switch():
    """``planner.los_unobserved_free`` (M29 deviation): a wall in cells no training sample reached does not
    block the line of sight; a wall in observed cells still does."""
    current = pose_looking([-1.0, 0.2, 0.1], [0.0, 0.0, 0.0])
    unseen_wall = ToyModel(ToyField(peak=0.0, walls=(0.0,)), observed_below=-0.2)
    seen_wall = ToyModel(ToyField(peak=0.0, walls=(0.0,)), observed_below=0.5)
    gen = lambda: seeded_generator(5, 2, "candidates")  # noqa: E731
    out = candidate_poses(unseen_wall, cfg(n=64), BOX, current, 1e-4, True, gen())
    assert (out[:, 4] < 0.0).all()  # the switch is off by default: METHOD's M29
    out = candidate_poses(unseen_wall, cfg(n=64, los_unobserved_free=True), BOX, current, 1e-4, True, gen())
    assert (out[:, 4] > 0.05).any()
    out = candidate_poses(seen_wall, cfg(n=64, los_unobserved_free=True), BOX, current, 1e-4, True, gen())
    assert (out[:, 4] < 0.0).all(), "a candidate behind an observed wall passed the line-of-sight filter"


def test_collision_filter_m29_from_the_mesh_replaces_the_model():
    """``planner.los_source=mesh`` (M29 deviation): the given segment test decides, not the model's
    density (the model's wall at x = 0 is ignored; the test's wall at x = 0.5 blocks), and it is required."""
    model = ToyModel(ToyField(peak=0.0, walls=(0.0,)))
    current = pose_looking([-1.0, 0.2, 0.1], [0.0, 0.0, 0.0])
    seen_from = []

    def mesh_sight(origin: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
        seen_from.append(origin)
        return points[:, 0] < 0.5

    c = cfg(n=64, los_source=LineOfSightSource.mesh)
    out = candidate_poses(model, c, BOX, current, 1e-4, True, seeded_generator(5, 2, "candidates"), True, mesh_sight)
    assert (out[:, 4] < 0.5).all() and ((out[:, 4] > 0.0) & (out[:, 4] < 0.5)).any()
    torch.testing.assert_close(seen_from[0], current[4:])
    with pytest.raises(ValueError, match="los_source=mesh needs"):
        candidate_poses(model, c, BOX, current, 1e-4, True, seeded_generator(5, 2, "candidates"))


def test_no_candidates_error_names_the_filter():
    solid = ToyModel(ToyField(peak=1e6, width=100.0))
    with pytest.raises(NoCandidatesError, match=r"density filter M28 .* all 24 of 24 drawn"):
        candidate_poses(solid, cfg(n=20), BOX, None, 1e-4, False, seeded_generator(0, 0, "candidates"))
    walled = ToyModel(ToyField(peak=0.0, walls=(0.0,)))
    right_room = torch.tensor([[0.5, -1.0, -1.0], [1.5, 1.0, 1.0]])
    current = pose_looking([-1.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    with pytest.raises(NoCandidatesError, match=r"line-of-sight filter M29 .* all 60 of 60 drawn") as err:
        candidate_poses(walled, cfg(n=20), right_room, current, 1e-4, True, seeded_generator(0, 0, "candidates"))
    assert "\n" not in str(err.value)


# ---------------------------------------------------------------- scoring and selection (M16)


def test_score_poses_is_the_full_image_mean_and_passes_pixel_index():
    model, scorer = blob_model(), AccScorer()
    poses = torch.stack(
        [pose_looking([1.5, 0.0, 0.0], [0.0, 0.0, 0.0]), pose_looking([1.5, 0.0, 0.0], [3.0, 0.0, 0.0])]
    )
    scores = score_poses(model, scorer, poses, INTR, chunk_rays=24)
    assert scores.shape == (2,) and scores[0] > 0.5 and scores[1] < 0.01
    seen = torch.cat(scorer.pixel_indices[: math.ceil(64 / 24)])
    torch.testing.assert_close(seen, torch.arange(64))
    assert all(call == (scorer.heads, False, scorer.sampler) for call in model.calls)
    torch.testing.assert_close(score_poses(model, scorer, poses, INTR, chunk_rays=64), scores)


def test_argmax_and_top_k_ties_go_to_the_lowest_index():
    scores = torch.tensor([1.0, 3.0, 2.0, 3.0, 3.0])
    assert argmax_first(scores) == 1
    assert top_k_first(scores, 3).tolist() == [1, 3, 4]
    assert top_k_first(scores, 9).tolist() == [1, 3, 4, 2, 0]
    sel = select_next_view(blob_model(), ConstScorer(), cfg(n=8), BOX, None, INTR, 1e-4, False, gens())
    assert sel.index == 0 and sel.score == pytest.approx(0.25)
    assert sel.candidate_scores.count == sel.num_candidates and sel.candidate_scores.std == 0.0
    assert sel.candidate_scores.ties_at_max == sel.num_candidates


def test_a_tie_is_a_seeded_random_pick():
    """METHOD 13: candidates are drawn i.i.d. (positions uniform in the box), so the first of tied candidates
    is a uniform pick among them, seeded from (seed, step): over steps it lands all over the camera box."""
    box = torch.tensor([[1.0, 1.0, 1.0], [1.9, 1.9, 1.9]])  # outside the blob: the density filter keeps all
    picks = torch.stack(
        [
            select_next_view(blob_model(), ConstScorer(), cfg(n=8), box, None, INTR, 1e-4, False, gens(step=s)).pose[4:]
            for s in range(24)
        ]
    )
    assert len({tuple(p.tolist()) for p in picks}) == 24
    middle = box.mean(0)
    assert ((picks < middle).any(0) & (picks > middle).any(0)).all()  # both halves of the box on every axis


def test_argmax_selection_picks_the_best_scored_candidate():
    model, scorer = blob_model(), AccScorer()
    sel = select_next_view(model, scorer, cfg(n=12), BOX, None, INTR, 1e-4, False, gens())
    candidates = candidate_poses(model, cfg(n=12), BOX, None, 1e-4, False, gens()("candidates"))
    scores = score_poses(model, scorer, candidates, INTR, 24)
    assert sel.index == int(scores.argmax()) and torch.equal(sel.pose, candidates[sel.index])
    assert sel.score == pytest.approx(scores.max().item()) == pytest.approx(sel.candidate_scores.max)
    assert sel.candidate_scores.ties_at_max == int((scores == scores.max()).sum())
    assert not sel.refined and sel.opt is None


def test_random_method_skips_filters_unless_asked():
    model = blob_model()
    box = torch.tensor([[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]])  # every centre is dense
    sel = select_next_view(model, None, cfg(n=8), box, None, INTR, 1e-4, False, gens())
    assert sel.score is None and sel.candidate_scores is None and sel.num_candidates == 8
    with pytest.raises(NoCandidatesError):
        select_next_view(model, None, cfg(n=8, random_filters=True), box, None, INTR, 1e-4, False, gens())
    picks = {
        select_next_view(model, None, cfg(n=8), box, None, INTR, 1e-4, False, gens(step=s)).index for s in range(40)
    }
    assert len(picks) >= 5  # uniform choice, not always the first


# ---------------------------------------------------------------- -OPT (METHOD 14)


def test_ray_subset_keeps_a_tenth_of_each_chunk():
    idx = ray_subset(300 * 300, 4096, 0.1, seeded_generator(0, 0, "opt_rays/0"))
    assert idx.shape[0] == 21 * 409 + 398 == 8987
    assert (idx.diff() > 0).all() and idx.min() >= 0 and idx.max() < 90000
    per_chunk = torch.bincount(idx // 4096)
    assert per_chunk[:21].eq(409).all() and per_chunk[21] == 398


@pytest.mark.parametrize("param", list(PoseParam))
def test_opt_refinement_ascends_the_score(param):
    """With a large step the refinement turns a camera that half-sees the blob towards it."""
    model, scorer = blob_model(), AccScorer()
    intr = Intrinsics.from_fov(16, 16)
    start = pose_looking([1.8, 0.0, 0.0], [0.0, 1.6, 0.0])[None]
    opt = OptConfig(lr=0.05, iters=20, param=param)
    refined, kept = refine_poses(model, scorer, start, BOX, intr, opt, gens())
    assert kept.tolist() == [0]
    torch.testing.assert_close(refined[:, :4].norm(dim=-1), torch.ones(1))
    assert ((refined[:, 4:] >= BOX[0]) & (refined[:, 4:] <= BOX[1])).all()
    before, after = score_poses(model, scorer, torch.cat([start, refined]), intr, 256)
    assert after > before + 0.3
    assert all(p.grad is None for p in model.parameters())


def test_opt_default_lr_moves_poses_only_slightly():
    model, scorer = blob_model(), AccScorer()
    start = torch.stack(
        [pose_looking([1.8, 0.0, 0.0], [0.0, 1.6, 0.0]), pose_looking([0.0, 1.8, 0.5], [0.0, 0.0, 0.0])]
    )
    refined, _ = refine_poses(model, scorer, start, BOX, INTR, OptConfig(), gens())
    step = (refined - start).abs().max()
    assert 0 < step < 5e-3  # 20 Adam steps of 1e-4 (METHOD 14.4)


@pytest.mark.parametrize("param", list(PoseParam))
@pytest.mark.parametrize("lr", [1e-4, 0.5])
def test_opt_never_scores_below_the_best_starting_candidate(param, lr):
    model, scorer = blob_model(), AccScorer()
    c = cfg(n=10, name="opt", opt=OptConfig(lr=lr, iters=5, param=param))
    sel = select_next_view(model, scorer, c, BOX, None, INTR, 1e-4, False, gens())
    assert sel.opt is not None and sel.opt.original_indices.shape == (3,)
    assert sel.score >= sel.opt.original_scores.max().item()
    assert sel.score >= sel.candidate_scores.max - 1e-12
    assert sel.score == pytest.approx(score_poses(model, scorer, sel.pose[None], INTR, 24).item())
    assert sel.index in sel.opt.original_indices.tolist()


def test_opt_drops_nan_poses_and_falls_back_to_the_originals():
    model, scorer = blob_model(), NanGradScorer()
    c = cfg(n=10, name="opt", opt=OptConfig(iters=2))
    sel = select_next_view(model, scorer, c, BOX, None, INTR, 1e-4, False, gens())
    assert sel.opt.refined_poses.shape == (0, 7) and not sel.refined
    assert sel.index == int(sel.opt.original_indices[0]) and math.isfinite(sel.score)
    model.calls.clear()
    start = sample_poses(3, BOX, seeded_generator(0, 0, "x"))
    refined, kept = refine_poses(model, scorer, start, BOX, INTR, OptConfig(iters=3), gens())
    assert refined.shape == (0, 7) and kept.shape == (0,)
    assert len(model.calls) == 3  # iteration 0 only: diverged poses are not rendered again


def test_non_finite_scores_raise():
    class NanScorer(AccScorer):
        def pixel_scores(self, result, pixel_index=None):
            return result.acc * float("nan")

    with pytest.raises(FloatingPointError, match="non-finite view score"):
        score_poses(blob_model(), NanScorer(), sample_poses(2, BOX, seeded_generator(0, 0, "x")), INTR, 24)


# ---------------------------------------------------------------- determinism (PROTOCOL 3)


def test_seeded_generators_are_stable_and_purpose_specific():
    a = torch.rand(4, generator=seeded_generator(100, 3, "candidates"))
    b = torch.rand(4, generator=gens(100, 3)("candidates"))
    torch.testing.assert_close(a, b)
    assert not torch.equal(a, torch.rand(4, generator=seeded_generator(100, 3, "random_pick")))
    assert not torch.equal(a, torch.rand(4, generator=seeded_generator(100, 4, "candidates")))


@pytest.mark.parametrize("name", ["argmax", "opt", "random"])
def test_same_seeds_give_the_same_selection(name):
    model = ToyModel(ToyField(centre=(0.8, 0.8, 0.0), width=0.25))
    scorer = None if name == "random" else AccScorer()
    c = cfg(n=10, name="argmax" if name == "random" else name, opt=OptConfig(iters=3, lr=0.01))
    current = pose_looking([-1.5, -1.5, 0.0], [0.8, 0.8, 0.0])
    first = select_next_view(model, scorer, c, BOX, current, INTR, 1e-4, True, gens(101, 7))
    again = select_next_view(model, scorer, c, BOX, current, INTR, 1e-4, True, gens(101, 7))
    other = select_next_view(model, scorer, c, BOX, current, INTR, 1e-4, True, gens(101, 8))
    assert torch.equal(first.pose, again.pose) and first.index == again.index and first.score == again.score
    assert not torch.equal(first.pose, other.pose)


def test_planner_config_is_used_not_redefined():
    c = replace(PlannerConfig(), num_candidates=4)
    assert c.oversample == 1.2 and c.los_samples == 200 and c.opt.top_k == 3 and c.opt.param == "quat_raw"


# ---------------------------------------------------------------- the real scorers (nvf.uncertainty)


@pytest.mark.parametrize(
    "method, entropy",
    [
        ("nvf", EntropyConfig()),
        ("nvf", EntropyConfig(depth_mode=DepthMode.chunk, chunk_rays=16)),
        ("wd", EntropyConfig()),
        ("air", EntropyConfig()),
        ("activenerf", EntropyConfig()),
    ],
)
def test_opt_with_the_real_scorers(method, entropy):
    model = blob_model()
    scorer = build_method(method_configs()[method], {"nvf.entropy": replace(entropy, d0=1.0)}).scorer()
    assert isinstance(scorer, ViewScorer) and isinstance(AccScorer(), ViewScorer)
    c = cfg(n=8, name="opt", score_chunk_rays=32, opt=OptConfig(iters=3, lr=1e-2, chunk_rays=16))
    sel = select_next_view(model, scorer, c, BOX, None, INTR, 1e-4, False, gens())
    assert math.isfinite(sel.score) and sel.score >= sel.opt.original_scores.max().item()
    assert sel.opt.refined_poses.shape == (3, 7) and sel.opt.refined_scores.isfinite().all()
    again = select_next_view(model, scorer, c, BOX, None, INTR, 1e-4, False, gens())
    assert torch.equal(sel.pose, again.pose)


def test_integration_with_the_scene_model():
    """The real SceneModel (random initial field, sigma about 1 in the AABB) with the NVF scorer,
    collision-free candidates and -OPT; ``alpha_threshold=0`` keeps samples so gradients exist."""
    pytest.importorskip("nvf.field")
    from nvf.config import FieldConfig, SamplerConfig
    from nvf.model import SceneModel

    aabb = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    field_cfg = FieldConfig(
        num_levels=4, log2_hashmap_size=12, max_resolution=64, hidden_dim=16, backend=HashBackend.torch
    )
    model = SceneModel(aabb, field_cfg, SamplerConfig(grid_resolution=16, alpha_threshold=0.0))
    model.update_grid(0, torch.Generator().manual_seed(0))
    scorer = build_method(method_configs()["nvf"], {"nvf.entropy": EntropyConfig(d0=1.0)}).scorer()
    current = pose_looking([-1.8, 0.1, 0.2], [0.0, 0.0, 0.0])
    c = cfg(n=8, name="opt", score_chunk_rays=4096, opt=OptConfig(iters=2, lr=1e-2))
    tau = 1e-4
    sel = select_next_view(model, scorer, c, BOX, current, INTR, tau, True, gens())
    candidates = candidate_poses(model, c, BOX, current, tau, True, gens()("candidates"))
    assert sel.num_candidates == candidates.shape[0] >= 2
    assert (model.density(candidates[:, 4:]) < tau).all()
    assert (sel.opt.refined_poses - candidates[sel.opt.refined_from]).abs().max() > 1e-3
    assert math.isfinite(sel.score) and sel.score >= sel.opt.original_scores.max().item()
    assert all(p.grad is None for p in model.parameters())
    again = select_next_view(model, scorer, c, BOX, current, INTR, tau, True, gens())
    assert torch.equal(sel.pose, again.pose)


def test_scorers_scored_together_are_bitwise_their_own_scores():
    """(M16) One render per chunk serves every per-pixel scorer of a sampler (the union of their heads): NVF,
    w/o Vis., ActiveNeRF's and WD's rewards are bitwise the rewards each gets from its own render; a scorer of
    another sampler renders for itself."""
    from nvf.config import EntropyConfig, EntropySampler, FieldConfig, SamplerConfig
    from nvf.model import SceneModel
    from nvf.planning import score_poses_together
    from nvf.uncertainty.baselines import RenderedVarianceScorer, WDScorer
    from nvf.uncertainty.nvf_entropy import NVFEntropyScorer

    torch.manual_seed(2)
    aabb = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    model = SceneModel(
        aabb, FieldConfig(log2_hashmap_size=10, num_levels=4, max_resolution=32), SamplerConfig(grid_resolution=16)
    )
    model.grid.occupied[:] = True
    with torch.no_grad():
        model.field.encoding.table.normal_(0.0, 1.0)
    scorers = [
        NVFEntropyScorer(EntropyConfig(), 1.0),
        NVFEntropyScorer(EntropyConfig(use_visibility=False), 1.0),
        RenderedVarianceScorer(),
        WDScorer(),
        NVFEntropyScorer(EntropyConfig(sampler=EntropySampler.uniform), 1.0),
    ]
    poses = torch.stack(
        [matrix_to_pose(look_at(torch.tensor([2.5, y, 0.5]), torch.zeros(3))) for y in (-1.0, 0.0, 1.5)]
    )
    intr = Intrinsics.from_fov(12, 12)
    together = score_poses_together(model, scorers, poses, intr, 50)
    for scorer, scores in zip(scorers, together, strict=True):
        alone = score_poses(model, scorer, poses, intr, 50)
        assert torch.equal(scores, alone), scorer
    assert not torch.equal(together[0], together[1])  # the visibility term matters on this model
