"""``python -m pipeline.bench plan [--out PATH] [--repeats N] [--blocks K] [--precisions fp32,bf16] [--probes LIST]
[overrides]``: view-scoring throughput of every scorer against a plain render (default ``budget=cpu
scene=default``), the scoring seconds of one planning step per method, the training precisions side by
side, and FisherRF's probe count against its cost (``pipeline.bench._probes``).

One full NVF model per ``train.precision`` in ``--precisions``, trained in lockstep on the scene's initial
views from the same weights and seed; on the reference model, 512 candidate poses (``planner.num_candidates``
overrides it) scored by each declared method's scorer and rendered plainly (colour and depth) in the same
chunks, the candidates split into ``K`` blocks that every job runs in turn so that drifts of the machine's
load cancel in the per-block ratios. A method that prepares on the step's model (FisherRF) is timed with its
preparation. The models run on the run's device (``device``, CUDA where present). Writes
``results/bench/plan.json`` (or ``--out``) and prints a table; results/bench/README.md ("plan.json") defines
every field of the report.
"""

import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
from jaxtyping import Float
from torch import Tensor
from tqdm import tqdm

from nvf.cameras import Intrinsics, camera_directions, pose_to_matrix, rays_from_camera_dirs
from nvf.config import STAGES
from nvf.device import resolve_device, synchronize
from nvf.field import INFERENCE_BLOCK, VIS_POSITION_WIDTH
from nvf.methods import FisherRF, Method
from nvf.model import SceneModel
from nvf.observations import Observations
from nvf.planning import score_poses
from nvf.precision import precision_dtype
from nvf.seeding import generator_factory
from nvf.uncertainty import StepScorer, ViewScorer, WholeViewScorer
from pipeline.bench._models import (
    RGB,
    CountingModel,
    held_out_poses,
    parse_precisions,
    report_settings,
    train_side_by_side,
    view_psnr,
)
from pipeline.bench._paired import IterationClock, ratio_spread
from pipeline.bench._probes import parse_probes, probes_study
from pipeline.bench._report import report_path, write_report
from pipeline.bench.field_throughput import matmul_gflops, mlp_flops
from pipeline.cli import ArgumentParser, bounded, description, fail
from pipeline.config.catalog import method_configs
from pipeline.config.method import build_method
from pipeline.config.validation import compose_run, run_settings_of
from pipeline.diagnostics.initial_view_model import InitialViewModel
from pipeline.episode.settings import EpisodeSettings

CANDIDATES = 512  # the paper's N; a later planner.num_candidates=... override wins
WARMUP_CANDIDATES = 8
MAX_REPEATS = 100
GOAL_NVF_OVER_PLAIN = 1.3


@torch.no_grad()
def plain_render(model: SceneModel, poses: Float[Tensor, "m 7"], intr: Intrinsics, chunk_rays: int) -> None:
    """Colour + depth render of every pose's image: ``score_poses``' rays and chunks, without a scorer."""
    cam_dirs = camera_directions(intr, poses.device)
    for c2w in pose_to_matrix(poses):
        origins, dirs = rays_from_camera_dirs(c2w, cam_dirs)
        for start in range(0, cam_dirs.shape[0], chunk_rays):
            model.render(origins[start : start + chunk_rays], dirs[start : start + chunk_rays], heads=RGB)


def time_in_blocks(
    jobs: dict[tuple[str, str], Callable[[Tensor], object]],
    poses: Float[Tensor, "m 7"],
    model: CountingModel,
    blocks: int,
    repeats: int,
) -> tuple[dict[tuple[str, str], list[float]], dict[tuple[str, str], list[float]], dict[tuple[str, str], int]]:
    """After one warm-up on a few candidates, every job on each of ``blocks`` candidate blocks before the next
    block (job order rotated per block), ``repeats`` passes: per job the wall and CPU seconds per block and
    the kept samples."""
    for job in jobs.values():
        job(poses[:WARMUP_CANDIDATES])
    wall: dict[tuple[str, str], list[float]] = {key: [] for key in jobs}
    cpu: dict[tuple[str, str], list[float]] = {key: [] for key in jobs}
    kept = dict.fromkeys(jobs, 0)
    keys = list(jobs)
    split = [b for b in torch.arange(poses.shape[0]).tensor_split(blocks) if b.numel() > 0] * repeats
    for i, block in enumerate(tqdm(split, desc="blocks", leave=False, disable=not sys.stderr.isatty())):
        for key in keys[i % len(keys) :] + keys[: i % len(keys)]:
            before = model.samples
            w, c = timed(lambda: jobs[key](poses[block]))  # noqa: B023 - called at once
            kept[key] += model.samples - before
            wall[key].append(w)
            cpu[key].append(c)
    return wall, cpu, kept


