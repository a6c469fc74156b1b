"""``python -m pipeline.bench speedups [--scene default] [--views 10] [--repeats 3] [--cache DIR] [--out PATH]
[overrides]``: each faithful speed-up of a paper-size state against the code it replaced, paired in one run
(the same process, inputs and thread: one), on a trained paper-size state (``pipeline.bench._state``).

- ``labels``: one stage-3 iteration's labels (M17-M18: 65,536 points against every training camera). ``before``:
  every bin of every segment placed and tested against the AABB, the hash grid read without prefetch; then, each
  step on top of the last, ``support`` (only the bins inside the model's density support, the occupied cells'
  box), ``kernel`` (the samples in occupied cells found by the C++ kernel before the density is asked),
  ``prefetch`` (the hash grid's rows prefetched, ``nvf.encoding.PREFETCH_AHEAD``): the exact labels today; and
  ``cutoff`` (M17's early stop, ``train.label_cutoff=LABEL_CUTOFF``, what ``budget=paper`` sets): not bitwise, so
  its report adds ``tolerance``: the mean and largest absolute difference to ``prefetch``'s labels on the same
  samples, the share of labels off by more than 0.05, and ``within``: whether the mean stays within
  ``MEAN_TOLERANCE`` and the largest within ``MAX_TOLERANCE`` (what a budget needs to switch it on); and
  ``lattice`` (with the cutoff, the density read from ``train.label_lattice=LABEL_LATTICE``'s lattice, built
  once before the repeats as stage 3 builds it once for its iterations; its ``build_seconds`` and ``vertices``
  beside): its ``tolerance`` the same way.
- ``encoding``: the hash grid's forward and backward on one training batch's marched samples, prefetch off and on.
- ``backbone``: ``--backbone-iters`` stage-1 iterations continued from the trained state, prefetch off and on.
- ``scoring``: NVF's and w/o Vis.'s scores of ``--candidates`` candidates at 300 px, each with its own render
  against one render serving both (``score_poses_together``).
- ``fisherrf``: FisherRF's probe diagonal (M31) of one candidate at 300 px, each chunk's gradients copied into a
  flat vector before they were added against added in place.
- ``stage_one``: NVF's and ActiveNeRF's stage 1 (``--stage-iters`` iterations) trained apart against once, NVF's
  continued from ActiveNeRF's backbone (``pipeline.episode.shared_training``).

``--only NAME ..`` runs the named pairs alone. Each pair runs ``--repeats`` times, the two alternating; a ratio
is the replaced code's seconds over today's (above 1: faster), given as median, min and max over the repeats,
with ``equal``: whether both gave bitwise the same result (the equivalence the tests check). Writes
``${paths.results}/bench/speedups.json`` (or ``--out``).
"""

import copy
import dataclasses
import os
import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

from nvf.cameras import pixel_rays, pose_to_matrix
from nvf.density_lattice import DensityLattice
from nvf.device import resolve_device, synchronize
from nvf.model import SceneModel
from nvf.planning import score_poses, score_poses_together
from nvf.seeding import seeded_generator
from nvf.uncertainty import ViewScorer
from nvf.uncertainty.fisher import _flat, colour_parameters, probe_fisher_diagonal, rademacher
from nvf.visibility import visibility_labels
from pipeline.bench._paired import ratio_spread
from pipeline.bench._replaced_labels import every_sample_labels
from pipeline.bench._report import report_path, write_report
from pipeline.bench._state import (
    add_state_arguments,
    check_state_arguments,
    continued_backbone,
    recorded_episode,
    state_candidates,
    trained_backbone,
)
from pipeline.cli import ArgumentParser, description, fail
from pipeline.config.validation import compose_run
from pipeline.diagnostics.initial_view_model import load
from pipeline.episode.loop import Episode
from pipeline.episode.settings import EpisodeSettings
from pipeline.episode.shared_training import train_models

MAX_REPEATS = 20
PAIRS = (
    "labels",
    "encoding",
    "backbone",
    "scoring",
    "fisherrf",
    "stage_one",
)
LABEL_CUTOFF = 1e-3  # budget=paper's train.label_cutoff
MEAN_TOLERANCE = 0.005  # a non-bitwise labels change must keep the mean absolute difference to the exact labels..
MAX_TOLERANCE = 0.05  # ..and every label's, to be switched on in a budget
LABEL_LATTICE = 4  # train.label_lattice measured: a 128³ grid's lattice at the paper's finest hash level, 512


