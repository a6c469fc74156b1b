"""``python -m pipeline.bench visibility [--out PATH] [--sets N] [overrides]``: how well the visibility
head tells seen from unseen object pixels of candidate views (METHOD 9, M17-M19), and how much it
changes NVF's ranking of the candidates against w/o Vis. (default ``budget=cpu scene=default``).

Trains one full NVF model (all three stages, at the budget) on the scene's initial views. For each
of ``N`` candidate sets (``nvf.planning.candidate_poses`` drawn as the planner's step ``k`` would,
``planner.num_candidates`` poses, rendered at ``planner.resolution``), per object pixel (the exact
ray cast hits the mesh and the model's accumulation ``A > 0.5``):

- the head's weight-averaged visibility ``sum_i w_i v_i / A``, and the same average of the labels
  (M17-M18 from the training cameras at the same samples: what a perfect head would predict);
- ``seen``: some initial camera has an unoccluded line of sight to the pixel's surface point
  (``GroundTruthRenderer.line_of_sight``, the point moved 0.01 towards the candidate);
- the AUC (Mann-Whitney) of seen against unseen pixels, for the head and for the labels;
- the Spearman correlation of NVF's and w/o Vis.'s view rewards (M16), and whether their argmax agree.

An AUC of 0.5 is no separation. Writes ``results/bench/visibility.json`` (or ``--out``).
"""

import dataclasses
import statistics
import time
from pathlib import Path

import numpy as np
import torch
from jaxtyping import Float
from scipy import stats
from torch import Tensor

from nvf.cameras import Intrinsics, pixel_rays, pose_to_matrix
from nvf.config import TrainConfig
from nvf.model import SceneModel
from nvf.planning import score_poses
from nvf.rendering import ray_sum
from nvf.training import Observations
from nvf.methods import NVF
from nvf.uncertainty import ViewScorer
from nvf.visibility import visibility_labels
from pipeline.cli import ArgumentParser, description
from pipeline.bench._report import report_path, write_report
from pipeline.bench.train import InitialViewModel
from pipeline.config.validation import compose_config

SURFACE_OFFSET = 0.01  # scene units: the surface point moves this far towards the candidate camera
MIN_ACCUMULATION = 0.5  # PROTOCOL 4.2's surface rule


@torch.no_grad()
def weighted_visibility(
    model: SceneModel, obs: Observations, origins: Float[Tensor, "R 3"], dirs: Float[Tensor, "R 3"], cfg: TrainConfig
) -> tuple[Float[Tensor, " R"], Float[Tensor, " R"], Float[Tensor, " R"]]:
    """Per ray: accumulation ``A``, ``sum_i w_i v_i / A`` of the head and ``sum_i w_i V*_i / A`` of
    the labels (M18, deterministic sample offsets)."""
    result = model.render(origins, dirs, heads=frozenset({"visibility"}))
    samples = result.samples
    labels = visibility_labels(model.density, samples.positions(origins, dirs), obs.c2w, obs.intrinsics, cfg)
    acc = result.acc.clamp_min(1e-12)
    head = ray_sum(result.weights * result.visibility, samples.ray_idx, samples.n_rays) / acc
    label = ray_sum(result.weights * labels, samples.ray_idx, samples.n_rays) / acc
    return result.acc, head, label


def auc(positive: np.ndarray, negative: np.ndarray) -> float | None:
    """P(a positive scores above a negative), ties counted half; None if a class is empty."""
    if len(positive) == 0 or len(negative) == 0:
        return None
    return float(stats.mannwhitneyu(positive, negative).statistic / (len(positive) * len(negative)))


def spearman(a: np.ndarray, b: np.ndarray) -> float | None:
    """Spearman's rank correlation; None when undefined (fewer than two values, or a constant one)."""
    if len(a) < 2 or np.ptp(a) == 0 or np.ptp(b) == 0:
        return None
    return float(stats.spearmanr(a, b).statistic)


def _mean(values: np.ndarray) -> float | None:
    return float(values.mean()) if len(values) else None


