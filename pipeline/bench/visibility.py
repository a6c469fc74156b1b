"""``python -m pipeline.bench visibility [--out PATH] [--sets N] [--sources head,labels,mesh] [--record DIR --step K]
[overrides]``:
how well each visibility source tells seen from unseen object pixels of candidate views (METHOD 9,
M17-M19), how much it changes NVF's ranking of the candidates against w/o Vis., and which term of the
reward decides each ranking (default ``budget=cpu scene=default``).

Trains one full NVF model (all three stages, at the budget) on the scene's initial views (with ``--record`` and
``--step K``: and the views a recorded episode selected at steps ``0..K-1``, its state at step ``K``). For each of
``N`` candidate sets (``nvf.planning.candidate_poses`` drawn as the planner's step ``k`` would,
``planner.num_candidates`` poses, rendered at ``planner.resolution``) and each visibility source
(``nvf.visibility_source``: ``head``, the trained head; ``labels``, M17-M18 at the scored samples, what a
perfect head would predict; ``mesh``, the scene mesh's line of sight to the training cameras, an oracle;
``train.label_margin`` applies to the last two):

- per object pixel (the exact ray cast hits the mesh and the model's accumulation ``A > 0.5``): the
  source's weight-averaged visibility ``sum_i w_i v_i / A``, and ``seen``: some initial camera has an
  unoccluded line of sight to the pixel's surface point (the point moved 0.01 towards the candidate); the
  AUC (Mann-Whitney) of seen against unseen pixels (0.5: no separation); the median weight spread of the
  object pixels' samples along the ray (``shell``: the model's surface thickness, scene units);
- the Spearman correlation of NVF's and w/o Vis.'s view rewards (M16), whether their argmax agree, and how
  many candidates tie at each maximum;
- each reward split into its terms (``NVFEntropyScorer.pixel_terms``) and each term's share of the
  reward's variance over the candidates (``pipeline.metrics.ranking.term_attribution``): the decisive term;
  the Spearman correlation of each reward with the candidates' object coverage (fraction of pixels with
  ``A > 0.5``), with their unseen coverage (fraction of pixels that are object pixels no initial camera
  saw) and with their novelty (the unseen share of their object pixels, over the views whose object pixels
  fill 5% of the image or more): a score that rewards seeing the object follows the first, one that rewards
  new surface the second and the third.

Writes ``results/bench/visibility.json`` (or ``--out``) and prints a table per source.
"""

import dataclasses
import math
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from jaxtyping import Float
from torch import Tensor

from nvf.cameras import Intrinsics, pose_to_matrix
from nvf.rendering import ray_sum
from nvf.uncertainty.nvf_entropy import NVFEntropyScorer
from nvf.visibility_source import SOURCES, label_visibility
from pipeline.bench._models import InitialViewModel
from pipeline.bench._report import report_path, write_report
from pipeline.cli import ArgumentParser, bounded, description, fail
from pipeline.config.typed import Run
from pipeline.config.validation import compose_run
from pipeline.metrics.ranking import (
    auc,
    render_for_terms,
    spearman,
    term_attribution,
    term_sum,
    ties_at_max,
    view_terms,
)
from pipeline.tables.load import load_run

MAX_SETS = 64
SURFACE_OFFSET = 0.01  # scene units: the surface point moves this far towards the candidate camera
MIN_ACCUMULATION = 0.5  # PROTOCOL 4.2's surface rule
MIN_OBJECT_FRACTION = 0.05  # novelty is taken on views whose object pixels fill at least this much

SourceFn = Callable[[Float[Tensor, "S 3"]], Float[Tensor, " S"]]


def source_functions(setup: InitialViewModel, sources: list[str]) -> dict[str, SourceFn | None]:
    """Each source's ``v`` at sample positions; None for the head (read from the render)."""
    model, obs, train = setup.model, setup.obs, setup.settings.train
    functions: dict[str, SourceFn | None] = {}
    for source in sources:
        if source == "head":
            functions[source] = None
        elif source == "labels":
            functions[source] = label_visibility(model, obs.c2w, obs.intrinsics, train)
        else:
            functions[source] = lambda points: setup.renderer.line_of_sight(
                points, obs.c2w, obs.intrinsics, train.label_margin
            ).to(points.dtype)
    return functions