def parse_args(argv: list[str]):
    parser = ArgumentParser(prog="python -m pipeline.bench speedups", description=description(__doc__))
    parser.add_argument("overrides", nargs="*", help="Hydra overrides on top of budget=paper")
    add_state_arguments(parser)
    parser.add_argument("--repeats", type=int, default=3, help=f"paired repeats of each comparison (1..{MAX_REPEATS})")
    parser.add_argument("--backbone-iters", type=int, default=16, help="stage-1 iterations per backbone repeat")
    parser.add_argument("--stage-iters", type=int, default=64, help="stage-1 iterations of the stage_one pair")
    parser.add_argument("--candidates", type=int, default=2, help="candidates per scoring repeat")
    parser.add_argument(
        "--out", type=Path, default=None, help="JSON report (default ${paths.results}/bench/speedups.json)"
    )
    parser.add_argument("--only", nargs="+", default=None, help=f"pairs to run (default all: {', '.join(PAIRS)})")
    args = parser.parse_intermixed_args(argv)
    unknown = [name for name in args.only or [] if name not in PAIRS]
    if unknown:
        fail(f"--only {' '.join(unknown)}: name pairs of {', '.join(PAIRS)}")
    for name, value, top in (
        ("--repeats", args.repeats, MAX_REPEATS),
        ("--backbone-iters", args.backbone_iters, 5000),
        ("--stage-iters", args.stage_iters, 5000),
        ("--candidates", args.candidates, 512),
    ):
        if not 1 <= value <= top:
            fail(f"{name} {value}: must be 1..{top}")
    check_state_arguments(args)
    return args


def timed(work: Callable[[], Any]) -> tuple[Any, float]:
    synchronize()
    start = time.perf_counter()
    result = work()
    synchronize()
    return result, time.perf_counter() - start


def same(a: Any, b: Any) -> bool:
    """Bitwise equality of two results (tensors, or lists, tuples and dicts of them)."""
    if isinstance(a, torch.Tensor):
        return isinstance(b, torch.Tensor) and a.shape == b.shape and torch.equal(a, b)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    return a == b


