"""nvf/training.py: losses (M4, M19-M21, M25, M27), lr schedule, ray sampling and the three stages
on a tiny analytic scene (a coloured ball rendered by ray-sphere intersection, 16x16 images)."""

import contextlib
import dataclasses
import math

import pytest
import torch
from beartype.roar import BeartypeCallHintViolation

training = pytest.importorskip("nvf.training", reason="nvf/training.py needs nvf/model.py (not importable yet)")
from nvf.cameras import Intrinsics, look_at, pixel_rays  # noqa: E402
from nvf.config import (  # noqa: E402
    EntropyConfig,
    FieldConfig,
    Precision,
    SamplerConfig,
    Schedule,
    StageBudget,
    StageOrder,
    TrainConfig,
)
from nvf.losses import (  # noqa: E402
    activenerf_loss,
    balanced_bce_weights,
    composite,
    neurar_loss,
    variance_nll,
    visibility_bce,
)
from nvf.model import SceneModel  # noqa: E402
from nvf.observations import Observations  # noqa: E402
from nvf.stage_recorder import StageRecorder, TrainingDiverged  # noqa: E402
from nvf.training import (  # noqa: E402
    RayBatch,
    backbone_lr,
    stage_order,
    stages_to_train,
    train_backbone,
    train_model,
    train_variance_head,
    train_visibility_head,
)

RADIUS = 0.5
AABB = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
INTR = Intrinsics.from_fov(16, 16, 90.0)


def render_ball(c2w: torch.Tensor, intr: Intrinsics) -> torch.Tensor:
    """RGBA ``[H,W,4]`` of a ball of radius 0.5 at the origin coloured by its normal; RGB 0 off the ball."""
    origins, dirs = pixel_rays(c2w, intr)
    b = (origins * dirs).sum(-1)
    disc = b * b - ((origins * origins).sum(-1) - RADIUS**2)
    hit = disc > 0
    t = -b - disc.clamp_min(0).sqrt()
    normal = (origins + t[:, None] * dirs) / RADIUS
    rgb = torch.where(hit[:, None], 0.5 + 0.4 * normal, 0.0)
    return torch.cat([rgb, hit[:, None].float()], -1).reshape(intr.height, intr.width, 4)


def ball_observations(n: int = 5) -> Observations:
    angles = torch.arange(n) * 2 * math.pi / n
    positions = torch.stack([2.2 * torch.cos(angles), 2.2 * torch.sin(angles), 0.6 * torch.ones(n)], -1)
    c2w = torch.stack([look_at(p, torch.zeros(3)) for p in positions])
    return Observations(torch.stack([render_ball(c, INTR) for c in c2w]), c2w, INTR)


def tiny_model(seed: int = 0) -> SceneModel:
    torch.manual_seed(seed)
    field_cfg = FieldConfig(num_levels=4, log2_hashmap_size=12, base_resolution=4, max_resolution=32, hidden_dim=32)
    sampler_cfg = SamplerConfig(grid_resolution=16, step_size=0.03, warmup_iters=16, update_every=4)
    return SceneModel(AABB, field_cfg, sampler_cfg, num_images=0)


def tiny_config(**overrides) -> TrainConfig:
    base = TrainConfig(
        backbone=StageBudget(60, 256, 1e-2),
        variance=StageBudget(15, 256, 1e-2),
        visibility=StageBudget(15, 1024, 1e-2),
        label_samples=32,
    )
    return dataclasses.replace(base, **overrides)


@pytest.fixture(scope="module")
def trained() -> tuple[SceneModel, Observations]:
    """A backbone fitted to the ball (stage 1, M20), shared by the stage-2/3 tests (they copy it)."""
    obs, model = ball_observations(), tiny_model()
    stats = train_backbone(model, obs, tiny_config(), torch.Generator().manual_seed(0))
    assert stats["last_loss"] < stats["first_loss"]
    return model, obs


def copy_model(model: SceneModel) -> SceneModel:
    clone = tiny_model()
    clone.load_state_dict(model.state_dict())
    return clone


