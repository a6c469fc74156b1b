"""The three training stages of an active-mapping step (METHOD.md section 10; M4, M19-M21, M25, M27).

Stage 1 fits the backbone and colour head (M20, optionally with the ActiveNeRF/NeurAR auxiliary
variance losses M25/M27), stage 2 the variance head (M21), stage 3 the visibility head (M19 on the
labels M17-M18). Nothing here prints; callers observe progress through the ``progress`` callback
``(stage, iteration, total, loss)``, called once per iteration.
"""

import contextlib
import dataclasses
import functools
import math
import time
from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from jaxtyping import Float, Int
from torch import Tensor

from nvf.cameras import Intrinsics, camera_directions
from nvf.config import STAGES, EntropyConfig, TrainConfig
from nvf.model import SceneModel
from nvf.precision import precision_dtype
from nvf.rendering import Samples, ray_sum
from nvf.uncertainty.mixture import mixture_log_density, ray_mixture
from nvf.visibility import visibility_labels

Progress = Callable[[str, int, int, float], None]
# (rendered ray variance V_r [R, 3], squared residual [R, 3]) -> loss (M25, M27)
AuxLoss = Callable[[Float[Tensor, "R 3"], Float[Tensor, "R 3"]], Float[Tensor, ""]]
REFERENCE_STEPS = {"variance": 3, "visibility": 5}  # D6, D7: Adam steps per iteration (schedule=reference)
BACKBONE_ADAM_EPS = 1e-15
LR_DECAY_BASE = 0.01  # backbone lr(k) = lr * 0.01 ** (k / horizon)
VAR_LOSS_SCALE = 0.01  # M21
VAR_P_FLOOR = 1e-7  # M21: -ln max(p, 1e-7)
AUX_VAR_EPS = 1e-9  # M25
NEURAR_SCALE = 0.01  # M27
BCE_POS_THRESHOLD = 0.5  # M19
_HEADS_VARIANCE_STAGE = frozenset({"rgb", "variance", "visibility"})
_HEADS_VISIBILITY = frozenset({"visibility"})


COLLAPSE_WINDOW = 5  # iterations averaged by the collapse rule (_Recorder)
COLLAPSE_FACTOR = 4.0  # ... and the rise over the lowest earlier average that counts as a collapse
COLLAPSE_STAGES = frozenset({"backbone", "visibility"})  # non-negative losses (M20, M19)


class TrainingDiverged(RuntimeError):
    """A training loss became NaN or infinite, or collapsed (``_Recorder``); the message names the stage,
    the iteration and the numbers."""


@dataclass
class Observations:
    """All images observed so far: RGBA in ``[0, 1]`` (RGB zero where alpha = 0), their poses and
    the shared intrinsics. Rays are drawn uniformly over all pixels of all images (section 10)."""

    images: Float[Tensor, "N H W 4"]
    c2w: Float[Tensor, "N 4 4"]
    intrinsics: Intrinsics

    def __post_init__(self) -> None:
        if self.c2w.shape[0] != self.images.shape[0]:
            raise ValueError(f"{self.images.shape[0]} images but {self.c2w.shape[0]} poses")
        if self.images.shape[1:3] != (self.intrinsics.height, self.intrinsics.width):
            raise ValueError(
                f"images are {tuple(self.images.shape[1:3])} (H, W) but the intrinsics are "
                f"{self.intrinsics.height}x{self.intrinsics.width}"
            )

    @property
    def num_images(self) -> int:
        return int(self.images.shape[0])

    def sample_rays(
        self, batch: int, generator: torch.Generator
    ) -> tuple[Float[Tensor, "B 3"], Float[Tensor, "B 3"], Float[Tensor, "B 4"], Int[Tensor, " B"]]:
        """``batch`` pixels drawn uniformly (with replacement) over all pixels of all images:
        world-frame origins, unit directions, the RGBA ground truth and each ray's image index."""
        _require_images(self)
        n, h, w = self.images.shape[:3]
        flat = torch.randint(n * h * w, (batch,), generator=generator, device=generator.device)
        flat = flat.to(self.images.device)
        image, pixel = flat // (h * w), flat % (h * w)
        cam_dirs = camera_directions(self.intrinsics, self.images.device)[pixel]
        c2w = self.c2w[image]
        dirs = torch.einsum("bij,bj->bi", c2w[:, :3, :3], cam_dirs)
        dirs = dirs / torch.linalg.norm(dirs, dim=-1, keepdim=True)
        return c2w[:, :3, 3], dirs, self.images.reshape(-1, 4)[flat], image


