"""Evaluation of one step's model (PROTOCOL 4): image metrics on the 20 evaluation views, geometry
from training-view rays, visual coverage of the observed poses, and uncertainty-error correlation.
"""

import dataclasses
import functools
import math

import numpy as np
import torch
from jaxtyping import Float, Int
from torch import Tensor

from nvf.cameras import Intrinsics, pixel_rays
from nvf.model import SceneModel
from nvf.observations import Observations
from nvf.seeding import seeded_generator
from nvf.uncertainty import ViewScorer
from nvf.visibility_source import SourcedVisibility
from pipeline.config.structured_configs import BudgetConfig, MetricsConfig
from pipeline.metrics.arrays import as_numpy
from pipeline.metrics.correlation import uncertainty_correlation
from pipeline.metrics.geometry import GeometryMetrics, geometry_metrics, points_from_rays
from pipeline.metrics.image import ImageMetrics, LpipsFeatures, LpipsMetric, image_metrics, psnr
from pipeline.metrics.visual_coverage import seen_faces, visual_coverage
from pipeline.records.schema import Metrics
from pipeline.scenes.ground_truth import Renderer
from pipeline.scenes.scene import Scene

RENDER_CHUNK = 4096  # rays per model call at inference
STEP_METRICS = tuple(field.name for field in dataclasses.fields(Metrics))  # what ``Evaluator.evaluate`` records
PATCHES_PER_SIDE = 16  # PROTOCOL 4.4: 32x32 patches of a 512x512 view


@torch.no_grad()
def render_view(
    model: SceneModel | SourcedVisibility,
    scorer,
    c2w: Float[Tensor, "4 4"],
    intr: Intrinsics,
    chunk: int = RENDER_CHUNK,
) -> dict[str, np.ndarray]:
    """Colour [H,W,3], expected depth [H,W], accumulation [H,W] and the scorer's per-pixel score [H,W]
    (NaN without a scorer) of one view, rendered in row-major chunks of rays (M3)."""
    origins, dirs = pixel_rays(c2w, intr)
    heads = frozenset({"rgb"}) | (scorer.heads if scorer is not None else frozenset())
    shared = scorer is None or scorer.sampler == "occupancy"
    parts: dict[str, list[Tensor]] = {"rgb": [], "depth": [], "acc": [], "score": []}
    for start in range(0, intr.num_pixels, chunk):
        o, d = origins[start : start + chunk], dirs[start : start + chunk]
        result = model.render(o, d, heads=heads if shared else frozenset({"rgb"}))
        parts["rgb"].append(result.rgb)
        parts["depth"].append(result.depth)
        parts["acc"].append(result.acc)
        if scorer is None:
            parts["score"].append(torch.full_like(result.depth, math.nan))
            continue
        if not shared:
            result = model.render(o, d, heads=heads, sampler=scorer.sampler)
        index = torch.arange(start, start + o.shape[0], device=o.device)
        parts["score"].append(scorer.pixel_scores(result, pixel_index=index))
    shape = (intr.height, intr.width)
    return {
        key: torch.cat(values).reshape(*shape, -1).squeeze(-1).float().cpu().numpy() for key, values in parts.items()
    }


@torch.no_grad()
def reconstruct_points(
    model: SceneModel | SourcedVisibility, obs: Observations, num_points: int, batch: int, generator: torch.Generator
) -> np.ndarray:
    """Points ``o + D d`` of training-view rays with accumulation > 0.5 (PROTOCOL 4.2), drawn in
    batches of pixels uniformly over all training images until ``num_points`` (at most 4x the
    nominal number of batches, so a model that predicts little surface cannot loop forever).
    ``D`` and ``A`` need only the density, so no field head is evaluated."""
    points: list[np.ndarray] = []
    count = 0
    for _ in range(4 * math.ceil(num_points / batch)):
        origins, dirs, _, _ = obs.sample_rays(batch, generator)
        result = model.render(origins, dirs, heads=frozenset())
        new = as_numpy(points_from_rays(origins, dirs, result.depth, result.acc))
        points.append(new)
        count += len(new)
        if count >= num_points:
            break
    return np.concatenate(points)[:num_points] if points else np.zeros((0, 3))


