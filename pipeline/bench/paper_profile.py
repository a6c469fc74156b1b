"""``python -m pipeline.bench paper_profile [--scene default] [--views 10] [--cache DIR] [--out PATH] [overrides]``:
where a paper-size state spends its time, one unit of work per stage, on a trained state, on one thread.

The state is ``budget=paper`` on ``--scene`` after ``--views`` views (the initial ones, then the poses of the
committed NVF cpu episode of seed 100), its backbone trained at the paper's 5000 iterations (kept in ``--cache``,
default ``${paths.outputs}/bench_states``, so a second run skips it). Each unit runs once unprofiled (its
seconds, wall and process CPU) and once under ``torch.profiler`` (its operators' self CPU time, the top
``TOP_OPS``):

- ``backbone``: stage 1, ``BACKBONE_ITERS`` iterations continued as its last ones run, occupancy-grid updates
  included; ``marched_per_ray``: the samples its skipping pass evaluates, beside the ``samples_per_ray`` it keeps;
- ``grid_update``: one M5 update past the warm-up, which stage 1 runs every ``sampler.update_every`` iterations
  (``probes``: the cells it evaluates);
- ``variance``: stage 2, ``VARIANCE_ITERS`` iterations;
- ``visibility``: stage 3, one iteration (labels against every training camera and the head's step; the
  seconds and samples of the labels' field queries apart);
- ``score_<method>``: one candidate at 300 px (NVF, w/o Vis., both in one render, ActiveNeRF's rendered
  variance, FisherRF; FisherRF's preparation, once per state, apart);
- ``evaluation``: one 512-px view (render, PSNR, SSIM, LPIPS); ``mesh_metrics``: one step's 500k points (Acc.,
  Comp., C.R.).

``encoding`` times the hash grid's forward and backward on the same samples at the paper's 2^19 table and the
cpu budget's 2^15. Writes ``${paths.results}/bench/paper_profile.json`` (or ``--out``);
``results/bench/paper_profile.md`` reads it.
"""

import dataclasses
import math
import os
import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
import torch.profiler

from nvf.device import resolve_device, synchronize
from nvf.encoding import HashEncoding
from nvf.planning import prepare_scorer, score_poses_together
from nvf.seeding import generator_factory, seeded_generator
from nvf.training import train_variance_head, train_visibility_head
from pipeline.bench._report import report_path, write_report
from pipeline.bench._state import (
    SCORED,
    add_state_arguments,
    check_state_arguments,
    continued_backbone,
    recorded_episode,
    state_candidates,
    trained_backbone,
)
from pipeline.cli import ArgumentParser, description
from pipeline.config.validation import compose_run
from pipeline.diagnostics.initial_view_model import load
from pipeline.episode.evaluation import render_view
from pipeline.episode.loop import Episode
from pipeline.episode.settings import EpisodeSettings
from pipeline.metrics.image import image_metrics

TOP_OPS = 12
BACKBONE_ITERS = 32  # two occupancy-grid update periods
VARIANCE_ITERS = 5


def parse_args(argv: list[str]):
    parser = ArgumentParser(prog="python -m pipeline.bench paper_profile", description=description(__doc__))
    parser.add_argument("overrides", nargs="*", help="Hydra overrides on top of budget=paper")
    add_state_arguments(parser)
    parser.add_argument(
        "--out", type=Path, default=None, help="JSON report (default ${paths.results}/bench/paper_profile.json)"
    )
    args = parser.parse_intermixed_args(argv)
    check_state_arguments(args)
    return args


def measured(work: Callable[[], Any], device: torch.device) -> tuple[Any, dict]:
    """Run ``work`` twice: timed (wall and process CPU seconds), then under ``torch.profiler`` (the top operators
    by self CPU time); returns the first run's result and the measurements."""
    synchronize()
    start, start_cpu = time.perf_counter(), time.process_time()
    result = work()
    synchronize()
    seconds, cpu = time.perf_counter() - start, (time.process_time() - start_cpu) / torch.get_num_threads()
    with torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU]) as prof:
        work()
    events = sorted(prof.key_averages(), key=lambda e: -e.self_cpu_time_total)
    total = sum(e.self_cpu_time_total for e in events) or 1.0
    ops = [
        {
            "op": e.key,
            "self_seconds": e.self_cpu_time_total / 1e6,
            "share": e.self_cpu_time_total / total,
            "calls": e.count,
        }
        for e in events[:TOP_OPS]
    ]
    return result, {"seconds": seconds, "process_seconds": cpu, "profiled_seconds": total / 1e6, "top_ops": ops}