def params(model: SceneModel, group: str) -> list[torch.Tensor]:
    return [p.detach().clone() for p in model.field.parameter_groups()[group]]


def same(a: list[torch.Tensor], b: list[torch.Tensor]) -> bool:
    return all(torch.equal(x, y) for x, y in zip(a, b, strict=True))


# ----------------------------------------------------------------------------- pure functions


def test_balanced_bce_weights_m19():
    labels = torch.tensor([0.9, 0.2, 0.1, 0.0])  # p = 1/4 positives (V* > 0.5)
    w = balanced_bce_weights(labels)
    assert w[0].item() == pytest.approx(0.7 / 0.5 + 0.3)
    assert torch.allclose(w[1:], torch.full((3,), 0.7 / 1.5 + 0.3))
    assert torch.equal(balanced_bce_weights(torch.zeros(5)), torch.ones(5))
    assert torch.equal(balanced_bce_weights(torch.ones(5)), torch.ones(5))
    assert torch.equal(balanced_bce_weights(torch.full((5,), 0.5)), torch.ones(5))  # 0.5 is not positive


def test_visibility_bce_is_weighted_plain_mean_m19():
    logits, labels = torch.tensor([2.0, -1.0, 0.5, 0.0]), torch.tensor([0.99, 0.3, 0.0, 0.0])
    bce = torch.nn.functional.binary_cross_entropy_with_logits(logits, labels, reduction="none")
    expected = (balanced_bce_weights(labels) * bce).sum() / 4
    assert visibility_bce(logits, labels).item() == pytest.approx(expected.item())


def test_composite_random_background_m4():
    bg = torch.tensor([[0.2, 0.4, 0.6], [0.2, 0.4, 0.6], [1.0, 0.0, 0.5]])
    rgb, acc = torch.tensor([[0.5, 0.5, 0.5], [0.0, 0.0, 0.0], [0.25, 0.25, 0.25]]), torch.tensor([1.0, 0.0, 0.5])
    out = composite(rgb, acc, bg)
    assert torch.allclose(out[0], rgb[0])  # opaque: no background
    assert torch.allclose(out[1], bg[1])  # empty: background only
    assert torch.allclose(out[2], torch.tensor([0.75, 0.25, 0.5]))  # C + (1 - A) b


def test_backbone_lr_schedule():
    cfg = TrainConfig()
    assert backbone_lr(cfg, 0) == pytest.approx(1e-2)
    assert backbone_lr(cfg, 5000) == pytest.approx(1e-3)
    assert backbone_lr(cfg, 10000) == pytest.approx(1e-4)
    assert backbone_lr(cfg, 2500) == pytest.approx(1e-2 * 0.01**0.25)


def test_variance_nll_excludes_zero_density_and_clamps_m21():
    log_p = torch.tensor([-math.inf, 0.0, -100.0, math.log(0.5)])
    expected = 0.01 * (0.0 - math.log(1e-7) - math.log(0.5)) / 3
    assert variance_nll(log_p).item() == pytest.approx(expected, rel=1e-6)


def test_aux_losses_m25_m27():
    var = torch.tensor([[0.5, 1.0, 2.0]], requires_grad=True)
    res = torch.tensor([[0.25, 0.0, 1.0]], requires_grad=True)
    an = activenerf_loss(var, res)
    expected = ((res / (2 * (var + 1e-9))) + 0.5 * torch.log(var + 1e-9)).mean()
    assert an.item() == pytest.approx(expected.item())
    na = neurar_loss(var, res)
    assert na.item() == pytest.approx(0.01 * ((var - res) ** 2).mean().item())
    (an + na).backward()
    assert res.grad is None or torch.equal(res.grad, torch.zeros_like(res))  # sg on the residual
    assert var.grad is not None