class Evaluator:
    """Holds the evaluation views' ground truth (RGB and its LPIPS features, computed once, when first needed)
    and computes a step's metrics (PROTOCOL 4)."""

    def __init__(
        self,
        scene: Scene,
        renderer: Renderer,
        budget: BudgetConfig,
        metrics: MetricsConfig,
        seed: int,
        device: torch.device,
        lpips: LpipsMetric,
    ):
        self.scene, self.budget, self.metrics, self.seed = scene, budget, metrics, seed
        self.device, self.lpips, self.renderer = device, lpips, renderer
        size = budget.eval_size
        self.intrinsics = Intrinsics.from_fov(size, size)
        self.patch = max(1, size // PATCHES_PER_SIDE)

    @functools.cached_property
    def gt(self) -> Float[np.ndarray, "V H W 3"]:
        """The evaluation views' ground truth, rendered when first read (a command that evaluates nothing, such
        as ``pipeline.experiments.paper_states`` without outcomes, renders none)."""
        k = self.budget.gt_samples
        return np.stack([self.renderer.render_rgba(c2w, self.intrinsics, k)[..., :3] for c2w in self.scene.eval_poses])

    @functools.cached_property
    def gt_lpips(self) -> LpipsFeatures | None:
        """The step-independent half of LPIPS of ``gt`` (None without weights)."""
        return self.lpips.reference(self.gt)

    def renders(
        self, model: SceneModel | SourcedVisibility, scorer: ViewScorer | None
    ) -> tuple[list[dict[str, np.ndarray]], Float[np.ndarray, "V H W 3"]]:
        """Every evaluation view rendered (``render_view``) and their colours clipped to ``[0, 1]``."""
        renders = [render_view(model, scorer, c2w.to(self.device), self.intrinsics) for c2w in self.scene.eval_poses]
        return renders, np.stack([r["rgb"] for r in renders]).clip(0.0, 1.0)

    def quality(self, pred: Float[np.ndarray, "V H W 3"]) -> ImageMetrics:
        """PSNR, SSIM, LPIPS and RGB of the rendered evaluation views ``pred`` (PROTOCOL 4.1)."""
        return image_metrics(pred, self.gt, self.lpips, self.metrics.ssim_data_range, self.gt_lpips)

    def geometry(self, model: SceneModel | SourcedVisibility, obs: Observations, step: int) -> GeometryMetrics:
        """Acc., Comp. and C.R. (PROTOCOL 4.2) of the points reconstructed from ``obs``' rays at step ``step``
        against ``budget.gt_points`` samples of the scene mesh."""
        budget = self.budget
        points = reconstruct_points(
            model,
            obs,
            budget.recon_points,
            budget.recon_batch,
            seeded_generator(self.seed, step, "recon_points", self.device),
        )
        return geometry_metrics(
            points,
            self.scene.mesh,
            self.scene.cr_threshold,
            seed=int(seeded_generator(self.seed, step, "gt_points").initial_seed() % 2**32),
            num_gt_samples=budget.gt_points,
        )

    def evaluate(
        self,
        model: SceneModel | SourcedVisibility,
        scorer,
        face_ids: list[Int[np.ndarray, "H W"]],
        obs: Observations,
        step: int,
        view: int = 0,
        psnr_only: bool = False,
    ) -> tuple[dict, dict, dict]:
        """Metrics of ``model`` after training on ``obs`` (step ``step``), images of evaluation view ``view``,
        and with a per-pixel scorer (``ViewScorer``) ``view_error`` and ``view_score`` [V], the per-view sums the
        view r pairs (else empty: Random, or a method that scores whole views, has no score map and no
        correlation). ``face_ids``: the face hit by each pixel-centre ray of every training view (Vis.).
        ``psnr_only``: PSNR alone (every other metric None, no score map; ``step_metrics=psnr``)."""
        scene = self.scene
        if psnr_only or not isinstance(scorer, ViewScorer):
            scorer = None
        renders, pred = self.renders(model, scorer)
        if psnr_only:
            shown = renders[view]
            metrics = {key: None for key in STEP_METRICS} | {"psnr": psnr(pred, self.gt)}
            return (
                metrics,
                {"gt": self.gt[view], "pred": pred[view], "score": shown["score"], "depth": shown["depth"]},
                {},
            )
        quality = self.quality(pred)
        geometry = self.geometry(model, obs, step)
        num_faces = len(scene.mesh.faces)
        seen = np.zeros(num_faces, dtype=bool)
        for ids in face_ids:
            seen |= seen_faces(ids, num_faces)
        coverage = visual_coverage(seen, scene.mesh)
        corr, view_sums = (math.nan, math.nan, math.nan), {}
        if scorer is not None:
            c = uncertainty_correlation(pred, self.gt, np.stack([r["score"] for r in renders]), self.patch)
            corr = (c.patch_pearson, c.view_pearson, c.ause)
            view_sums = {"view_error": c.view_error, "view_score": c.view_score}
        metrics = {
            "psnr": quality.psnr,
            "ssim": quality.ssim,
            "lpips": quality.lpips,
            "rgb": quality.rgb,
            "acc": geometry.acc,
            "comp": geometry.comp,
            "cr": geometry.cr,
            "vis": coverage.vis,
            "vis_area": coverage.vis_area,
            "num_points": geometry.num_points,
            "patch_pearson": corr[0],
            "view_pearson": corr[1],
            "ause": corr[2],
        }
        shown = renders[view]
        images = {"gt": self.gt[view], "pred": pred[view], "score": shown["score"], "depth": shown["depth"]}
        return metrics, images, view_sums


def candidate_score_map(
    positions: Float[np.ndarray, "m 3"], scores: Float[np.ndarray, " m"], box: Float[np.ndarray, "2 3"], size: int
) -> Float[np.ndarray, "size size"]:
    """A whole-view method's scores seen from above: each candidate's score at its camera centre over the camera
    box's x-y extent (+x right, +y up), a disc ``size / 40`` pixels across, the higher score on top where discs
    overlap; NaN where no candidate is (what the grid's score column shows for a method with no per-pixel map)."""
    image = np.full((size, size), np.nan)
    span = np.maximum(box[1, :2] - box[0, :2], 1e-12)
    cols = np.round((positions[:, 0] - box[0, 0]) / span[0] * (size - 1)).astype(int)
    rows = np.round((box[1, 1] - positions[:, 1]) / span[1] * (size - 1)).astype(int)
    radius = max(1, size // 40)
    dy, dx = np.mgrid[-radius : radius + 1, -radius : radius + 1]
    inside = dy**2 + dx**2 <= radius**2
    for i in np.argsort(scores, kind="stable"):
        r, c = rows[i] + dy[inside], cols[i] + dx[inside]
        keep = (r >= 0) & (r < size) & (c >= 0) & (c < size)
        image[r[keep], c[keep]] = scores[i]
    return image
