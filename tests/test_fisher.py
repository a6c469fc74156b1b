"""FisherRF on NVF's backbone (METHOD 17, M30-M32): the probe estimate of a view's Fisher diagonal against
the exact one, its independence of ray order and chunking, the score's seen/unseen order on the embedded
scene, and its place in planning (argmax only) and evaluation (no per-pixel map). The method is built from
its declaration, ``conf/method/fisherrf.yaml``."""

import math

import numpy as np
import pytest
import torch

from nvf.cameras import Intrinsics, look_at, matrix_to_pose, pixel_rays
from nvf.methods import FisherRF
from nvf.model import SceneModel
from nvf.planning import argmax_first, prepare_scorer, score_poses, select_next_view
from nvf.seeding import generator_factory
from nvf.training import train_model
from nvf.uncertainty import StepScorer, ViewScorer, WholeViewScorer
from nvf.uncertainty.fisher import (
    FisherRFScorer,
    colour_parameters,
    exact_fisher_diagonal,
    probe_fisher_diagonal,
    rademacher,
    view_fisher_diagonal,
)
from pipeline.bench.train import observations
from pipeline.config.validation import compose_run
from pipeline.episode.evaluation import Evaluator
from pipeline.episode.settings import EpisodeSettings
from pipeline.metrics.image import LpipsMetric
from pipeline.scenes.loading import load_scene
from pipeline.scenes.mesh_renderer import GroundTruthRenderer

CHUNK = 8192


def declared() -> FisherRF:
    """FisherRF as ``conf/method/fisherrf.yaml`` declares it."""
    method = compose_run(["method=fisherrf"]).method
    assert isinstance(method, FisherRF)
    return method


def fisher_scorer() -> FisherRFScorer:
    """FisherRF's scorer with its declared settings (it reads none of NVF's keys)."""
    return declared().scorer()


@pytest.fixture(scope="module")
def smoke():
    """The backbone at the smoke budget trained on the embedded scene's three one-sided initial views:
    ``(cfg, settings, scene, renderer, obs, model)``."""
    cfg = compose_run(["budget=smoke", "scene=default"])
    scene = load_scene("default")
    settings = EpisodeSettings.of(cfg, scene)
    renderer = GroundTruthRenderer(scene.mesh)
    size = int(cfg.budget.image_size)
    obs = observations(renderer, scene.init_poses, Intrinsics.from_fov(size, size))
    torch.manual_seed(0)
    model = SceneModel(scene.object_aabb, settings.field, settings.sampler)
    train_model(model, obs, settings.train, ["backbone"], settings.entropy, torch.Generator().manual_seed(0))
    return cfg, settings, scene, renderer, obs, model