def test_sample_rays_match_pixel_rays_and_are_seeded():
    obs = ball_observations(3)
    o1, d1, c1, i1 = obs.sample_rays(64, torch.Generator().manual_seed(7))
    o2, d2, c2, i2 = obs.sample_rays(64, torch.Generator().manual_seed(7))
    assert torch.equal(d1, d2) and torch.equal(c1, c2) and torch.equal(i1, i2)
    all_o, all_d = pixel_rays(obs.c2w, INTR)  # [N,P,3]
    flat = obs.images.reshape(-1, 4)
    # each sampled ray is one of the image pixels, with its own RGBA
    match = (d1[:, None, :] - all_d.reshape(-1, 3)[None]).norm(dim=-1) < 1e-5
    match &= (o1[:, None, :] - all_o.reshape(-1, 3)[None]).norm(dim=-1) < 1e-5
    assert match.any(1).all()
    idx = match.float().argmax(1)
    assert torch.equal(flat[idx], c1)
    assert torch.equal(i1, idx // (INTR.height * INTR.width))  # the ray's image index


def test_empty_training_set_raises():
    empty = Observations(torch.zeros(0, 16, 16, 4), torch.zeros(0, 4, 4), INTR)
    model, cfg, gen = tiny_model(), tiny_config(), torch.Generator()
    with pytest.raises(ValueError, match="empty"):
        train_backbone(model, empty, cfg, gen)
    with pytest.raises(ValueError, match="empty"):
        train_visibility_head(model, empty, cfg, gen)
    with pytest.raises(ValueError, match="empty"):
        train_model(model, empty, cfg, ["backbone"], EntropyConfig(), gen)
    with pytest.raises(ValueError):
        Observations(torch.zeros(1, 8, 16, 4), torch.eye(4)[None], INTR)  # H, W do not match
    with pytest.raises((ValueError, TypeError)):  # TypeError: jaxtyping's check, when active
        Observations(torch.zeros(2, 16, 16, 4), torch.eye(4)[None], INTR)  # 2 images, 1 pose


def test_stage_order():
    assert stage_order(TrainConfig()) == ("backbone", "variance", "visibility")
    assert stage_order(TrainConfig(stage_order=StageOrder.vis_first)) == ("backbone", "visibility", "variance")
    with pytest.raises((TypeError, BeartypeCallHintViolation)):  # outside the StageOrder enum: refused when built
        TrainConfig(stage_order="bogus")


# ------------------------------------------------------------------------------------- stages


def test_backbone_nan_raises_training_diverged():
    obs = ball_observations(2)
    obs.images[0, ..., 0] = math.nan  # half of all pixels: the first batch draws one
    cfg = tiny_config(backbone=StageBudget(50, 64, 1e-2))
    with pytest.raises(TrainingDiverged, match=r"backbone stage diverged at iteration 0"):
        train_backbone(tiny_model(), obs, cfg, torch.Generator().manual_seed(0))


def _feed(stage: str, losses: list[float]) -> None:
    recorder = StageRecorder(stage, len(losses), None)
    for iteration, loss in enumerate(losses):
        recorder.end_iteration(iteration, loss)


def test_collapse_rule_needs_a_full_window_above_four_times_the_lowest_mean_and_the_first_loss():
    """(documented in ``_Recorder``) The mean of the last 5 losses above 4x the lowest earlier mean and
    above the first loss."""
    collapse = [0.01, 0.1, 0.1, 0.1, 0.1]  # lr=1e3 at the smoke budget: 6-16x from iteration 1 on
    with pytest.raises(
        TrainingDiverged, match=r"backbone stage collapsed at iteration 4: mean loss 0\.082 .* 8\.2 times"
    ):
        _feed("backbone", collapse)
    _feed("backbone", [0.01, 0.1, 0.1, 0.1])  # no full window yet
    _feed("backbone", [0.01, 0.001, 0.002, 0.001, 0.003, 0.004, 0.002, 0.001, 0.001])  # noise at a low loss: 2.8x
    _feed("backbone", [0.01, 0.015, 0.02, 0.025, 0.03, 0.035])  # a slow rise: 2.5x, kept
    _feed("backbone", [0.1, *[0.001] * 4, *[0.02] * 5])  # 4.2x over the lowest mean, but below the first loss
    _feed("variance", collapse)  # M21 is checked for non-finite values only
    with pytest.raises(TrainingDiverged, match="visibility stage collapsed"):
        _feed("visibility", [0.69, 50.0, 50.0, 50.0, 50.0])


def test_visibility_stage_with_lr_1e3_collapses(trained):
    """Stage 3 at lr 1e3: the balanced BCE jumps from 0.69 to ~1e23 at the second iteration; the
    collapse rule stops the stage at iteration 4 (before: recorded as a finished stage)."""
    model, obs = trained
    cfg = tiny_config(visibility=StageBudget(30, 1024, 1e3))
    with pytest.raises(
        TrainingDiverged, match=r"visibility stage collapsed at iteration 4: .* lowest earlier mean 0\.69"
    ):
        train_visibility_head(copy_model(model), obs, cfg, torch.Generator().manual_seed(2))


def test_aux_loss_trains_variance_head_only():
    """M25/M27 share stage 1's steps but never change the backbone (stop-gradients)."""
    obs = ball_observations()
    cfg = tiny_config(backbone=StageBudget(6, 128, 1e-2))
    runs = {}
    losses = {"none": None, "activenerf": activenerf_loss, "neurar": neurar_loss}
    for aux, loss in losses.items():
        model = tiny_model(seed=1)
        before = params(model, "variance")
        stats = train_backbone(model, obs, cfg, torch.Generator().manual_seed(3), aux_loss=loss)
        runs[aux] = (params(model, "backbone"), same(before, params(model, "variance")), stats)
    assert runs["none"][1] and not runs["activenerf"][1] and not runs["neurar"][1]
    for aux in ("activenerf", "neurar"):
        assert all(torch.allclose(a, b, atol=1e-6) for a, b in zip(runs["none"][0], runs[aux][0], strict=True))
        assert math.isfinite(runs[aux][2]["last_aux_loss"])


def test_variance_stage_nll_decreases(trained):
    """Stage 2 (M21): the mixture NLL falls and only the variance head moves."""
    model, obs = trained
    model = copy_model(model)
    frozen = params(model, "backbone") + params(model, "visibility")
    calls = []
    gen = torch.Generator().manual_seed(1)
    stats = train_variance_head(model, obs, tiny_config(), EntropyConfig(), gen, progress=lambda *a: calls.append(a))
    assert stats["last_loss"] < stats["first_loss"]
    assert stats["iters"] == 15 and stats["steps"] == 15
    assert same(frozen, params(model, "backbone") + params(model, "visibility"))
    assert [c[:3] for c in calls] == [("variance", k, 15) for k in range(15)]


def test_variance_stage_trains_as_with_every_graph_recorded(trained, monkeypatch):
    """Freezing the other parameters for stage 2 only spares memory: the variance head ends bit for bit where
    it ends when autograd records the whole field, the other parameters keep ``requires_grad`` and get no
    gradient."""
    model, obs = trained
    frozen, whole = copy_model(model), copy_model(model)
    train_variance_head(frozen, obs, tiny_config(), EntropyConfig(), torch.Generator().manual_seed(1))
    assert all(p.requires_grad for p in frozen.parameters())
    assert all(p.grad is None for group in ("backbone", "visibility") for p in frozen.field.parameter_groups()[group])
    monkeypatch.setattr(training, "_only_trained", lambda model, trained: contextlib.nullcontext())
    train_variance_head(whole, obs, tiny_config(), EntropyConfig(), torch.Generator().manual_seed(1))
    assert same(params(frozen, "variance"), params(whole, "variance"))


def test_visibility_stage_bce_decreases(trained):
    """Stage 3 (M17-M19): the balanced BCE falls and only the visibility head moves."""
    model, obs = trained
    model = copy_model(model)
    frozen = params(model, "backbone") + params(model, "variance")
    stats = train_visibility_head(model, obs, tiny_config(), torch.Generator().manual_seed(2))
    assert stats["last_loss"] < stats["first_loss"]
    assert same(frozen, params(model, "backbone") + params(model, "variance"))


def test_reference_schedule_step_counts(trained):
    model, obs = trained
    model = copy_model(model)
    cfg = tiny_config(
        schedule=Schedule.reference, variance=StageBudget(2, 64, 1e-3), visibility=StageBudget(2, 256, 1e-3)
    )
    stats = train_model(model, obs, cfg, ["variance", "visibility"], EntropyConfig(), torch.Generator().manual_seed(0))
    assert list(stats.stages) == ["variance", "visibility"]
    assert stats.stages["variance"]["steps"] == 6  # D6: 3 fresh batches per iteration
    assert stats.stages["visibility"]["steps"] == 10  # D7: 5 steps on the same batch
    assert stats.seconds > 0


def test_ray_batch_follows_the_reference_dynamic_batch_d5():
    """D5: start at target // max_samples_per_ray rays, scale by target / kept samples; paper: fixed."""
    reference = RayBatch(tiny_config(schedule=Schedule.reference, target_samples=1000), 64, max_samples_per_ray=100)
    assert reference.rays == 10
    reference.update(500)  # half the target kept: twice the rays
    assert reference.rays == 20
    reference.update(0)  # nothing kept: unchanged (our choice; the reference would divide by zero)
    assert reference.rays == 20
    reference.update(1)  # capped at target_samples rays
    assert reference.rays == 1000
    paper = RayBatch(tiny_config(), 64, max_samples_per_ray=100)
    paper.update(500)
    assert paper.rays == 64


def test_reference_schedule_keeps_about_target_samples_per_batch(trained):
    """D5: with ``schedule=reference`` the backbone's batches adapt until they keep about ``target_samples``."""
    model, obs = trained
    target = 3000
    cfg = tiny_config(schedule=Schedule.reference, target_samples=target, backbone=StageBudget(12, 256, 1e-2))
    kept: list[int] = []
    model = copy_model(model)
    render = model.render

    def counting_render(*args, **kwargs):
        result = render(*args, **kwargs)
        kept.append(result.samples.num_samples)
        return result

    model.render = counting_render
    stats = train_backbone(model, obs, cfg, torch.Generator().manual_seed(0))
    assert kept[0] < target / 4  # starts at target // 1024 = 2 rays
    assert all(0.5 * target < k < 2.0 * target for k in kept[-4:]), kept
    assert stats["rays_per_batch"] != 256


def test_ablation_affects_training_wo_var_skips_variance_stage(trained):
    model, obs = trained
    model = copy_model(model)
    before = params(model, "variance")
    cfg = tiny_config(ablation_affects_training=True, variance=StageBudget(2, 64, 1e-2))
    stats = train_variance_head(model, obs, cfg, EntropyConfig(use_variance=False), torch.Generator())
    assert stats["steps"] == 0 and same(before, params(model, "variance"))
    # w/o Vis. still trains the head (raw-density weights, v-split kept)
    stats = train_variance_head(model, obs, cfg, EntropyConfig(use_visibility=False), torch.Generator())
    assert stats["steps"] == 2 and not same(before, params(model, "variance"))


def test_train_model_runs_stages_in_order():
    obs, model = ball_observations(3), tiny_model()
    cfg = tiny_config(
        stage_order=StageOrder.vis_first,
        backbone=StageBudget(4, 64, 1e-2),
        variance=StageBudget(2, 64, 1e-3),
        visibility=StageBudget(2, 128, 1e-3),
    )
    seen = []
    stats = train_model(
        model,
        obs,
        cfg,
        ["backbone", "variance", "visibility"],
        EntropyConfig(),
        torch.Generator().manual_seed(0),
        progress=lambda stage, k, total, loss: seen.append(stage),
    )
    assert list(stats.stages) == ["backbone", "visibility", "variance"]
    assert seen == ["backbone"] * 4 + ["visibility"] * 2 + ["variance"] * 2
    with pytest.raises(ValueError, match="unknown training stages"):
        train_model(model, obs, cfg, ["colour"], EntropyConfig(), torch.Generator())


def test_wo_vis_trains_no_visibility_head_and_all_else_as_nvf():
    """METHOD 11: w/o Vis.'s score never reads ``v`` and, with ``var_first``, no stage after the head does, so
    the head is not trained (its collapse failed a w/o Vis. run); the backbone and variance head are exactly
    full NVF's. With ``vis_first`` the variance head reads the trained head, so it stays."""
    nvf = ["backbone", "variance", "visibility"]
    wo_vis = EntropyConfig(use_visibility=False)
    assert stages_to_train(nvf, tiny_config(), EntropyConfig()) == ("backbone", "variance", "visibility")
    assert stages_to_train(nvf, tiny_config(), wo_vis) == ("backbone", "variance")
    assert stages_to_train(nvf, tiny_config(stage_order=StageOrder.vis_first), wo_vis) == (
        "backbone",
        "visibility",
        "variance",
    )
    obs = ball_observations(3)
    cfg = tiny_config(
        backbone=StageBudget(4, 64, 1e-2), variance=StageBudget(2, 64, 1e-3), visibility=StageBudget(2, 128, 1e-3)
    )
    models = {}
    for name, entropy in (("nvf", EntropyConfig()), ("wo_vis", wo_vis)):
        model = tiny_model(seed=4)
        untrained = params(model, "visibility")
        stats = train_model(
            model, obs, cfg, stages_to_train(nvf, cfg, entropy), entropy, torch.Generator().manual_seed(5)
        )
        models[name] = (model, same(untrained, params(model, "visibility")), list(stats.stages))
    assert models["nvf"][2] == nvf and models["wo_vis"][2] == ["backbone", "variance"]
    assert not models["nvf"][1] and models["wo_vis"][1]
    for group in ("backbone", "variance"):
        assert same(params(models["nvf"][0], group), params(models["wo_vis"][0], group)), group


def test_appearance_embedding_is_trained_per_image():
    """(D8) With ``field.appearance_embedding`` every training image's embedding gets gradient, not only image 0's."""
    obs = ball_observations(3)
    torch.manual_seed(0)
    field_cfg = FieldConfig(
        num_levels=4,
        log2_hashmap_size=12,
        base_resolution=4,
        max_resolution=32,
        hidden_dim=32,
        appearance_embedding=True,
    )
    sampler_cfg = SamplerConfig(grid_resolution=16, step_size=0.03, warmup_iters=16, update_every=4)
    model = SceneModel(AABB, field_cfg, sampler_cfg, num_images=obs.num_images)
    before = model.field.appearance.weight.detach().clone()
    train_backbone(model, obs, tiny_config(backbone=StageBudget(10, 256, 1e-2)), torch.Generator().manual_seed(0))
    changed = (model.field.appearance.weight.detach() != before).any(dim=1)
    assert changed.all(), changed


def test_backbone_marks_the_cells_its_samples_reached(trained):
    """Stage 1 marks ``grid.observed`` (read by M29 with ``planner.los_unobserved_free``): the ball's
    surface facing the cameras is reached, its centre (behind an opaque surface from every camera) is not."""
    model, obs = trained
    toward_camera = torch.nn.functional.normalize(obs.c2w[:, :3, 3], dim=-1)
    radii = torch.linspace(0.35, 0.75, 9)  # the surface is at 0.5; cells are 0.125 wide
    near_surface = radii[:, None, None] * toward_camera  # [9, cameras, 3]
    assert model.grid.is_observed(near_surface.reshape(-1, 3)).reshape(9, -1).any(0).all()
    assert not model.grid.is_observed(torch.zeros(1, 3)).any()
    assert 0.0 < model.grid.observed.float().mean() < 1.0


# --------------------------------------------------------------------------- mixed precision


def test_low_precision_render_is_within_tolerance_of_float32_on_a_fixed_batch(trained):
    """``train.precision=bf16`` runs only the MLPs' layers in bfloat16: on a fixed batch the M20 loss is
    within 5% of float32's and its gradients point the same way (cosine > 0.95); the hash table, the
    volume-rendering sums (M1-M3) and the loss stay float32."""
    model, obs = trained
    model = copy_model(model)
    origins, dirs, rgba, _ = obs.sample_rays(256, torch.Generator().manual_seed(5))
    background = torch.full((256, 3), 0.5)
    runs = {}
    for dtype in (torch.float32, torch.bfloat16):
        model.zero_grad(set_to_none=True)
        with model.field.mlp_precision(dtype):
            result = model.render(origins, dirs)
        pred = composite(result.rgb, result.acc, background)
        loss = ((pred - composite(rgba[:, :3] * rgba[:, 3:], rgba[:, 3], background)) ** 2).mean()
        loss.backward()
        grads = torch.cat([p.grad.flatten() for p in model.field.parameter_groups()["backbone"]])
        runs[dtype] = (result, loss.detach(), grads)
        for name in ("sigma", "alpha", "weights", "trans", "rgb_s", "rgb", "depth", "acc"):
            assert getattr(result, name).dtype == torch.float32, name
        assert loss.dtype == model.field.encoding.table.dtype == model.field.encoding.table.grad.dtype == torch.float32
    (exact, exact_loss, exact_grads), (low, low_loss, low_grads) = runs[torch.float32], runs[torch.bfloat16]
    # alpha skipping (section 4) tests the densities against a threshold: a few samples near it may flip
    assert abs(low.samples.num_samples - exact.samples.num_samples) <= 0.02 * exact.samples.num_samples
    assert (low.rgb - exact.rgb).abs().max() < 0.02
    assert abs(low_loss - exact_loss) <= 0.05 * exact_loss
    assert torch.nn.functional.cosine_similarity(low_grads, exact_grads, dim=0) > 0.95


@pytest.mark.parametrize("precision", ["bf16", "fp16"])
def test_low_precision_backbone_trains_and_keeps_samples(precision):
    """A mixed-precision stage 1 trains like float32's: the loss falls to within 1.5x of float32's final
    loss and samples survive the occupancy grid (a bfloat16 density activation once tied every cell's
    density at initialisation, so that no cell was occupied and nothing was ever sampled). fp16 scales
    the loss and reports skipped steps."""
    obs = ball_observations()
    stats = {}
    for name in ("fp32", precision):
        model = tiny_model()
        stats[name] = train_backbone(
            model, obs, tiny_config(precision=Precision(name)), torch.Generator().manual_seed(0)
        )
        assert model.grid.occupied.any() and stats[name]["samples_per_ray"] > 1.0, name
    assert stats[precision]["last_loss"] < 0.5 * stats[precision]["first_loss"]
    assert stats[precision]["last_loss"] < 1.5 * stats["fp32"]["last_loss"]
    assert ("skipped_steps" in stats[precision]) == (precision == "fp16")


@pytest.mark.parametrize("precision", ["bf16", "fp16"])
def test_low_precision_nan_is_divergence(precision):
    obs = ball_observations(2)
    obs.images[0, ..., 0] = math.nan
    cfg = tiny_config(backbone=StageBudget(50, 64, 1e-2), precision=Precision(precision))
    with pytest.raises(TrainingDiverged, match=r"backbone stage diverged at iteration 0"):
        train_backbone(tiny_model(), obs, cfg, torch.Generator().manual_seed(0))


def test_fp16_gradients_that_overflow_unscaled_are_divergence():
    """With fp16 a step whose gradients overflow is skipped and the loss scale halved; once the scale
    falls below 1 (the gradients overflow float16 unscaled) the stage fails instead of silently never
    stepping. Targets of 1e8 make every gradient overflow while the float32 loss stays finite."""
    obs = ball_observations(2)
    obs.images[..., :3] *= 1e8
    cfg = tiny_config(backbone=StageBudget(40, 64, 1e-2), precision=Precision.fp16)
    with pytest.raises(TrainingDiverged, match=r"float16 gradients overflow at loss scale 0\.5"):
        train_backbone(tiny_model(), obs, cfg, torch.Generator().manual_seed(0))