def paired(variants: dict[str, Callable[[], Any]], repeats: int) -> dict:
    """Every variant ``repeats`` times, alternating; each variant's median seconds, and against the first
    (the replaced code) each later one's ratio spread and whether its result is bitwise the first's."""
    seconds: dict[str, list[float]] = {name: [] for name in variants}
    results: dict[str, Any] = {}
    for _ in range(repeats):
        for name, work in variants.items():
            results[name], took = timed(work)
            seconds[name].append(took)
    names = list(variants)
    out: dict[str, Any] = {"seconds": {name: sorted(values)[len(values) // 2] for name, values in seconds.items()}}
    for name in names[1:]:
        out[name] = {
            "ratio": ratio_spread(seconds[names[0]], seconds[name]),
            "equal": same(results[names[0]], results[name]),
        }
    return out


def with_prefetch(model: SceneModel, ahead: int, work: Callable[[], Any]) -> Callable[[], Any]:
    def run() -> Any:
        own = model.field.encoding.prefetch_ahead
        model.field.encoding.prefetch_ahead = ahead
        try:
            return work()
        finally:
            model.field.encoding.prefetch_ahead = own

    return run


def labels_pairs(model: SceneModel, episode: Episode, repeats: int) -> dict:
    s, obs, device = episode.settings, episode.observations(), episode.device
    aabb, support = model.aabb, model.density_support()
    u = torch.rand(s.train.visibility.batch, 3, generator=torch.Generator().manual_seed(0)).to(aabb)
    points = aabb[0] + u * (aabb[1] - aabb[0])

    exact = dataclasses.replace(s.train, label_cutoff=0.0)

    def labels(box: torch.Tensor, clip: bool, grid, cutoff: float = 0.0, density=model.density) -> Callable:
        """The labels with today's code (``clip``: the bins placed inside the box only), or the code it replaced."""
        train = dataclasses.replace(exact, label_cutoff=cutoff)

        def run() -> torch.Tensor:
            generator = seeded_generator(s.seed, 0, "bench_labels", device)
            if clip:
                return visibility_labels(density, points, obs.c2w, obs.intrinsics, train, generator, box, grid=grid)
            return every_sample_labels(density, points, obs.c2w, obs.intrinsics, train, generator, box)

        return run

    start = time.perf_counter()
    lattice = model.label_density(LABEL_LATTICE)
    build = time.perf_counter() - start

    variants = {
        "before": with_prefetch(model, 0, labels(aabb, False, None)),
        "support": with_prefetch(model, 0, labels(support.box, True, None)),
        "kernel": with_prefetch(model, 0, labels(support.box, True, support.grid)),
        "prefetch": labels(support.box, True, support.grid),
        "cutoff": labels(support.box, True, support.grid, LABEL_CUTOFF),
        "lattice": labels(support.box, True, support.grid, LABEL_CUTOFF, lattice),
    }
    report = paired(variants, repeats)
    exact_labels = variants["prefetch"]()
    for name in ("cutoff", "lattice"):
        found = variants[name]()
        diff = (found - exact_labels).abs()
        mean_abs, max_abs = float(diff.mean()), float(diff.max())
        report[name]["tolerance"] = {
            "cutoff": LABEL_CUTOFF,
            "mean_abs": mean_abs,
            "max_abs": max_abs,
            "share_above_0.05": float((diff > MAX_TOLERANCE).float().mean()),
            "positives_exact": float((exact_labels > 0.5).float().mean()),
            f"positives_{name}": float((found > 0.5).float().mean()),
            "within": mean_abs <= MEAN_TOLERANCE and max_abs <= MAX_TOLERANCE,
        }
    assert isinstance(lattice, DensityLattice)
    report["lattice"] |= {"subdivisions": LABEL_LATTICE, "build_seconds": build, "vertices": lattice.evaluated}
    return report | {"points": int(points.shape[0]), "cameras": obs.num_images}


def equivalence(found: dict) -> str:
    """One pair's equivalence in words: bitwise, or its tolerance's mean and largest difference, within or not."""
    if found["equal"]:
        return "bitwise"
    tolerance = found["tolerance"]
    verdict = "within tolerance" if tolerance["within"] else "OUTSIDE tolerance"
    return f"{verdict}: mean {tolerance['mean_abs']:.2g}, largest {tolerance['max_abs']:.2g}"


def encoding_pairs(model: SceneModel, episode: Episode, repeats: int) -> dict:
    s, obs, device = episode.settings, episode.observations(), episode.device
    origins, dirs, _, _ = obs.sample_rays(s.train.backbone.batch, seeded_generator(s.seed, 0, "bench_rays", device))
    samples = model.grid.march(origins, dirs, jitter=False)
    u = model.field.normalize(samples.positions(origins, dirs)).clamp(0.0, 1.0).contiguous()
    encoding = model.field.encoding

    def forward_backward() -> tuple[torch.Tensor, torch.Tensor]:
        out = encoding(u)
        (grad,) = torch.autograd.grad(out, [encoding.table], torch.ones_like(out))
        return out.detach(), grad

    report = paired({"before": with_prefetch(model, 0, forward_backward), "prefetch": forward_backward}, repeats)
    return report | {"samples": int(u.shape[0])}


def backbone_pairs(model: SceneModel, episode: Episode, iters: int, repeats: int) -> dict:
    s, obs, device = episode.settings, episode.observations(), episode.device

    def continued(ahead: int) -> Callable[[], dict[str, torch.Tensor]]:
        def run() -> dict[str, torch.Tensor]:
            copied = copy.deepcopy(model)
            copied.field.encoding.prefetch_ahead = ahead
            continued_backbone(copied, obs, s, iters, seeded_generator(s.seed, 0, "bench_backbone", device))
            return copied.state_dict()

        return run

    return paired({"before": continued(0), "prefetch": continued(model.field.encoding.prefetch_ahead)}, repeats) | {
        "iterations": iters
    }


def scoring_pairs(cfg_overrides: list[str], model: SceneModel, episode: Episode, count: int, repeats: int) -> dict:
    s = episode.settings
    poses = state_candidates(episode, model, count)
    blind = EpisodeSettings.of(compose_run([*cfg_overrides, "ablation=wo_vis"]), episode.scene).scorer()
    nvf = s.scorer()
    assert isinstance(nvf, ViewScorer) and isinstance(blind, ViewScorer), "NVF and w/o Vis. score per pixel"
    intr, chunk = episode.plan_intrinsics, s.planner.score_chunk_rays
    report = paired(
        {
            "apart": lambda: [score_poses(model, scorer, poses, intr, chunk) for scorer in (nvf, blind)],
            "together": lambda: score_poses_together(model, [nvf, blind], poses, intr, chunk),
        },
        repeats,
    )
    return report | {"candidates": int(poses.shape[0])}


def flat_probe_diagonal(
    model: SceneModel, params: list, origins: torch.Tensor, dirs: torch.Tensor, signs: torch.Tensor, chunk: int
) -> torch.Tensor:
    """M31 as ``probe_fisher_diagonal`` computed it before: each chunk's gradient of every parameter copied into
    one flat vector (``_flat``) before it was added (the code the in-place accumulation replaced)."""
    probes = signs.shape[0]
    sums = [torch.zeros(sum(p.numel() for p in params), device=origins.device) for _ in range(probes)]
    for start in range(0, origins.shape[0], chunk):
        with torch.enable_grad():
            rgb = model.render(
                origins[start : start + chunk], dirs[start : start + chunk], heads=frozenset({"rgb"})
            ).rgb
        for k in range(probes):
            grads = torch.autograd.grad(
                rgb, params, signs[k, start : start + chunk].to(rgb), retain_graph=k < probes - 1, allow_unused=True
            )
            sums[k] += _flat(grads, params)
    return torch.stack([total.double().square() for total in sums]).mean(0)


def fisher_pairs(model: SceneModel, episode: Episode, repeats: int) -> dict:
    s = episode.settings
    pose = state_candidates(episode, model, 1)[0]
    origins, dirs = pixel_rays(pose_to_matrix(pose), episode.plan_intrinsics)
    params = colour_parameters(model)
    signs = rademacher(2, origins.shape[0], seeded_generator(s.seed, 0, "bench_probes", episode.device))
    chunk = s.planner.score_chunk_rays
    report = paired(
        {
            "flat": lambda: flat_probe_diagonal(model, params, origins, dirs, signs, chunk),
            "in_place": lambda: probe_fisher_diagonal(model, params, origins, dirs, signs, chunk),
        },
        repeats,
    )
    return report | {"rays": int(origins.shape[0]), "parameters": sum(p.numel() for p in params)}


def stage_one_pairs(cfg_overrides: list[str], episode: Episode, iters: int, repeats: int) -> dict:
    cut = [*cfg_overrides, f"train.backbone.iters={iters}", "train.variance.iters=1", "train.visibility.iters=1"]
    episodes = {
        name: episode.as_method(EpisodeSettings.of(compose_run([*cut, *overrides]), episode.scene))
        for name, overrides in (("nvf", []), ("activenerf", ["method=activenerf"]))
    }
    obs = episode.observations()
    step = len(episode.poses) - int(episode.scene.init_poses.shape[0])

    def apart() -> list[dict[str, torch.Tensor]]:
        return [train_models({name: one}, obs, step)[name].model.state_dict() for name, one in episodes.items()]

    def once() -> list[dict[str, torch.Tensor]]:
        trained = train_models(episodes, obs, step)
        return [trained[name].model.state_dict() for name in episodes]

    return paired({"apart": apart, "once": once}, repeats) | {"iterations": iters}


def main(argv: list[str]) -> None:
    args = parse_args(argv)
    torch.set_num_threads(1)  # one thread, as the paper-size states run
    overrides = [f"budget={args.budget}", f"scene={args.scene}", *args.overrides]
    cfg = compose_run(overrides)
    out = report_path(args.out, cfg.paths.results, "speedups")
    cache = args.cache if args.cache is not None else Path(cfg.paths.outputs) / "bench_states"
    scene = load(cfg)
    device = resolve_device(str(cfg.device))
    start = time.perf_counter()
    episode = recorded_episode(cfg, scene, args.views, args.records, device)
    try:
        print(f"speedups: {args.scene} at {args.budget} after {args.views} views, one thread", flush=True)
        model, _ = trained_backbone(episode, cache)
        pairs: dict[str, Callable[[], dict]] = {
            "labels": lambda: labels_pairs(model, episode, args.repeats),
            "encoding": lambda: encoding_pairs(model, episode, args.repeats),
            "backbone": lambda: backbone_pairs(model, episode, args.backbone_iters, args.repeats),
            "scoring": lambda: scoring_pairs(overrides, model, episode, args.candidates, args.repeats),
            "fisherrf": lambda: fisher_pairs(model, episode, args.repeats),
            "stage_one": lambda: stage_one_pairs(overrides, episode, args.stage_iters, args.repeats),
        }
        found = {}
        for name in args.only or PAIRS:
            found[name] = pairs[name]()
            print(f"  {name} {found[name]}", flush=True)
    finally:
        episode.close()
    report = {
        "benchmark": "speedups",
        "command": " ".join(["python -m pipeline.bench speedups", *argv]),
        "budget": args.budget,
        "scene": args.scene,
        "views": args.views,
        "repeats": args.repeats,
        "only": args.only,
        "device": str(device),
        "torch_threads": torch.get_num_threads(),
        "machine": platform.platform(),
        "load_average_1_5_15_min": os.getloadavg(),
        "pairs": found,
        "seconds": time.perf_counter() - start,
    }
    write_report(report, out)
    for name, pair in found.items():
        ratios = ", ".join(
            f"{k} {v['ratio']['median']:.2f}x ({equivalence(v)})"
            for k, v in pair.items()
            if isinstance(v, dict) and "ratio" in v
        )
        print(f"  {name:10} {ratios}")
    print(f"wrote {out}")
