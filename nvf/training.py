"""The three training stages of an active-mapping step (METHOD.md section 10; M4, M19-M21, M25, M27).

Stage 1 fits the backbone and colour head (M20, optionally with the ActiveNeRF/NeurAR auxiliary
variance losses M25/M27), stage 2 the variance head (M21), stage 3 the visibility head (M19 on the
labels M17-M18). Nothing here prints; callers observe progress through the ``progress`` callback
``(stage, iteration, total, loss)``, called once per iteration.
"""

import contextlib
import dataclasses
import functools
from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass

import torch
from jaxtyping import Float
from torch import Tensor

from nvf.config import STAGES, EntropyConfig, TrainConfig
from nvf.losses import AuxLoss, composite, ground_truth, variance_nll, visibility_bce
from nvf.model import SceneModel
from nvf.observations import Observations
from nvf.precision import precision_dtype
from nvf.rendering import ray_sum
from nvf.stage_recorder import Progress, StageRecorder
from nvf.uncertainty.mixture import mixture_log_density, ray_mixture
from nvf.visibility import visibility_labels

REFERENCE_STEPS = {"variance": 3, "visibility": 5}  # D6, D7: Adam steps per iteration (schedule=reference)
BACKBONE_ADAM_EPS = 1e-15
LR_DECAY_BASE = 0.01  # backbone lr(k) = lr * 0.01 ** (k / horizon)
_HEADS_VARIANCE_STAGE = frozenset({"rgb", "variance", "visibility"})
_HEADS_VISIBILITY = frozenset({"visibility"})


@dataclass
class TrainStats:
    """Per-stage summaries in run order (``iters``, ``steps``, ``first_loss``, ``last_loss``,
    ``seconds``; stage 1 with an auxiliary loss adds ``first_aux_loss``, ``last_aux_loss``)."""

    stages: dict[str, dict[str, float]]

    @property
    def seconds(self) -> float:
        return sum(s["seconds"] for s in self.stages.values())


def backbone_lr(cfg: TrainConfig, iteration: int) -> float:
    """Stage-1 learning rate ``lr(k) = lr * 0.01 ** (k / lr_decay_horizon)`` (section 10, D5)."""
    return cfg.backbone.lr * LR_DECAY_BASE ** (iteration / cfg.lr_decay_horizon)


# ---------------------------------------------------------------------------------------- helpers


def _background(
    batch: int, cfg_background: str, generator: torch.Generator, like: Float[Tensor, "..."]
) -> Float[Tensor, "B 3"]:
    """Per-ray background ``b ~ U[0,1]^3`` (M4), or black."""
    if cfg_background == "black":
        return torch.zeros(batch, 3, dtype=like.dtype, device=like.device)
    if cfg_background != "random":
        raise ValueError(f"var_loss_background must be 'random' or 'black', got {cfg_background!r}")
    return torch.rand(batch, 3, generator=generator, device=generator.device).to(like)


def _steps_per_iteration(cfg: TrainConfig, stage: str) -> int:
    if cfg.schedule == "paper":
        return 1
    if cfg.schedule == "reference":
        return REFERENCE_STEPS[stage]
    raise ValueError(f"schedule must be 'paper' or 'reference', got {cfg.schedule!r}")