def object_rays(smoke, n: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``n`` rays of the first training view that hit the object (the model renders them opaque)."""
    _, _, _, _, obs, model = smoke
    origins, dirs = pixel_rays(obs.c2w[0], obs.intrinsics)
    hits = (obs.images[0].reshape(-1, 4)[:, 3] > 0.5).nonzero().flatten()
    pick = hits[torch.linspace(0, len(hits) - 1, n).long()]
    return origins[pick], dirs[pick]


def relative_error(estimate: torch.Tensor, exact: torch.Tensor) -> float:
    return float((estimate - exact).abs().sum() / exact.abs().sum())


def test_probes_converge_to_the_exact_diagonal(smoke):
    """(M30, M31) On 6 rays of the smoke field the mean of K Rademacher probes approaches the exact diagonal
    (one backward pass per ray and channel): its relative L1 error falls at least like 1/sqrt(K), to under
    10% at K = 512 (measured on this field: 0.32 at K = 16, 0.045 at K = 512)."""
    model = smoke[-1]
    params = colour_parameters(model)
    origins, dirs = object_rays(smoke, 6)
    exact = exact_fisher_diagonal(model, params, origins, dirs)
    assert exact.sum() > 0
    generator = torch.Generator().manual_seed(0)
    errors = {k: relative_error(probe_fisher_diagonal(model, params, origins, dirs, rademacher(k, 6, generator), CHUNK),
                                exact) for k in (16, 512)}  # fmt: skip
    print(f"relative L1 error of the probe estimate: {errors}")
    assert errors[512] < 0.1
    assert errors[512] < errors[16] / 3  # 1/sqrt(K) predicts a factor of 5.7


def test_exact_where_it_takes_no_more_backward_passes(smoke):
    """(M30) With at least 3 probes per ray the exact diagonal is cheaper, and used."""
    model = smoke[-1]
    params = colour_parameters(model)
    origins, dirs = object_rays(smoke, 4)
    generator = torch.Generator().manual_seed(0)
    exact = exact_fisher_diagonal(model, params, origins, dirs)
    assert torch.equal(view_fisher_diagonal(model, params, origins, dirs, 12, generator, CHUNK), exact)
    assert not torch.equal(view_fisher_diagonal(model, params, origins, dirs, 11, generator, CHUNK), exact)


def test_only_the_backbone_carries_fisher_information(smoke):
    """The rendered colour depends on stage 1's parameters (hash table, density MLP, colour head): the
    variance and visibility heads get a zero diagonal, and every backbone tensor some information."""
    model = smoke[-1]
    params = colour_parameters(model)
    origins, dirs = object_rays(smoke, 8)
    diagonal = exact_fisher_diagonal(model, params, origins, dirs)
    backbone = {id(p) for p in model.field.parameter_groups()["backbone"]}
    for p, part in zip(params, diagonal.split([p.numel() for p in params]), strict=True):
        assert (part.sum() > 0) == (id(p) in backbone)


def test_the_estimate_does_not_depend_on_ray_order_or_chunking(smoke):
    """(M31) A probe's gradient is accumulated over chunks before it is squared: permuting the rays with their
    signs and chunking them by 5 gives the one-chunk estimate, and a view's score is the same at any
    ``chunk_rays``."""
    _, _, scene, _, obs, model = smoke
    params = colour_parameters(model)
    origins, dirs = object_rays(smoke, 40)
    signs = rademacher(4, 40, torch.Generator().manual_seed(1))
    whole = probe_fisher_diagonal(model, params, origins, dirs, signs, CHUNK)
    perm = torch.randperm(40, generator=torch.Generator().manual_seed(2))
    shuffled = probe_fisher_diagonal(model, params, origins[perm], dirs[perm], signs[:, perm], 5)
    torch.testing.assert_close(shuffled, whole, rtol=1e-5, atol=1e-12)

    scorer = fisher_scorer().prepare(model, obs, generator_factory(0, 0), CHUNK)
    view_origins, view_dirs = pixel_rays(scene.eval_poses[0], Intrinsics.from_fov(12, 12))
    one = scorer.view_score(model, view_origins, view_dirs, CHUNK)
    torch.testing.assert_close(scorer.view_score(model, view_origins, view_dirs, 7), one, rtol=1e-5, atol=0.0)
    assert scorer.view_score(model, view_origins, view_dirs, CHUNK) == one  # the same probes every time


def ring_pose(scene, obs, azimuth_offset_deg: float) -> torch.Tensor:
    """A look-at pose at the training cameras' mean distance and 30 degrees elevation, ``azimuth_offset_deg``
    from their mean azimuth."""
    centre = scene.tight_box.mean(0)
    seen = obs.c2w[:, :3, 3].mean(0) - centre
    theta = math.atan2(seen[1], seen[0]) + math.radians(azimuth_offset_deg)
    phi = math.radians(30.0)
    direction = torch.tensor([math.cos(theta) * math.cos(phi), math.sin(theta) * math.cos(phi), math.sin(phi)])
    return look_at(centre + float(torch.linalg.norm(seen)) * direction, centre)


def test_a_repeated_training_view_scores_below_the_unseen_side(smoke):
    """(M32) A candidate at a training camera adds little information the training views do not hold; views
    of the side no training view saw add parameters the training rays never constrained (measured at the
    smoke budget with the declared K: 1.0e4 and 1.1e4 for two training cameras, 2.4e4-3.5e4 for the unseen
    side)."""
    cfg, _, scene, _, obs, model = smoke
    scorer = prepare_scorer(fisher_scorer(), model, obs, generator_factory(0, 0), CHUNK)
    assert isinstance(scorer, WholeViewScorer)
    repeated = obs.c2w[:2]
    unseen = torch.stack([ring_pose(scene, obs, offset) for offset in (160.0, 180.0, 200.0)])
    plan = Intrinsics.from_fov(int(cfg.planner.resolution), int(cfg.planner.resolution))
    scores = score_poses(model, scorer, matrix_to_pose(torch.cat([repeated, unseen])), plan, CHUNK)
    print(f"FisherRF view scores, training cameras then the unseen side: {scores.tolist()}")
    assert scores.dtype == torch.float64 and scores[:2].max() < scores[2:].min()


def refusal(capsys, *overrides: str) -> str:
    """The one line (exit status 2) a run with ``overrides`` is refused with before it starts."""
    with pytest.raises(SystemExit) as exit_:
        compose_run(list(overrides))
    assert exit_.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1
    return lines[0]


def test_argmax_planning_only(smoke, capsys):
    """The prepared scorer plans by argmax over the candidates' full-image scores; -OPT is refused, by the
    planner and, before a run starts, by the run's settings (one line naming planner=opt)."""
    cfg, settings, scene, _, obs, model = smoke
    generators = generator_factory(0, 0)
    scorer = fisher_scorer()
    assert isinstance(scorer, StepScorer) and not isinstance(scorer, ViewScorer)
    prepared = prepare_scorer(scorer, model, obs, generators, CHUNK)
    plan = Intrinsics.from_fov(int(cfg.planner.resolution), int(cfg.planner.resolution))
    current = matrix_to_pose(obs.c2w[-1])
    args = (scene.camera_box, current, plan, settings.tau, settings.collision_free, generators)
    selection = select_next_view(model, prepared, settings.planner, *args)
    scores = score_poses(model, prepared, selection.candidates, plan, settings.planner.score_chunk_rays)
    assert torch.equal(selection.scores, scores) and selection.index == argmax_first(scores)

    opt = EpisodeSettings.of(compose_run(["budget=smoke", "scene=default", "planner=opt"]), scene)
    with pytest.raises(ValueError, match="fisherrf scores whole views"):
        select_next_view(model, prepared, opt.planner, *args)
    assert refusal(capsys, "budget=smoke", "method=fisherrf", "planner=opt").startswith(
        "error: planner=opt: fisherrf scores whole views"
    )
    nvf = opt.scorer()  # NVF, the default method, with -OPT: a per-pixel scorer, used as it is
    assert isinstance(nvf, ViewScorer) and prepare_scorer(nvf, model, obs, generators, CHUNK) is nvf
    assert prepare_scorer(None, model, obs, generators, CHUNK) is None


def test_evaluation_has_no_score_map(smoke):
    """A method that scores whole views has no per-pixel score: the step's score map is NaN and the
    uncertainty correlation missing, as for Random."""
    cfg, settings, scene, renderer, obs, model = smoke
    evaluator = Evaluator(scene, renderer, settings.budget, settings.metrics, 0, torch.device("cpu"), LpipsMetric())
    face_ids = [renderer.face_ids(c2w.numpy(), obs.intrinsics) for c2w in obs.c2w]
    metrics, images, view_sums = evaluator.evaluate(model, fisher_scorer(), face_ids, obs, 0)
    assert np.isnan(images["score"]).all() and view_sums == {}
    assert all(math.isnan(metrics[key]) for key in ("patch_pearson", "view_pearson", "ause"))


@pytest.mark.parametrize(
    "override, needle",
    [
        ("method.probes=0", "error: method.probes=0 must be at least 1"),
        ("method.prior_precision=0.0", "error: method.prior_precision=0.0 must be > 0"),
    ],
)
def test_invalid_settings_are_refused_in_one_line(capsys, override, needle):
    """FisherRF's own settings are checked when its declaration is built, before a run starts."""
    assert needle in refusal(capsys, "method=fisherrf", override)
    with pytest.raises(ValueError, match="at least one probe"):
        FisherRFScorer(0, 1e-6)