@dataclass
class TrainStats:
    """Per-stage summaries in run order (``iters``, ``steps``, ``first_loss``, ``last_loss``,
    ``seconds``; stage 1 with an auxiliary loss adds ``first_aux_loss``, ``last_aux_loss``)."""

    stages: dict[str, dict[str, float]]

    @property
    def seconds(self) -> float:
        return sum(s["seconds"] for s in self.stages.values())


# ----------------------------------------------------------------------------------------- losses


def backbone_lr(cfg: TrainConfig, iteration: int) -> float:
    """Stage-1 learning rate ``lr(k) = lr * 0.01 ** (k / lr_decay_horizon)`` (section 10, D5)."""
    return cfg.backbone.lr * LR_DECAY_BASE ** (iteration / cfg.lr_decay_horizon)


def composite(
    rgb: Float[Tensor, "R 3"], opacity: Float[Tensor, " R"], background: Float[Tensor, "R 3"]
) -> Float[Tensor, "R 3"]:
    """(M4) ``rgb + (1 - opacity) b``: the prediction with ``(C_hat, A)``, the ground truth with
    ``(c_gt alpha_gt, alpha_gt)``."""
    return rgb + (1.0 - opacity)[:, None] * background


def _ground_truth(rgba: Float[Tensor, "R 4"], background: Float[Tensor, "R 3"]) -> Float[Tensor, "R 3"]:
    """(M4) ``c_gt alpha_gt + (1 - alpha_gt) b``."""
    alpha = rgba[:, 3]
    return composite(rgba[:, :3] * alpha[:, None], alpha, background)


def activenerf_loss(ray_variance: Float[Tensor, "R 3"], sq_residual: Float[Tensor, "R 3"]) -> Float[Tensor, ""]:
    """(M25) ``mean[ sg(res^2) / (2 (V + 1e-9)) + 0.5 ln(V + 1e-9) ]``; the residual is detached."""
    v = ray_variance + AUX_VAR_EPS
    return (sq_residual.detach() / (2.0 * v) + 0.5 * torch.log(v)).mean()


def neurar_loss(ray_variance: Float[Tensor, "R 3"], sq_residual: Float[Tensor, "R 3"]) -> Float[Tensor, ""]:
    """(M27) ``0.01 mean (V - sg(res^2))^2``; the residual is detached."""
    return NEURAR_SCALE * ((ray_variance - sq_residual.detach()) ** 2).mean()


def variance_nll(log_p: Float[Tensor, " R"]) -> Float[Tensor, ""]:
    """(M21) ``0.01 mean_{r: p_r > 0} [-ln max(p_r, 1e-7)]`` from ``ln p_r`` (``-inf`` when p_r = 0).

    NaN when no ray has ``p_r > 0`` (reported as divergence by the caller)."""
    valid = log_p > -math.inf
    return VAR_LOSS_SCALE * (-log_p[valid].clamp_min(math.log(VAR_P_FLOOR))).mean()