def precision_comparison(
    setups: dict[str, InitialViewModel],
    clocks: dict[str, IterationClock],
    wall: dict[tuple[str, str], list[float]],
    work: list[str],
    candidates: int,
    windows: int,
) -> tuple[dict[str, dict], dict[str, dict]]:
    """Per precision (the first is the reference): its model's training seconds (all, by stage), its
    candidates/s with the reference model's MLPs in it, and its model's held-out PSNR; per other precision,
    the paired speed-ups over the reference (training by iteration window, scoring by block) and the PSNR
    difference."""
    names = list(setups)
    base, reference = names[0], setups[names[0]]
    held_out = held_out_poses(reference.scene)
    size = int(reference.cfg.budget.image_size)
    per: dict[str, dict[str, Any]] = {
        name: {
            "train_seconds": setup.train_seconds,
            "train_seconds_by_stage": clocks[name].stage_seconds(),
            "candidates_per_s": {job: candidates / sum(wall[(job, name)]) for job in work},
            "heldout_psnr": view_psnr(setup.model, reference.renderer, held_out, Intrinsics.from_fov(size, size), 1)[0],
        }
        for name, setup in setups.items()
    }
    spans = clocks[base].windows(1, windows)
    ratios = {
        f"{name}_over_{base}": {
            "train_speedup": ratio_spread(
                [clocks[base].rates(a, b)["train_ms_per_iter"] for a, b in spans],
                [clocks[name].rates(a, b)["train_ms_per_iter"] for a, b in spans],
            ),
            "scoring_speedup": {job: ratio_spread(wall[(job, base)], wall[(job, name)]) for job in work},
            "heldout_psnr_diff": per[name]["heldout_psnr"] - per[base]["heldout_psnr"],
        }
        for name in names[1:]
    }
    return per, ratios


def timed(fn: Callable[[], object]) -> tuple[float, float]:
    """Wall and process-CPU-per-thread seconds of one call."""
    start, start_cpu = time.perf_counter(), time.process_time()
    fn()
    synchronize()
    return time.perf_counter() - start, (time.process_time() - start_cpu) / torch.get_num_threads()


def parse_args(argv: list[str]):
    parser = ArgumentParser(prog="python -m pipeline.bench plan", description=description(__doc__))
    parser.add_argument("overrides", nargs="*", help="Hydra overrides, e.g. budget=smoke")
    parser.add_argument(
        "--out", type=Path, default=None, help="JSON report path (default: ${paths.results}/bench/plan.json)"
    )
    parser.add_argument("--repeats", type=int, default=1, help="timed passes over all candidates")
    parser.add_argument("--blocks", type=int, default=8, help="candidate blocks per pass (ratio = median over blocks)")
    parser.add_argument(
        "--precisions",
        help="train.precision values compared, first the reference (default: fp32,bf16 "
        "where the CPU has bfloat16, else fp32)",
    )
    parser.add_argument("--probes", help="FisherRF probe counts K to compare, e.g. 1,2,4,8,16 (default: none)")
    args = parser.parse_intermixed_args(argv)
    bounded("--repeats", args.repeats, 1, MAX_REPEATS)
    bounded("--blocks", args.blocks, 1, CANDIDATES, "the default candidates; a block holds at least one")
    args.probes = None if args.probes is None else parse_probes(args.probes)
    return args


def scoring_rates(
    wall: dict[str, list[float]], cpu: dict[str, list[float]], work: list[str], methods: list[str], candidates: int
) -> dict:
    """Candidates per second of each job, and each method's scoring time over the plain render's (the median
    over blocks of the paired ratios)."""
    report: dict = {}
    for name in work:
        report[f"candidates_per_s_{name}"] = candidates / sum(wall[name])
        report[f"candidates_per_s_{name}_cpu"] = candidates / sum(cpu[name])
    for method in methods:
        report[f"{method}_over_plain_render"] = statistics.median(
            w / p for w, p in zip(wall[method], wall["plain_render"], strict=True)
        )
        report[f"{method}_over_plain_render_cpu"] = statistics.median(
            c / p for c, p in zip(cpu[method], cpu["plain_render"], strict=True)
        )
    return report