def _seen_surface(setup: InitialViewModel, origins: Tensor, dirs: Tensor, pixels: Tensor) -> np.ndarray:
    """Whether some initial camera sees the surface point of each object pixel (exact, from the mesh)."""
    t_hit, _ = setup.renderer.cast_rays(origins.numpy(), dirs.numpy())
    t = torch.from_numpy(t_hit)[pixels] - SURFACE_OFFSET
    surface = origins[pixels] + t[:, None] * dirs[pixels]
    return setup.renderer.line_of_sight(surface, setup.obs.c2w, setup.obs.intrinsics).numpy()


def candidate_view(
    setup: InitialViewModel,
    c2w: Tensor,
    intr: Intrinsics,
    scorers: tuple[NVFEntropyScorer, NVFEntropyScorer],
    functions: dict[str, SourceFn | None],
) -> dict:
    """One candidate view: per source its NVF reward terms and per-object-pixel visibility, w/o Vis.'s
    terms, the object pixels' seen flags, shell thickness and the view's object coverage."""
    nvf, blind = scorers
    result, origins, dirs = render_for_terms(setup.model, c2w, intr, nvf.sampler)
    samples = result.samples
    acc = result.acc
    visibility = result.visibility
    assert visibility is not None, "render_for_terms renders the visibility head"
    with torch.no_grad():
        positions = samples.positions(origins, dirs)
        v = {name: visibility if fn is None else fn(positions) for name, fn in functions.items()}
    t_hit, _ = setup.renderer.cast_rays(origins.numpy(), dirs.numpy())
    pixels = torch.from_numpy(np.isfinite(t_hit)) & (acc > MIN_ACCUMULATION)
    safe = acc.clamp_min(1e-12)
    spread = ray_sum(
        result.weights * (samples.t_mid - result.depth[samples.ray_idx]).square(), samples.ray_idx, samples.n_rays
    )
    seen = _seen_surface(setup, origins, dirs, pixels)
    view = {
        "nvf": {name: view_terms(nvf, result, values) for name, values in v.items()},
        "wo_vis": view_terms(blind, result),
        "pixel_v": {
            name: (ray_sum(result.weights * values, samples.ray_idx, samples.n_rays) / safe)[pixels].numpy()
            for name, values in v.items()
        },
        "seen": seen,
        "shell": (spread / safe).sqrt()[pixels].numpy(),
        "coverage": float((acc > MIN_ACCUMULATION).float().mean()),
    }
    view["unseen_coverage"] = float((~seen).sum()) / acc.shape[0]
    enough = len(seen) >= MIN_OBJECT_FRACTION * acc.shape[0]
    view["novelty"] = float((~seen).mean()) if enough else math.nan
    return view


def _stack(views: list[dict[str, float]]) -> dict[str, np.ndarray]:
    return {name: np.array([view[name] for view in views]) for name in views[0]}


def _novelty_spearman(reward: np.ndarray, novelty: np.ndarray) -> float | None:
    """Spearman of the reward with novelty over the views that see enough object to have one."""
    seen_enough = np.isfinite(novelty)
    return spearman(reward[seen_enough], novelty[seen_enough])


def _mean(values: np.ndarray) -> float | None:
    return float(values.mean()) if len(values) else None


def candidate_set_report(
    setup: InitialViewModel,
    poses: Float[Tensor, "m 7"],
    intr: Intrinsics,
    scorers: tuple[NVFEntropyScorer, NVFEntropyScorer],
    functions: dict[str, SourceFn | None],
) -> dict:
    """Separation, ranking agreement and the decisive terms over one candidate set, per source."""
    views = [candidate_view(setup, c2w, intr, scorers, functions) for c2w in pose_to_matrix(poses)]
    seen = np.concatenate([view["seen"] for view in views])
    coverage = np.array([view["coverage"] for view in views])
    unseen = np.array([view["unseen_coverage"] for view in views])
    novelty = np.array([view["novelty"] for view in views])
    blind = _stack([view["wo_vis"] for view in views])
    blind_reward = term_sum(blind)
    sources: dict[str, dict] = {}
    report = {
        "candidates": int(poses.shape[0]),
        "object_pixels": int(len(seen)),
        "seen_fraction": _mean(seen.astype(np.float64)),
        "shell_median": _mean(np.array([np.median(np.concatenate([view["shell"] for view in views]))])),
        "wo_vis": {
            "ties_at_max": ties_at_max(blind_reward),
            "coverage_spearman": spearman(blind_reward, coverage),
            "unseen_coverage_spearman": spearman(blind_reward, unseen),
            "novelty_spearman": _novelty_spearman(blind_reward, novelty),
            **term_attribution(blind),
        },
        "sources": sources,
    }
    for name in functions:
        v = np.concatenate([view["pixel_v"][name] for view in views])
        terms = _stack([view["nvf"][name] for view in views])
        reward = term_sum(terms)
        sources[name] = {
            "seen_mean": _mean(v[seen]),
            "unseen_mean": _mean(v[~seen]),
            "auc": auc(v[seen], v[~seen]),
            "spearman_nvf_wo_vis": spearman(reward, blind_reward),
            "same_argmax": bool(reward.argmax() == blind_reward.argmax()),
            "ties_at_max": ties_at_max(reward),
            "coverage_spearman": spearman(reward, coverage),
            "unseen_coverage_spearman": spearman(reward, unseen),
            "novelty_spearman": _novelty_spearman(reward, novelty),
            **term_attribution(terms),
        }
    return report