def balanced_bce_weights(labels: Float[Tensor, " N"]) -> Float[Tensor, " N"]:
    """(M19) ``w+ = 0.7/(2p) + 0.3``, ``w- = 0.7/(2(1-p)) + 0.3`` with ``p`` the fraction of
    ``labels > 0.5``; all ones if ``2p < 1e-7`` or ``2(1-p) < 1e-7``."""
    positive = labels > BCE_POS_THRESHOLD
    p = positive.float().mean().item()
    if 2.0 * p < 1e-7 or 2.0 * (1.0 - p) < 1e-7:
        return torch.ones_like(labels)
    w_pos, w_neg = 0.7 / (2.0 * p) + 0.3, 0.7 / (2.0 * (1.0 - p)) + 0.3
    return torch.where(positive, torch.full_like(labels, w_pos), torch.full_like(labels, w_neg))


def visibility_bce(logits: Float[Tensor, " N"], labels: Float[Tensor, " N"]) -> Float[Tensor, ""]:
    """(M19) ``mean_n [w_n BCEWithLogits(logit_n, V*_n)]`` (a plain mean, not normalised by sum w)."""
    bce = F.binary_cross_entropy_with_logits(logits, labels, reduction="none")
    return (balanced_bce_weights(labels) * bce).mean()


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


def _require_images(obs: Observations) -> None:
    if obs.num_images == 0:
        raise ValueError("empty training set: no observed images")