def print_report(
    report: dict, work: list[str], precisions: list[str], per: dict, ratios: dict, train_seconds: float, res: int
) -> None:
    base, m, ratio = precisions[0], report["settings"]["candidates"], report["nvf_over_plain_render"]
    print(f"{'':14}{'cand/s':>10}{'(cpu)':>10}{'x plain':>9}{'s/step':>9}")
    for name in work:
        x = 1.0 if name == "plain_render" else report[f"{name}_over_plain_render"]
        rate, rate_cpu = report[f"candidates_per_s_{name}"], report[f"candidates_per_s_{name}_cpu"]
        print(f"{name:14}{rate:>10.1f}{rate_cpu:>10.1f}{x:>9.2f}{report['seconds_per_step'][name]:>9.2f}")
    fraction = report["nvf_extra_fraction_of_limit"]
    print(
        f"NVF / plain render = {ratio:.2f} (goal <= {GOAL_NVF_OVER_PLAIN}: "
        f"{'met' if report['goal_met'] else 'not met'}; MLP FLOPs {report['nvf_over_plain_mlp_flops']:.1f}x; "
        f"{report['nvf_over_plain_render_at_limit']:.2f} with the extra heads at "
        f"{report['matmul_gflops']:.0f} GFLOP/s, they run at "
        f"{'an unmeasurable fraction' if fraction is None else f'{fraction:.0%}'} of it); "
        f"{m} candidates at {res}x{res}; training {train_seconds:.0f} s; {report['seconds']:.0f} s"
    )
    for name in precisions[1:]:
        ratio = ratios[f"{name}_over_{base}"]

        def spread(x: dict) -> str:
            return f"{x['median']:.2f} [{x['min']:.2f}-{x['max']:.2f}]"

        print(
            f"{name} over {base} (speed-ups, median [min-max], paired): training {spread(ratio['train_speedup'])} "
            f"({per[base]['train_seconds']:.0f} s vs {per[name]['train_seconds']:.0f} s, all stages), held-out PSNR "
            f"{ratio['heldout_psnr_diff']:+.2f} dB; scoring with the MLPs in {name}: "
            + ", ".join(f"{job} {spread(x)}" for job, x in ratio["scoring_speedup"].items())
        )
    study = report["fisherrf_probes"]
    if study is not None:
        print(
            f"FisherRF by probes K ({m} candidates, {report['settings']['training_views']} training views; "
            f"reference: K = {study['reference_probes']} drawn independently):"
        )
        for row in study["rows"]:
            rho = row["spearman_to_reference"]
            print(
                f"  K = {row['probes']:>3}: {row['seconds_per_step']:7.2f} s per step "
                f"(H_D {row['prepare_seconds_per_view']:.2f} s per training view), Spearman "
                f"{'n/a' if rho is None else f'{rho:.3f}'}, same choice {row['same_choice_as_reference']} "
                f"(its choice scores {row['choice_over_best_in_reference']:.4f} of the reference's best)"
            )


def scoring_jobs(
    model: SceneModel,
    s: EpisodeSettings,
    obs: Observations,
    methods: dict[str, Method],
    intr: Intrinsics,
    precisions: list[str],
) -> tuple[dict[str, ViewScorer | WholeViewScorer], dict[str, Callable[[Tensor], object]], dict, dict[str, float]]:
    """Every declared method's scorer (a ``StepScorer`` prepared on ``obs``, timed: the seconds per method), the
    work timed (a plain render, each scorer) and one job per work and precision (the model's MLPs inferring in
    that precision)."""
    chunk = int(s.planner.score_chunk_rays)
    scorers: dict[str, ViewScorer | WholeViewScorer] = {}
    prepare_seconds: dict[str, float] = {}
    for name, method in methods.items():
        scorer = method.scorer()
        if isinstance(scorer, StepScorer):
            began = time.perf_counter()
            scorers[name] = scorer.prepare(model, obs, generator_factory(s.seed, 0, model.aabb.device), chunk)
            prepare_seconds[name] = time.perf_counter() - began
        elif scorer is not None:
            scorers[name] = scorer

    def scoring(scorer: ViewScorer | WholeViewScorer) -> Callable[[Tensor], object]:
        return lambda p: score_poses(model, scorer, p, intr, chunk)

    work: dict[str, Callable[[Tensor], object]] = {"plain_render": lambda p: plain_render(model, p, intr, chunk)}
    work |= {name: scoring(scorer) for name, scorer in scorers.items()}

    def in_precision(fn: Callable[[Tensor], object], name: str) -> Callable[[Tensor], object]:
        def run(p: Tensor) -> object:
            with model.field.mlp_precision(torch.float32, infer=precision_dtype(name)):
                return fn(p)

        return run

    jobs = {(name, precision): in_precision(fn, precision) for precision in precisions for name, fn in work.items()}
    return scorers, work, jobs, prepare_seconds