class MarchCounter:
    """Counts the samples the model's occupancy grid marches (before alpha skipping) until ``restore``."""

    def __init__(self, model) -> None:
        self.grid, self.own, self.samples = model.grid, model.grid.march, 0

        def march(*args, **kwargs):
            found = self.own(*args, **kwargs)
            self.samples += found.num_samples
            return found

        self.grid.march = march

    def restore(self) -> None:
        self.grid.march = self.own


class TimedDensity:
    """A density function that counts its samples and its seconds."""

    def __init__(self, density: Callable[[torch.Tensor], torch.Tensor], device: torch.device):
        self.density, self.device = density, device
        self.samples, self.seconds = 0, 0.0

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        start = time.perf_counter()
        out = self.density(x)
        synchronize()
        self.samples += int(x.shape[0])
        self.seconds += time.perf_counter() - start
        return out


def encoding_rates(device: torch.device, samples: int = 1 << 20) -> dict:
    """Forward and backward of the hash grid on the same ray-coherent samples at 2^19 and 2^15 rows (M samples/s)."""
    generator = torch.Generator().manual_seed(0)
    start, end = (
        torch.rand(samples // 64, 1, 3, generator=generator),
        torch.rand(samples // 64, 1, 3, generator=generator),
    )
    u = (start + torch.linspace(0, 1, 64)[None, :, None] * (end - start)).reshape(-1, 3).to(device)
    rates = {}
    for log2, top in ((19, 512), (15, 256)):
        enc = HashEncoding(16, 2, log2, 16, top).to(device)
        out = enc(u)
        grad = torch.ones_like(out)
        synchronize()
        begin = time.perf_counter()
        with torch.no_grad():
            enc(u)
        synchronize()
        forward = time.perf_counter() - begin
        begin = time.perf_counter()
        out = enc(u)
        out.backward(grad)
        synchronize()
        backward = time.perf_counter() - begin - forward
        rates[f"2^{log2}"] = {
            "forward_msamples_per_s": samples / forward / 1e6,
            "backward_msamples_per_s": samples / max(backward, 1e-9) / 1e6,
            "rows": enc.table.shape[0],
        }
    return rates


def profile_state(cfg_overrides: list[str], episode: Episode, cache: Path | None) -> dict:
    """The units of the module docstring on ``episode``'s state (``cfg_overrides``: the configuration it was made
    with, to which each scored method's overrides are added)."""
    s, device, obs = episode.settings, episode.device, episode.observations()
    step = len(episode.poses) - int(episode.scene.init_poses.shape[0])
    model, train_seconds = trained_backbone(episode, cache)
    units: dict[str, dict] = {}
    generator = seeded_generator(s.seed, step, "profile", device)
    marched = MarchCounter(model)
    stats, units["backbone"] = measured(lambda: continued_backbone(model, obs, s, BACKBONE_ITERS, generator), device)
    marched.restore()
    rays = 2 * BACKBONE_ITERS * s.train.backbone.batch  # measured() runs the work twice
    units["backbone"] |= {
        "unit": "iteration",
        "count": BACKBONE_ITERS,
        "samples_per_ray": stats.get("samples_per_ray"),
        "marched_per_ray": marched.samples / rays,
    }
    every = s.sampler.update_every
    update = every * math.ceil(s.sampler.warmup_iters / every)  # the first update past the warm-up (M5)
    _, units["grid_update"] = measured(lambda: model.update_grid(update, generator), device)
    cells = model.grid.resolution**3
    units["grid_update"] |= {"unit": "update", "count": 1, "probes": 2 * (cells // 4), "every": s.sampler.update_every}
    variance = dataclasses.replace(s.train, variance=dataclasses.replace(s.train.variance, iters=VARIANCE_ITERS))
    _, units["variance"] = measured(lambda: train_variance_head(model, obs, variance, s.entropy, generator), device)
    units["variance"] |= {"unit": "iteration", "count": VARIANCE_ITERS}
    units["visibility"] = visibility_unit(model, obs, s, generator, device)
    poses = state_candidates(episode, model, 1)
    generators = generator_factory(s.seed, step, device)
    scorers, prepare = {}, {}
    for name, overrides in SCORED.items():
        other = EpisodeSettings.of(compose_run([*cfg_overrides, *overrides]), episode.scene)
        start = time.perf_counter()
        scorers[name] = prepare_scorer(other.scorer(), model, obs, generators, s.planner.score_chunk_rays)
        prepare[name] = time.perf_counter() - start
    for group in (("nvf",), ("wo_vis",), ("nvf", "wo_vis"), ("activenerf",), ("fisherrf",)):
        chosen = [scorers[name] for name in group]
        assert all(scorer is not None for scorer in chosen)

        def score(chosen=chosen) -> list[torch.Tensor]:
            scored = [scorer for scorer in chosen if scorer is not None]
            return score_poses_together(model, scored, poses, episode.plan_intrinsics, s.planner.score_chunk_rays)

        _, unit = measured(score, device)
        units["score_" + "+".join(group)] = unit | {"unit": "candidate", "count": 1}
    evaluator = episode.evaluator
    gt = evaluator.gt[:1]
    reference = evaluator.lpips.reference(gt)

    def evaluate() -> object:
        pred = render_view(model, None, episode.scene.eval_poses[0].to(device), evaluator.intrinsics)["rgb"]
        return image_metrics(pred.clip(0.0, 1.0)[None], gt, evaluator.lpips, s.metrics.ssim_data_range, reference)

    _, units["evaluation"] = measured(evaluate, device)
    units["evaluation"] |= {"unit": "view", "count": 1, "lpips": evaluator.lpips.model is not None}
    _, units["mesh_metrics"] = measured(lambda: evaluator.geometry(model, obs, step), device)
    units["mesh_metrics"] |= {"unit": "step", "count": 1}
    return {"units": units, "prepare_seconds": prepare, "backbone_train_seconds": train_seconds}


def visibility_unit(model, obs, s: EpisodeSettings, generator: torch.Generator, device: torch.device) -> dict:
    """One stage-3 iteration, with the seconds and samples of its labels' field queries apart."""
    one = dataclasses.replace(s.train, visibility=dataclasses.replace(s.train.visibility, iters=1))
    timed = TimedDensity(model.density, device)
    own = model.density
    model.density = timed  # the labels' density, timed
    try:
        _, unit = measured(lambda: train_visibility_head(model, obs, one, generator), device)
    finally:
        model.density = own
    runs = 2  # measured() runs the work twice
    return unit | {
        "unit": "iteration x training camera",
        "count": obs.num_images,
        "field_query_seconds": timed.seconds / runs,
        "field_query_samples": timed.samples // runs,
    }


def main(argv: list[str]) -> None:
    args = parse_args(argv)
    torch.set_num_threads(1)  # the profile of one thread
    overrides = [f"budget={args.budget}", f"scene={args.scene}", *args.overrides]
    cfg = compose_run(overrides)
    out = report_path(args.out, cfg.paths.results, "paper_profile")
    cache = args.cache if args.cache is not None else Path(cfg.paths.outputs) / "bench_states"
    scene = load(cfg)
    device = resolve_device(str(cfg.device))
    start = time.perf_counter()
    episode = recorded_episode(cfg, scene, args.views, args.records, device)
    try:
        print(
            f"paper_profile: {args.scene} at {args.budget} after {args.views} views, {torch.get_num_threads()} threads"
        )
        found = profile_state(overrides, episode, cache)
    finally:
        episode.close()
    report = {
        "benchmark": "paper_profile",
        "command": " ".join(["python -m pipeline.bench paper_profile", *argv]),
        "budget": args.budget,
        "scene": args.scene,
        "views": args.views,
        "device": str(device),
        "torch_threads": torch.get_num_threads(),
        "machine": platform.platform(),
        "load_average_1_5_15_min": os.getloadavg(),
        **found,
        "encoding": encoding_rates(device),
        "seconds": time.perf_counter() - start,
    }
    write_report(report, out)
    for name, unit in found["units"].items():
        top = ", ".join(f"{op['op']} {op['share']:.0%}" for op in unit["top_ops"][:4])
        print(f"  {name:22} {unit['seconds'] / unit['count']:8.3f} s per {unit['unit']}: {top}")
    print(f"wrote {out}")