class RayBatch:
    """Rays per batch of the backbone and variance stages (METHOD 10, D5).

    ``schedule=paper``: ``batch`` rays every time. ``schedule=reference``: the reference's dynamic
    batch: start at ``target_samples // max_samples_per_ray`` rays (256 with METHOD's 2^18 and
    1024), then after each batch scale the count by ``target_samples / kept samples``, truncated,
    so that a batch keeps about ``target_samples`` samples. Two choices of ours: the count stays in
    ``[1, target_samples]``, and a batch that kept no sample leaves it unchanged.
    """

    def __init__(self, cfg: TrainConfig, batch: int, max_samples_per_ray: int):
        self.dynamic = cfg.schedule == "reference"
        self.target = cfg.target_samples
        self.rays = max(1, self.target // max_samples_per_ray) if self.dynamic else batch

    def update(self, kept_samples: int) -> None:
        """Adapt the next batch to the samples the last one kept (a no-op for ``schedule=paper``)."""
        if self.dynamic and kept_samples > 0:
            self.rays = min(self.target, max(1, int(self.rays * (self.target / kept_samples))))


# ----------------------------------------------------------------------------------------- stages


def _in_training_precision(stage: Callable[..., dict[str, float]]) -> Callable[..., dict[str, float]]:
    """Run a stage ``stage(model, obs, cfg, ...)`` with the field's MLPs in ``cfg.precision`` where they
    run with autograd (``RadianceField.mlp_precision``): float32 (unchanged) by default, bf16 or fp16 for
    mixed precision. Their calls without autograd (the skipping pass, occupancy updates, visibility
    labels) stay float32: bf16 is no faster there (docs/BUDGETS.md, "Mixed precision"), and the grid and
    the labels see float32 densities."""

    @functools.wraps(stage)
    def run(model: SceneModel, obs: Observations, cfg: TrainConfig, *args, **kwargs) -> dict[str, float]:
        with model.field.mlp_precision(precision_dtype(cfg.precision)):
            return stage(model, obs, cfg, *args, **kwargs)

    return run


@_in_training_precision
def train_backbone(
    model: SceneModel,
    obs: Observations,
    cfg: TrainConfig,
    generator: torch.Generator,
    aux_loss: AuxLoss | None = None,
    progress: Progress | None = None,
) -> dict[str, float]:
    """Stage 1: hash grid, density MLP and colour head on (M20) with the random background (M4).

    ``cfg.backbone.batch`` rays per iteration, or the dynamic batch with ``schedule=reference`` (``RayBatch``, D5).
    Adam (eps 1e-15), ``lr(k) = lr * 0.01 ** (k / lr_decay_horizon)``; ``model.update_grid`` is
    called every iteration and refreshes the occupancy grid (M5) every ``update_every``; the cells of
    each batch's kept samples are marked observed (``grid.mark_observed``, read by M29's
    ``planner.los_unobserved_free``). ``aux_loss`` (a method's, e.g. ActiveNeRF's M25 or NeurAR's M27)
    also trains the variance head, in the same Adam steps and with the same lr, on
    ``V_r = sum_i sg(w_i) q_i`` and the detached squared residual, so the backbone is unaffected.
    """
    obs.require_images()
    groups = model.field.parameter_groups()
    param_groups = [{"params": groups["backbone"]}]
    heads = frozenset({"rgb"})
    if aux_loss is not None:
        param_groups.append({"params": groups["variance"]})
        heads = heads | {"variance"}
    optimizer = torch.optim.Adam(param_groups, lr=cfg.backbone.lr, eps=BACKBONE_ADAM_EPS, fused=True)
    rec = StageRecorder("backbone", cfg.backbone.iters, progress, cfg.precision, model.aabb.device.type)
    batch = RayBatch(cfg, cfg.backbone.batch, model.sampler_cfg.max_samples_per_ray)
    aux_losses: list[float] = []
    for k in range(cfg.backbone.iters):
        model.update_grid(k, generator)  # M5: a no-op unless k % sampler.update_every == 0
        for group in optimizer.param_groups:
            group["lr"] = backbone_lr(cfg, k)
        origins, dirs, rgba, image = obs.sample_rays(batch.rays, generator)
        background = _background(origins.shape[0], "random", generator, origins)
        result = model.render(origins, dirs, heads=heads, train=True, generator=generator, image_idx=image)
        rec.count(result.samples)
        batch.update(result.samples.num_samples)
        model.grid.mark_observed(result.samples.positions(origins, dirs))
        pred = composite(result.rgb, result.acc, background)
        gt = ground_truth(rgba, background)
        loss = ((pred - gt) ** 2).mean()  # M20
        value = rec.check(loss, k)
        if aux_loss is not None:
            assert result.variance is not None, "stage 1 with an auxiliary loss renders the variance head"
            samples = result.samples
            ray_var = ray_sum(result.weights.detach()[:, None] * result.variance, samples.ray_idx, samples.n_rays)
            sq_residual = (gt - pred).detach() ** 2
            aux = aux_loss(ray_var, sq_residual)
            aux_losses.append(rec.check(aux, k))
            loss = loss + aux
        rec.step(optimizer, loss)
        rec.end_iteration(k, value)
    summary = rec.summary()
    if aux_losses:
        summary["first_aux_loss"], summary["last_aux_loss"] = aux_losses[0], aux_losses[-1]
    return summary


def variance_mixture_config(cfg: TrainConfig, entropy_cfg: EntropyConfig) -> EntropyConfig | None:
    """Mixture settings of (M21); ``None`` when the stage trains nothing.

    By default the ablation switches only change the score (section 11): the full mixture is
    used. With ``ablation_affects_training``: w/o Var. fixes ``q = 1e-4`` so the head gets no
    gradient (stage skipped); w/o Vis. renders the weights from the raw density but keeps the
    ``v : 1 - v`` split, which is (M7) with ``beta = 1``.
    """
    full = dataclasses.replace(entropy_cfg, use_visibility=True, use_variance=True)
    if not cfg.ablation_affects_training:
        return full
    if not entropy_cfg.use_variance:
        return None
    if not entropy_cfg.use_visibility:
        return dataclasses.replace(full, beta=1.0)
    return full


@_in_training_precision
def train_variance_head(
    model: SceneModel,
    obs: Observations,
    cfg: TrainConfig,
    entropy_cfg: EntropyConfig,
    generator: torch.Generator,
    progress: Progress | None = None,
) -> dict[str, float]:
    """Stage 2: the variance head only, on the mixture NLL (M21) of fresh ray batches.

    The mixture (M9) uses the frozen density, colours and the current visibility head (untrained
    under ``var_first``); only ``q`` carries gradients. ``z`` is the ground truth on a random
    (or black, ``cfg.var_loss_background``) background. Adam with default eps, constant lr;
    ``schedule=reference`` takes 3 steps per iteration, each on a fresh dynamic batch (D6, ``RayBatch``). Iteration
    losses are means over their steps.
    """
    obs.require_images()
    mix_cfg = variance_mixture_config(cfg, entropy_cfg)
    rec = StageRecorder("variance", cfg.variance.iters, progress, cfg.precision, model.aabb.device.type)
    if mix_cfg is None:
        return rec.summary()
    trained = model.field.parameter_groups()["variance"]
    optimizer = torch.optim.Adam(trained, lr=cfg.variance.lr, fused=True)
    batch = RayBatch(cfg, cfg.variance.batch, model.sampler_cfg.max_samples_per_ray)
    with _only_trained(model, trained):
        _variance_iterations(model, obs, cfg, mix_cfg, generator, optimizer, batch, rec)
    return rec.summary()


@contextlib.contextmanager
def _only_trained(model: SceneModel, trained: list[torch.nn.Parameter]) -> Iterator[None]:
    """Every parameter of ``model`` outside ``trained`` frozen (``requires_grad`` off) for the block: autograd
    then records only what reaches ``trained``. The variance stage's loss reads the density, colours and
    visibility detached, so their graphs (the encoding's and the other MLPs') were memory alone: on Room at
    the paper's sizes 3x stage 1's per sample (results/bench/README.md, "paper_shape.json")."""
    frozen = [p for p in model.parameters() if p.requires_grad and not any(p is q for q in trained)]
    for p in frozen:
        p.requires_grad_(False)
    try:
        yield
    finally:
        for p in frozen:
            p.requires_grad_(True)


def _variance_iterations(
    model: SceneModel,
    obs: Observations,
    cfg: TrainConfig,
    mix_cfg: EntropyConfig,
    generator: torch.Generator,
    optimizer: torch.optim.Optimizer,
    batch: RayBatch,
    rec: StageRecorder,
) -> None:
    """Stage 2's iterations (``train_variance_head``)."""
    steps = _steps_per_iteration(cfg, "variance")
    for k in range(cfg.variance.iters):
        values = []
        for _ in range(steps):
            origins, dirs, rgba, image = obs.sample_rays(batch.rays, generator)
            background = _background(origins.shape[0], cfg.var_loss_background, generator, origins)
            result = model.render(
                origins, dirs, heads=_HEADS_VARIANCE_STAGE, train=True, generator=generator, image_idx=image
            )
            samples = result.samples
            rec.count(samples)
            batch.update(samples.num_samples)
            assert result.rgb_s is not None and result.variance is not None and result.visibility is not None
            mixture, _ = ray_mixture(
                result.alpha.detach(),
                result.rgb_s.detach(),
                result.variance,
                result.visibility.detach(),
                samples.ray_idx,
                samples.n_rays,
                mix_cfg,
            )
            loss = variance_nll(mixture_log_density(mixture, ground_truth(rgba, background)))
            values.append(rec.check(loss, k))
            rec.step(optimizer, loss)
        rec.end_iteration(k, sum(values) / len(values))


@_in_training_precision
def train_visibility_head(
    model: SceneModel,
    obs: Observations,
    cfg: TrainConfig,
    generator: torch.Generator,
    progress: Progress | None = None,
) -> dict[str, float]:
    """Stage 3: the visibility head only, on the balanced BCE (M19).

    Each iteration draws ``cfg.visibility.batch`` points uniformly in the object AABB and labels
    them (M17-M18) with the **current** density and all observed cameras (stratified label
    samples from ``generator``); with ``cfg.label_lattice`` above 0 that density is sampled once on its
    lattice (``SceneModel.label_density``) and read from it. Adam with default eps, constant lr;
    ``schedule=reference`` takes 5 steps on the same batch (D7). Iteration losses are means over their steps.
    """
    obs.require_images()
    steps = _steps_per_iteration(cfg, "visibility")
    aabb = model.aabb
    support = model.density_support()  # the grid and the density are fixed in this stage
    density = model.label_density(cfg.label_lattice)
    c2w = obs.c2w.to(aabb.device)
    optimizer = torch.optim.Adam(model.field.parameter_groups()["visibility"], lr=cfg.visibility.lr, fused=True)
    rec = StageRecorder("visibility", cfg.visibility.iters, progress, cfg.precision, aabb.device.type)

    for k in range(cfg.visibility.iters):
        u = torch.rand(cfg.visibility.batch, 3, generator=generator, device=generator.device).to(aabb)
        points = aabb[0] + u * (aabb[1] - aabb[0])
        labels = visibility_labels(
            density, points, c2w, obs.intrinsics, cfg, generator=generator, aabb=support.box, grid=support.grid
        )
        no_dirs = torch.zeros_like(points)
        values = []
        for _ in range(steps):
            logits = model.field(points, no_dirs, _HEADS_VISIBILITY).vis_logit
            loss = visibility_bce(logits, labels)
            values.append(rec.check(loss, k))
            rec.step(optimizer, loss)
        rec.end_iteration(k, sum(values) / len(values))
    return rec.summary()


def stage_order(cfg: TrainConfig) -> tuple[str, ...]:
    """Stage run order: backbone first, then variance/visibility per ``cfg.stage_order``."""
    if cfg.stage_order == "var_first":
        return ("backbone", "variance", "visibility")
    if cfg.stage_order == "vis_first":
        return ("backbone", "visibility", "variance")
    raise ValueError(f"stage_order must be 'var_first' or 'vis_first', got {cfg.stage_order!r}")


def stages_to_train(stages: Collection[str], cfg: TrainConfig, entropy: EntropyConfig) -> tuple[str, ...]:
    """The method's ``stages`` in run order (``stage_order``), less the visibility head where nothing reads
    it (METHOD 11): a score that ignores ``v`` (``entropy.use_visibility=false``, w/o Vis.) with the head
    trained after the variance head (``var_first``). The stages before it draw and train exactly as with it."""
    unread = not entropy.use_visibility and cfg.stage_order == "var_first"
    return tuple(s for s in stage_order(cfg) if s in stages and not (s == "visibility" and unread))


def train_model(
    model: SceneModel,
    obs: Observations,
    cfg: TrainConfig,
    stages: Collection[str],
    entropy_cfg: EntropyConfig,
    generator: torch.Generator,
    aux_loss: AuxLoss | None = None,
    progress: Progress | None = None,
) -> TrainStats:
    """Run the requested ``stages`` (a subset of backbone, variance, visibility) in the order of
    ``cfg.stage_order`` on ``model`` as given (re-creating it for each step is the caller's job)."""
    unknown = set(stages) - set(STAGES)
    if unknown:
        raise ValueError(f"unknown training stages {sorted(unknown)}; expected a subset of {STAGES}")
    obs.require_images()
    summaries: dict[str, dict[str, float]] = {}
    for stage in stage_order(cfg):
        if stage not in stages:
            continue
        if stage == "backbone":
            summaries[stage] = train_backbone(model, obs, cfg, generator, aux_loss, progress)
        elif stage == "variance":
            summaries[stage] = train_variance_head(model, obs, cfg, entropy_cfg, generator, progress)
        else:
            summaries[stage] = train_visibility_head(model, obs, cfg, generator, progress)
    return TrainStats(summaries)