def main(argv: list[str]) -> None:
    args = parse_args(argv)
    start = time.perf_counter()
    cfg = compose_run([f"planner.num_candidates={CANDIDATES}", *args.overrides])
    args.out = report_path(args.out, cfg.paths.results, "plan")  # checked before any work
    precisions = parse_precisions(args.precisions, resolve_device(str(cfg.device)))
    methods = {name: build_method(m, run_settings_of(cfg)) for name, m in method_configs().items()}
    fisher = next((method for method in methods.values() if isinstance(method, FisherRF)), None)
    if args.probes is not None and fisher is None:
        fail("--probes: no method in conf/method is FisherRF (nvf.methods.FisherRF); declare it or drop --probes")
    setups, clocks = train_side_by_side(cfg, precisions)
    base = precisions[0]
    setup = setups[base]  # scoring: the reference precision's model with its MLPs in each precision
    s, obs, model = setup.settings, setup.obs, setup.model
    assert isinstance(model, CountingModel), "models trained side by side count their samples"
    size = int(cfg.budget.image_size)
    planner = s.planner
    poses = setup.candidates(0)
    res = int(planner.resolution)
    intr = Intrinsics.from_fov(res, res)
    chunk = int(planner.score_chunk_rays)
    scorers, work, jobs, prepare_seconds = scoring_jobs(model, s, obs, methods, intr, precisions)
    timings = time_in_blocks(jobs, poses, model, args.blocks, args.repeats)
    candidates = poses.shape[0] * args.repeats
    per, ratios = precision_comparison(setups, clocks, timings[0], list(work), candidates, args.blocks)
    wall_by_job, cpu_by_job, kept_by_job = timings
    wall = {job: wall_by_job[(job, base)] for job in work}  # the reference's
    cpu = {job: cpu_by_job[(job, base)] for job in work}
    kept = {job: kept_by_job[(job, base)] for job in work}

    m = poses.shape[0]
    report: dict = scoring_rates(wall, cpu, list(work), list(scorers), m * args.repeats)
    ratio = report["nvf_over_plain_render"]
    nvf_scorer = scorers["nvf"]
    assert isinstance(nvf_scorer, ViewScorer), "NVF scores pixels"
    nvf_flops, plain_flops = mlp_flops(model.field, nvf_scorer.heads, False), mlp_flops(model.field, RGB, False)
    extra_flops = nvf_flops - plain_flops
    report["matmul_gflops"], _ = matmul_gflops(INFERENCE_BLOCK, VIS_POSITION_WIDTH, 3)
    plain_seconds = sum(wall["plain_render"])
    extra_seconds_at_limit = extra_flops * kept["nvf"] / (report["matmul_gflops"] * 1e9)
    report["nvf_over_plain_render_at_limit"] = 1.0 + extra_seconds_at_limit / plain_seconds
    extra_seconds = sum(wall["nvf"]) - plain_seconds
    report["nvf_extra_fraction_of_limit"] = extra_seconds_at_limit / extra_seconds if extra_seconds > 0 else None
    if args.probes is not None and fisher is not None:
        report["fisherrf_probes"] = probes_study(setup, poses, intr, chunk, args.probes, fisher.prior_precision)
    else:
        report["fisherrf_probes"] = None
    per_pixel = {method: scorer for method, scorer in scorers.items() if isinstance(scorer, ViewScorer)}
    report.update(
        {
            "prepare_seconds": prepare_seconds,
            "prepare_seconds_per_view": {method: t / obs.num_images for method, t in prepare_seconds.items()},
            "seconds_per_step": {
                name: prepare_seconds.get(name, 0.0) + sum(wall[name]) / args.repeats for name in work
            },
            "goal_nvf_over_plain_render": GOAL_NVF_OVER_PLAIN,
            "goal_met": ratio <= GOAL_NVF_OVER_PLAIN,
            "goal_within_limit": report["nvf_over_plain_render_at_limit"] <= GOAL_NVF_OVER_PLAIN,
            "nvf_over_plain_mlp_flops": nvf_flops / plain_flops,
            "seconds_per_block": {name: wall[name] for name in work},
            "precision": base,
            "precisions": per,
            "ratios": ratios,
            "settings": {
                **report_settings(cfg, s, obs.num_images, size, precisions, args.overrides),
                "train_iters": {stage: getattr(s.train, stage).iters for stage in STAGES},
                "train_seconds": setup.train_seconds,
                "candidates": m,
                "candidates_requested": planner.num_candidates,
                "resolution": res,
                "chunk_rays": chunk,
                "tau": s.tau,
                "collision_free": s.collision_free,
                "heads": {method: sorted(scorer.heads) for method, scorer in per_pixel.items()},
                "samplers": {method: scorer.sampler for method, scorer in per_pixel.items()},
                "plain_render_samples_per_ray": kept["plain_render"] / (args.repeats * m * intr.num_pixels),
                "repeats": args.repeats,
                "blocks": args.blocks,
            },
            "seconds": time.perf_counter() - start,
        }
    )
    write_report(report, args.out)
    print_report(report, list(work), precisions, per, ratios, setup.train_seconds, res)
    print(f"wrote {args.out}")