def _mean_of(values: list) -> float | None:
    kept = [v for v in values if v is not None]
    return statistics.fmean(kept) if kept else None


def summarise(sets: list[dict], sources: list[str]) -> dict:
    """Means over the candidate sets, per source."""
    per_source = {}
    for name in sources:
        rows = [s["sources"][name] for s in sets]
        per_source[name] = {
            "auc_mean": _mean_of([r["auc"] for r in rows]),
            "spearman_nvf_wo_vis_mean": _mean_of([r["spearman_nvf_wo_vis"] for r in rows]),
            "same_argmax_sets": sum(r["same_argmax"] for r in rows),
            "decisive_terms": [r["decisive"] for r in rows],
            "unknown_share_mean": _mean_of([r["terms"]["unknown"]["share"] for r in rows]),
            "coverage_spearman_mean": _mean_of([r["coverage_spearman"] for r in rows]),
            "unseen_coverage_spearman_mean": _mean_of([r["unseen_coverage_spearman"] for r in rows]),
            "novelty_spearman_mean": _mean_of([r["novelty_spearman"] for r in rows]),
            "max_ties_at_max": max(r["ties_at_max"] for r in rows),
        }
    blind = [s["wo_vis"] for s in sets]
    return {
        "sources": per_source,
        "wo_vis_decisive_terms": [s["decisive"] for s in blind],
        "wo_vis_coverage_spearman_mean": _mean_of([s["coverage_spearman"] for s in blind]),
        "wo_vis_unseen_coverage_spearman_mean": _mean_of([s["unseen_coverage_spearman"] for s in blind]),
        "wo_vis_novelty_spearman_mean": _mean_of([s["novelty_spearman"] for s in blind]),
        "wo_vis_max_ties_at_max": max(s["wo_vis"]["ties_at_max"] for s in sets),
    }


def recorded_poses(record: Path, step: int) -> Float[Tensor, "k 4 4"]:
    """The poses a recorded episode selected before ``step`` (its state at ``step``, after the initial views)."""
    _, rows = load_run(record)
    if step > len(rows):
        raise ValueError(f"{record} has {len(rows)} steps; --step {step} needs that many")
    return pose_to_matrix(
        torch.tensor([row["selected_pose"] for row in rows[:step]], dtype=torch.float32).reshape(-1, 7)
    )


def visibility_report(cfg: Run, sets: int, sources: list[str], extra: Tensor | None = None) -> dict:
    """Train the model of ``cfg`` on the initial views (and the poses ``extra`` after them) and report
    ``sets`` candidate sets (see the module doc)."""
    setup = InitialViewModel.train(cfg, extra_poses=extra)
    s = setup.settings
    res = int(s.planner.resolution)
    intr = Intrinsics.from_fov(res, res)
    d0 = s.entropy.d0
    assert isinstance(d0, (int, float)), f"nvf.entropy.d0={d0!r} is not resolved"
    blind = dataclasses.replace(s.entropy, use_visibility=False)
    scorers = (NVFEntropyScorer(s.entropy, d0), NVFEntropyScorer(blind, d0))
    functions = source_functions(setup, sources)
    reports = [
        {"set": k, **candidate_set_report(setup, setup.candidates(k), intr, scorers, functions)} for k in range(sets)
    ]
    return {
        **summarise(reports, sources),
        "sets": reports,
        "settings": {
            "budget": cfg.budget.name,
            "scene": cfg.scene.name,
            "field_kind": s.field.kind,
            "seed": int(cfg.seed),
            "training_views": setup.obs.num_images,
            "image_size": int(cfg.budget.image_size),
            "resolution": res,
            "candidates_requested": int(s.planner.num_candidates),
            "label_samples": s.train.label_samples,
            "label_margin": s.train.label_margin,
            "logdet_coeff": s.entropy.logdet_coeff,
            "head_iters": {stage: getattr(s.train, stage).iters for stage in ("variance", "visibility")},
            "head_lr": {stage: getattr(s.train, stage).lr for stage in ("variance", "visibility")},
        },
    }