class _Recorder:
    """Loss history, divergence check, timing and progress of one stage.

    Divergence: a non-finite loss (any stage, ``check``), or a collapse (``end_iteration``) of a stage
    whose loss cannot be negative (``COLLAPSE_STAGES``: M20's squared error, M19's BCE): at a full
    window, the mean of the last ``COLLAPSE_WINDOW`` iteration losses exceeds both ``COLLAPSE_FACTOR``
    times the lowest such mean before it (over the first ``i + 1`` losses while ``i < COLLAPSE_WINDOW``)
    and the loss of the first iteration (the untrained model: training made it worse).
    The factor sits between what a diverging learning rate does to stage 1's loss and what normal training
    reaches (docs/DEVIATIONS.md, "training divergence", gives both). Variance NLL (M21, bounded above by its
    floor; it can be negative) and the auxiliary losses (M25 can be negative) are checked for non-finite
    values only.

    ``precision="fp16"`` scales the loss (``torch.amp.GradScaler``): float16 gradients of the MLPs
    would otherwise underflow. A step whose gradients overflow is skipped and the scale halved
    (``skipped_steps``); a scale below 1, gradients that overflow float16 unscaled, is divergence.
    """

    def __init__(self, stage: str, total: int, progress: Progress | None, precision: str = "fp32", device: str = "cpu"):
        self.stage, self.total, self.progress = stage, total, progress
        self.scaler = torch.amp.GradScaler(device) if precision == "fp16" else None
        self.losses: list[float] = []
        self.lowest_mean: float | None = None
        self.steps = self.skipped = 0
        self.samples = self.rays = self.batches = 0
        self.start = time.perf_counter()

    def count(self, samples: Samples) -> None:
        """Add one rendered batch to the stage's kept samples per ray."""
        self.samples += samples.num_samples
        self.rays += samples.n_rays
        self.batches += 1

    def check(self, loss: Float[Tensor, ""], iteration: int) -> float:
        value = float(loss.detach())
        if not math.isfinite(value):
            raise TrainingDiverged(f"{self.stage} stage diverged at iteration {iteration}: loss = {value}")
        return value

    def step(self, optimizer: torch.optim.Optimizer, loss: Float[Tensor, ""]) -> None:
        """Adam step on ``loss`` (skipped if nothing requires grad, e.g. a batch with no samples)."""
        optimizer.zero_grad(set_to_none=True)
        if not loss.requires_grad:
            return
        if self.scaler is None:
            loss.backward()
            optimizer.step()
            self.steps += 1
            return
        scale = self.scaler.get_scale()
        self.scaler.scale(loss).backward()
        self.scaler.step(optimizer)
        self.scaler.update()
        if self.scaler.get_scale() < scale:
            self.skipped += 1
        else:
            self.steps += 1
        if self.scaler.get_scale() < 1.0:
            raise TrainingDiverged(
                f"{self.stage} stage diverged after {self.steps + self.skipped} steps: float16 gradients "
                f"overflow at loss scale {self.scaler.get_scale()}"
            )

    def end_iteration(self, iteration: int, loss: float) -> None:
        self.losses.append(loss)
        if self.progress is not None:
            self.progress(self.stage, iteration, self.total, loss)
        if self.stage in COLLAPSE_STAGES:
            self._check_collapse(iteration)

    def _check_collapse(self, iteration: int) -> None:
        """The collapse rule of the class docstring."""
        window = self.losses[-COLLAPSE_WINDOW:]
        mean = sum(window) / len(window)
        lowest = self.lowest_mean
        full = len(window) == COLLAPSE_WINDOW and lowest is not None and lowest > 0
        if full and lowest is not None and mean > COLLAPSE_FACTOR * lowest and mean > self.losses[0]:
            raise TrainingDiverged(
                f"{self.stage} stage collapsed at iteration {iteration}: mean loss {mean:.4g} over the last "
                f"{COLLAPSE_WINDOW} iterations, {mean / lowest:.3g} times its lowest earlier mean {lowest:.4g} and "
                f"above the first iteration's {self.losses[0]:.4g} (limit {COLLAPSE_FACTOR:g}x; a learning rate too "
                "high?)"
            )
        self.lowest_mean = mean if lowest is None else min(lowest, mean)

    def summary(self) -> dict[str, float]:
        """Iterations, optimiser steps, first/last loss, seconds, and for stages that render rays
        ``samples_per_ray`` (the kept samples after alpha skipping, the stage's main cost) and
        ``rays_per_batch`` (mean; it varies with the reference's dynamic batch)."""
        nan = float("nan")
        summary = {
            "iters": float(len(self.losses)),
            "steps": float(self.steps),
            "first_loss": self.losses[0] if self.losses else nan,
            "last_loss": self.losses[-1] if self.losses else nan,
            "seconds": time.perf_counter() - self.start,
        }
        if self.scaler is not None:
            summary["skipped_steps"] = float(self.skipped)
        if self.rays:
            summary["samples_per_ray"] = self.samples / self.rays
            summary["rays_per_batch"] = self.rays / self.batches
        return summary


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
    _require_images(obs)
    groups = model.field.parameter_groups()
    param_groups = [{"params": groups["backbone"]}]
    heads = frozenset({"rgb"})
    if aux_loss is not None:
        param_groups.append({"params": groups["variance"]})
        heads = heads | {"variance"}
    optimizer = torch.optim.Adam(param_groups, lr=cfg.backbone.lr, eps=BACKBONE_ADAM_EPS, fused=True)
    rec = _Recorder("backbone", cfg.backbone.iters, progress, cfg.precision, model.aabb.device.type)
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
        gt = _ground_truth(rgba, background)
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
    _require_images(obs)
    mix_cfg = variance_mixture_config(cfg, entropy_cfg)
    rec = _Recorder("variance", cfg.variance.iters, progress, cfg.precision, model.aabb.device.type)
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
    rec: _Recorder,
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
            loss = variance_nll(mixture_log_density(mixture, _ground_truth(rgba, background)))
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
    _require_images(obs)
    steps = _steps_per_iteration(cfg, "visibility")
    aabb = model.aabb
    support = model.density_support()  # the grid and the density are fixed in this stage
    density = model.label_density(cfg.label_lattice)
    c2w = obs.c2w.to(aabb.device)
    optimizer = torch.optim.Adam(model.field.parameter_groups()["visibility"], lr=cfg.visibility.lr, fused=True)
    rec = _Recorder("visibility", cfg.visibility.iters, progress, cfg.precision, aabb.device.type)

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
    _require_images(obs)
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