def candidate_set_report(
    setup: InitialViewModel, poses: Float[Tensor, "m 7"], intr: Intrinsics, scorers: tuple[ViewScorer, ViewScorer]
) -> dict:
    """Seen/unseen separation of the head and the labels over one candidate set, and the view rewards
    of ``scorers`` (NVF, w/o Vis.) compared."""
    model, obs, renderer = setup.model, setup.obs, setup.renderer
    head, label, seen = [], [], []
    for c2w in pose_to_matrix(poses):
        origins, dirs = pixel_rays(c2w, intr)
        acc, head_v, label_v = weighted_visibility(model, obs, origins, dirs, setup.settings.train)
        t_hit, _ = renderer.cast_rays(origins.numpy(), dirs.numpy())
        pixels = torch.from_numpy(np.isfinite(t_hit)) & (acc > MIN_ACCUMULATION)
        t = torch.from_numpy(t_hit)[pixels] - SURFACE_OFFSET
        surface = origins[pixels] + t[:, None] * dirs[pixels]
        seen.append(renderer.line_of_sight(surface, obs.c2w, obs.intrinsics).numpy())
        head.append(head_v[pixels].numpy())
        label.append(label_v[pixels].numpy())
    seen_all, head_all, label_all = (np.concatenate(x) for x in (seen, head, label))
    chunk = int(setup.settings.planner.score_chunk_rays)
    nvf_scores, wo_vis_scores = (score_poses(model, scorer, poses, intr, chunk).numpy() for scorer in scorers)
    return {
        "candidates": int(poses.shape[0]),
        "object_pixels": int(len(seen_all)),
        "seen_fraction": _mean(seen_all.astype(np.float64)),
        "head_seen": _mean(head_all[seen_all]), "head_unseen": _mean(head_all[~seen_all]),
        "head_auc": auc(head_all[seen_all], head_all[~seen_all]),
        "label_seen": _mean(label_all[seen_all]), "label_unseen": _mean(label_all[~seen_all]),
        "label_auc": auc(label_all[seen_all], label_all[~seen_all]),
        "spearman_nvf_wo_vis": spearman(nvf_scores, wo_vis_scores),
        "same_argmax": bool(nvf_scores.argmax() == wo_vis_scores.argmax()),
    }  # fmt: skip


def _show(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def _mean_of(sets: list[dict], key: str) -> float | None:
    values = [r[key] for r in sets if r[key] is not None]
    return statistics.fmean(values) if values else None


def main(argv: list[str]) -> None:
    parser = ArgumentParser(prog="python -m pipeline.bench visibility", description=description(__doc__))
    parser.add_argument("overrides", nargs="*", help="Hydra overrides, e.g. train.visibility.iters=500")
    parser.add_argument("--out", type=Path, default=None, help="JSON report path (default: ${paths.results}/bench/visibility.json)")
    parser.add_argument("--sets", type=int, default=3, help="candidate sets (the planner's draws at steps 0..N-1)")
    args = parser.parse_intermixed_args(argv)
    if args.sets < 1:
        parser.error("--sets must be >= 1")
    start = time.perf_counter()
    cfg = compose_config(["planner.num_candidates=64", *args.overrides])
    setup = InitialViewModel.train(cfg)
    s, seed, size = setup.settings, int(cfg.seed), int(cfg.budget.image_size)
    res = int(s.planner.resolution)
    intr = Intrinsics.from_fov(res, res)
    d0 = float(s.entropy.d0)
    blind = dataclasses.replace(s.entropy, use_visibility=False)
    scorers = (NVF().scorer(s.entropy, s.baseline, d0), NVF().scorer(blind, s.baseline, d0))
    sets = [{"set": k, **candidate_set_report(setup, setup.candidates(k), intr, scorers)} for k in range(args.sets)]
    report = {
        "head_auc_mean": _mean_of(sets, "head_auc"),
        "label_auc_mean": _mean_of(sets, "label_auc"),
        "spearman_nvf_wo_vis_mean": _mean_of(sets, "spearman_nvf_wo_vis"),
        "same_argmax_sets": sum(r["same_argmax"] for r in sets),
        "sets": sets,
        "settings": {
            "budget": cfg.budget.name, "scene": cfg.scene.name, "field_kind": s.field.kind, "seed": seed,
            "training_views": setup.obs.num_images, "image_size": size, "resolution": res,
            "candidates_requested": int(s.planner.num_candidates), "label_samples": s.train.label_samples,
            "head_iters": {stage: getattr(s.train, stage).iters for stage in ("variance", "visibility")},
            "head_lr": {stage: getattr(s.train, stage).lr for stage in ("variance", "visibility")},
            "overrides": args.overrides,
        },
        "seconds": time.perf_counter() - start,
    }  # fmt: skip
    args.out = report_path(args.out, cfg.paths.results, "visibility")
    write_report(report, args.out)
    columns = (("set", 4), ("pixels", 8), ("seen", 7), ("head AUC", 10), ("label AUC", 11),
               ("rho(NVF, w/o Vis.)", 20), ("same argmax", 13))  # fmt: skip
    print("".join(f"{name:>{width}}" for name, width in columns))
    for r in sets:
        cells = (r["set"], r["object_pixels"], _show(r["seen_fraction"], ".2f"), _show(r["head_auc"], ".3f"),
                 _show(r["label_auc"], ".3f"), _show(r["spearman_nvf_wo_vis"], ".3f"), r["same_argmax"])  # fmt: skip
        print("".join(f"{str(cell):>{width}}" for cell, (_, width) in zip(cells, columns, strict=True)))
    print(f"mean head AUC {_show(report['head_auc_mean'], '.3f')}, label AUC {_show(report['label_auc_mean'], '.3f')}; "
          f"{report['seconds']:.0f} s; wrote {args.out}")  # fmt: skip