def _show(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def print_report(report: dict) -> None:
    """A table per source and candidate set (rho: NVF vs w/o Vis.; rho cov / new / nov: NVF vs object coverage,
    unseen coverage and novelty)."""
    columns = (
        ("source", 8),
        ("set", 4),
        ("pixels", 7),
        ("seen", 6),
        ("shell", 7),
        ("AUC", 7),
        ("rho", 7),
        ("same", 6),
        ("ties", 5),
        ("rho cov", 8),
        ("rho new", 8),
        ("rho nov", 8),
        ("decisive NVF", 22),
        ("w/o Vis.", 20),
    )
    print("".join(f"{name:>{width}}" for name, width in columns))
    for name in report["sources"]:
        for r in report["sets"]:
            x, blind = r["sources"][name], r["wo_vis"]
            share = x["terms"][x["decisive"]]["share"] if x["decisive"] else None
            blind_share = blind["terms"][blind["decisive"]]["share"] if blind["decisive"] else None
            cells = (
                name,
                r["set"],
                r["object_pixels"],
                _show(r["seen_fraction"], ".2f"),
                _show(r["shell_median"], ".3f"),
                _show(x["auc"], ".3f"),
                _show(x["spearman_nvf_wo_vis"], ".3f"),
                x["same_argmax"],
                x["ties_at_max"],
                _show(x["coverage_spearman"], ".3f"),
                _show(x["unseen_coverage_spearman"], ".3f"),
                _show(x["novelty_spearman"], ".3f"),
                f"{x['decisive']} ({_show(share, '.2f')})",
                f"{blind['decisive']} ({_show(blind_share, '.2f')})",
            )
            print("".join(f"{str(cell):>{width}}" for cell, (_, width) in zip(cells, columns, strict=True)))
    blind = report["sets"]
    print(
        "w/o Vis. rho cov "
        + ", ".join(_show(r["wo_vis"]["coverage_spearman"], ".3f") for r in blind)
        + "; rho new "
        + ", ".join(_show(r["wo_vis"]["unseen_coverage_spearman"], ".3f") for r in blind)
        + "; rho nov "
        + ", ".join(_show(r["wo_vis"]["novelty_spearman"], ".3f") for r in blind)
    )


def main(argv: list[str]) -> None:
    parser = ArgumentParser(prog="python -m pipeline.bench visibility", description=description(__doc__))
    parser.add_argument("overrides", nargs="*", help="Hydra overrides, e.g. train.label_margin=0.05")
    parser.add_argument(
        "--out", type=Path, default=None, help="JSON report path (default: ${paths.results}/bench/visibility.json)"
    )
    parser.add_argument("--sets", type=int, default=3, help="candidate sets (the planner's draws at steps 0..N-1)")
    parser.add_argument(
        "--sources", default=",".join(SOURCES), help=f"visibility sources, a subset of {','.join(SOURCES)}"
    )
    parser.add_argument("--record", type=Path, default=None, help="a recorded episode whose state at --step to measure")
    parser.add_argument(
        "--step", type=int, default=0, help="with --record: the state before this step (its views so far)"
    )
    args = parser.parse_intermixed_args(argv)
    sources = args.sources.split(",")
    bounded("--sets", args.sets, 1, MAX_SETS)
    if not sources or any(name not in SOURCES for name in sources):
        parser.error(f"--sources={args.sources!r}: use a comma-separated subset of {','.join(SOURCES)}")
    if args.step < 0 or (args.step > 0 and args.record is None):
        parser.error("--step takes a number >= 0 and needs --record")
    start = time.perf_counter()
    cfg = compose_run(["planner.num_candidates=64", *args.overrides])
    args.out = report_path(args.out, cfg.paths.results, "visibility")  # checked before any work
    try:
        extra = recorded_poses(args.record, args.step) if args.record is not None else None
    except (ValueError, OSError) as err:
        fail(str(err))
    report = visibility_report(cfg, args.sets, sources, extra)
    report["settings"]["overrides"] = args.overrides
    report["settings"]["state"] = None if args.record is None else {"record": str(args.record), "step": args.step}
    report["seconds"] = time.perf_counter() - start
    write_report(report, args.out)
    print_report(report)
    print(f"{report['seconds']:.0f} s; wrote {args.out}")
