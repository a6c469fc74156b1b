"""``python -m pipeline.bench paper_shape [--scenes default,room] [--eval-views 4] [--out PATH] [overrides]``:
``budget=paper`` at the paper's sizes with only counts cut: per stage seconds per unit of work and peak
memory, against the memory model, and a whole paper episode extrapolated from the measured rates.

Every size stays the paper's (512-px ground truth, training and evaluation images, 4096-ray batches, 65,536
visibility points x 200 label samples, 300-px planning images, a 2^19 hash table, a 128^3 grid, 500k
points); only counts are cut (``CUTS``: iterations, candidates, -OPT iterations, Cycles samples, the
evaluation views with ``--eval-views``, one step of the horizon). Overrides go on top (a cut key given there
replaces the cut; a size key changes both the run and the paper configuration it is compared with).

Step 0 of an NVF episode runs through the episode's own code (``pipeline.episode``, ``nvf.training``,
``nvf.planning``) as stages, one after another in one process: ``ground_truth`` (the episode's start: the
initial and evaluation views and their LPIPS features), ``ground_truth_paper_samples`` (Blender only: one view
at the paper's Cycles samples, its worker's start included), ``backbone``, ``variance``, ``visibility`` (each
a training stage), ``candidates`` (the candidate draw and the M28/M29 filters at the paper's candidate count),
``planning`` (``Episode.plan`` at the cut count: filters and scoring at 300 px; where the model's line of
sight leaves no candidate, as an untrained model's fog does on Room, it runs again with the scene mesh's, and
``problems`` says so), ``opt`` (-OPT's refinement of the top candidates), ``evaluation`` (the evaluation views
rendered, PSNR, SSIM, LPIPS) and ``mesh_metrics`` (500k points reconstructed, Acc., Comp., C.R. against 500k
mesh samples). Each stage reports its seconds per unit, its peak resident memory (``pipeline.bench._stages``)
and ``predicted_gib`` (``pipeline.config.memory.stage_peaks``). ``extrapolated_episode_hours_<device>``: a
20-step paper episode from the measured rates (per stage: seconds per unit x the paper's units; the visibility
head's unit is one iteration's labels against one training camera, so it grows with the views; the ground
truth at the paper's samples where Blender renders it); ``extrapolated_opt_extra_hours_<device>``: what
``planner=opt`` adds. A model trained for the cut iterations marches more samples than a trained one, so the
planning, evaluation and point-cloud rates are those of an untrained model. Writes
``results/bench/paper_shape.json`` (or ``--out``)."""

import dataclasses
import math
import os
import platform
import time
from pathlib import Path

import torch

from nvf.cameras import matrix_to_pose
from nvf.config import LineOfSightSource
from nvf.device import resolve_device
from nvf.model import SceneModel
from nvf.observations import Observations
from nvf.planning import NoCandidatesError, candidate_poses, refine_poses, top_k_first
from nvf.seeding import generator_factory, seeded_generator
from nvf.training import train_model
from nvf.uncertainty import ViewScorer
from nvf.visibility_source import SourcedVisibility
from pipeline.bench._report import report_path, write_report
from pipeline.bench._stages import GIB, PEAK_RSS, Stage, StageMeter
from pipeline.bench._state import MAX_STATE_VIEWS, measure_state, recorded_episode
from pipeline.cli import ArgumentParser, description, fail
from pipeline.config.catalog import declared
from pipeline.config.memory import EVAL_VIEWS, host_memory, stage_peaks
from pipeline.config.typed_run import Run
from pipeline.config.validation import compose_run
from pipeline.diagnostics.initial_view_model import load
from pipeline.episode.loop import Episode
from pipeline.episode.runner import torch_threads
from pipeline.episode.settings import EpisodeSettings
from pipeline.metrics.image import LpipsMetric
from pipeline.repo import RUNS
from pipeline.scenes.ground_truth import open_renderer
from pipeline.scenes.scene import Scene

# The counts cut (key: value); every other key keeps budget=paper's value.
CUTS = {
    "train.backbone.iters": 32,  # two occupancy-grid update periods (sampler.update_every = 16)
    "train.variance.iters": 5,
    "train.visibility.iters": 3,
    "planner.num_candidates": 8,
    "planner.opt.iters": 2,
    "render.samples": 16,
}
SIZE_KEYS = {  # the report's sizes: name -> key
    "image_px": "budget.image_size",
    "eval_px": "budget.eval_size",
    "planning_px": "planner.resolution",
    "hash_table_log2": "field.log2_hashmap_size",
    "grid": "sampler.grid_resolution",
    "gt_points": "budget.gt_points",
    "recon_points": "budget.recon_points",
    "backbone_rays": "train.backbone.batch",
    "variance_rays": "train.variance.batch",
    "visibility_points": "train.visibility.batch",
    "label_samples": "train.label_samples",
}


def parse_args(argv: list[str]):
    parser = ArgumentParser(prog="python -m pipeline.bench paper_shape", description=description(__doc__))
    parser.add_argument("overrides", nargs="*", help="Hydra overrides on top of budget=paper and the cuts")
    parser.add_argument("--scenes", default="default,room", help="comma-separated scenes (default: default,room)")
    parser.add_argument(
        "--budget", default="paper", help="the budget whose sizes run (default: paper; smoke: a dry run)"
    )
    parser.add_argument("--eval-views", type=int, default=4, help=f"evaluation views rendered (of {EVAL_VIEWS})")
    parser.add_argument(
        "--out", type=Path, default=None, help="JSON report path (default: ${paths.results}/bench/paper_shape.json)"
    )
    parser.add_argument(
        "--full-state",
        type=int,
        default=0,
        metavar="VIEWS",
        help="also measure one whole state of the first scene after VIEWS views at the full counts (0: none)",
    )
    parser.add_argument("--records", type=Path, default=RUNS, help=f"the NVF cpu record a state takes (default {RUNS})")
    args = parser.parse_intermixed_args(argv)
    if args.budget not in declared("budget"):
        fail(f"--budget {args.budget!r}: not one of conf/budget ({', '.join(declared('budget'))})")
    if not 0 <= args.full_state <= MAX_STATE_VIEWS:
        fail(f"--full-state {args.full_state}: must be 0..{MAX_STATE_VIEWS} views")
    if not 1 <= args.eval_views <= EVAL_VIEWS:
        fail(f"--eval-views {args.eval_views}: must be 1..{EVAL_VIEWS}")
    args.scenes = [name.strip() for name in args.scenes.split(",") if name.strip()]
    if not args.scenes:
        fail("--scenes: name at least one scene, e.g. --scenes default,room")
    return args


def configs(budget: str, scene: str, overrides: list[str]) -> tuple[Run, Run]:
    """The cut configuration the stages run and the uncut one it stands for (``budget``, the same overrides);
    a cut never raises a count above the budget's."""
    paper = compose_run([f"budget={budget}", f"scene={scene}", *overrides])
    counts = [f"{key}={min(value, paper.setting(key))}" for key, value in CUTS.items()]
    cut = compose_run([f"budget={budget}", f"scene={scene}", *counts, *overrides])
    for key in SIZE_KEYS.values():
        assert cut.setting(key) == paper.setting(key), f"a cut changed the size {key}"
    return cut, paper


def cuts(cut: Run, paper: Run, eval_views: int) -> list[dict]:
    """Each count the run cut: its key, the paper's value and the value used."""
    blender = paper.render.backend == "blender"
    found = [
        {"key": key, "budget_value": paper.setting(key), "used": cut.setting(key)}
        for key in CUTS
        if paper.setting(key) != cut.setting(key) and (blender or key != "render.samples")
    ]
    found.append({"key": "budget.horizon", "budget_value": int(paper.budget.horizon), "used": 1})
    if eval_views < EVAL_VIEWS:
        found.append({"key": "evaluation views (--eval-views)", "budget_value": EVAL_VIEWS, "used": eval_views})
    return found


def measure(cfg: Run, paper: Run, scene: Scene, eval_views: int, meter: StageMeter) -> list[str]:
    """Step 0 of an episode of ``cfg`` on ``scene`` as stages timed by ``meter`` (``paper``: the paper's
    candidate count and Cycles samples); returns what could not run, one line each."""
    if eval_views < scene.eval_poses.shape[0]:
        scene = dataclasses.replace(scene, eval_poses=scene.eval_poses[:eval_views])
    s = EpisodeSettings.of(cfg, scene)
    with meter.stage("ground_truth", "view", scene.init_poses.shape[0] + eval_views):
        episode = Episode(s, scene, meter.device, LpipsMetric())
    try:
        if s.render.backend == "blender":
            with meter.stage("ground_truth_paper_samples", "view", 1):
                render = dataclasses.replace(s.render, samples=int(paper.render.samples))
                renderer = open_renderer(scene, render, s.blender_python)
                renderer.render_rgba(scene.eval_poses[0], episode.intrinsics, s.budget.gt_samples)
                renderer.close()
        return measure_step(episode, int(paper.planner.num_candidates), meter)
    finally:
        episode.close()


def measure_step(episode: Episode, paper_candidates: int, meter: StageMeter) -> list[str]:
    """Step 0's training stages, planning, -OPT and evaluation (the module docstring's stages); returns the
    stages that could not run and why."""
    s, device = episode.settings, meter.device
    obs = episode.observations()
    model = episode.new_model(0)
    generator = seeded_generator(s.seed, 0, "train", device)
    for stage in s.stages:
        iters = getattr(s.train, stage).iters
        per_camera = stage == "visibility"
        unit = "iteration x training camera" if per_camera else "iteration"
        with meter.stage(stage, unit, iters * obs.num_images if per_camera else iters) as record:
            stats = train_model(model, obs, s.train, {stage}, s.entropy, generator, type(s.method).aux_loss)
            record.samples_per_ray = stats.stages[stage].get("samples_per_ray")
    planning = episode.planning_model(model, obs)
    scorer = episode.scorer if isinstance(episode.scorer, ViewScorer) else None
    problems = plan_stages(episode, planning, obs, scorer, paper_candidates, meter)
    with meter.stage("evaluation", "view", len(episode.scene.eval_poses)):
        _, pred = episode.evaluator.renders(planning, scorer)
        episode.evaluator.quality(pred)
    with meter.stage("mesh_metrics", "step", 1):
        episode.evaluator.geometry(planning, obs, 0)
    return problems


def plan_stages(
    episode: Episode,
    planning: SceneModel | SourcedVisibility,
    obs: Observations,
    scorer: ViewScorer | None,
    paper_candidates: int,
    meter: StageMeter,
) -> list[str]:
    """The candidate draw and filters at the paper's count, ``Episode.plan`` at the cut count and -OPT's
    refinement of its top candidates (with a per-pixel ``scorer``). Where the model's line of sight (M29)
    leaves no candidate, planning runs again with the scene mesh's (``planner.los_source=mesh``, the same
    scoring); returns those failures."""
    s, device = episode.settings, meter.device
    drawn = 3 * paper_candidates if s.collision_free else math.floor(s.planner.oversample * paper_candidates)
    box = episode.scene.camera_box.to(device)
    problems = []
    try:
        with meter.stage("candidates", "drawn pose", drawn):
            candidate_poses(
                planning,
                dataclasses.replace(s.planner, num_candidates=paper_candidates),
                box,
                matrix_to_pose(episode.poses[-1]).to(device),
                s.tau,
                s.collision_free,
                generator_factory(s.seed, 0, device)("candidates"),
                line_of_sight=episode.renderer.unoccluded,
            )
    except NoCandidatesError as err:
        problems.append(f"candidates ({drawn} drawn): {err}")
    try:
        with meter.stage("planning", "candidate", s.planner.num_candidates) as record:
            selection, generators = episode.plan(planning, obs, 0)
            record.count = selection.num_candidates
    except NoCandidatesError as err:
        problems.append(f"planning: {err}; measured again with planner.los_source=mesh")
        episode.settings = dataclasses.replace(
            s, planner=dataclasses.replace(s.planner, los_source=LineOfSightSource.mesh)
        )
        with meter.stage("planning", "candidate", s.planner.num_candidates) as record:
            selection, generators = episode.plan(planning, obs, 0)
            record.count = selection.num_candidates
    if scorer is not None and selection.scores is not None and selection.candidates is not None:
        top = selection.candidates[top_k_first(selection.scores, s.planner.opt.top_k)]
        with meter.stage("opt", "iteration", s.planner.opt.iters):
            refine_poses(planning, scorer, top, box, episode.plan_intrinsics, s.planner.opt, generators)
    return problems


def paper_units(name: str, paper: Run, views: int) -> float:
    """Units of stage ``name`` in one paper episode of ``paper`` starting from ``views`` initial views (argmax
    planner; ``opt``: what ``planner=opt`` adds, its re-scoring counted under ``planning``)."""
    h = int(paper.budget.horizon)
    p = paper.planner
    drawn = 3 * int(p.num_candidates) if paper.scene.collision_free else math.floor(p.oversample * p.num_candidates)
    per_episode = {
        "ground_truth": views + EVAL_VIEWS + h,
        "backbone": h * int(paper.train.backbone.iters),
        "variance": h * int(paper.train.variance.iters),
        "visibility": int(paper.train.visibility.iters) * sum(views + t for t in range(h)),
        "candidates": h * drawn,
        "planning": h * int(p.num_candidates),
        "opt": h * int(p.opt.iters),
        "evaluation": h * EVAL_VIEWS,
        "mesh_metrics": h,
    }
    return float(per_episode.get(name, 0))


def stage_rows(scene: str, stages: list[Stage], predicted: dict[str, float], paper: Run, views: int) -> list[dict]:
    """The report's rows of one scene's stages, each with its memory prediction and its share of a paper
    episode (the ground truth at the paper's Cycles samples where they ran)."""
    rates = {stage.name: stage.seconds_per_unit for stage in stages}
    rates["ground_truth"] = rates.get("ground_truth_paper_samples", rates["ground_truth"])
    rows = []
    for stage in stages:
        row = {"scene": scene, **dataclasses.asdict(stage), "seconds_per_unit": stage.seconds_per_unit}
        row["predicted_gib"] = predicted[stage.name.removesuffix("_paper_samples")] / GIB
        peak = stage.peak_device_gib if stage.peak_device_gib is not None else stage.peak_rss_gib
        if peak is not None:
            row["measured_over_predicted"] = peak / row["predicted_gib"]
        units = paper_units(stage.name, paper, views)
        row["paper_units_per_episode"] = units
        row["extrapolated_hours"] = rates[stage.name] * units / 3600.0 if stage.name in rates else None
        rows.append(row)
    return rows


def print_stage(stage: Stage) -> None:
    peak = "n/a" if stage.peak_rss_gib is None else f"{stage.peak_rss_gib:.2f} GiB"
    device = "" if stage.peak_device_gib is None else f", device {stage.peak_device_gib:.2f} GiB"
    work = f"{stage.count:>6} x {stage.unit:27}"
    print(f"  {stage.name:27} {work} {stage.seconds_per_unit:9.3f} s each, peak {peak}{device}", flush=True)


def opt_extra_hours(rows: list[dict], paper: Run) -> float | None:
    """What ``planner=opt`` adds to a paper episode: the refinement and the re-scoring of ``2 top_k`` poses."""
    by_name = {row["name"]: row for row in rows}
    if "opt" not in by_name or "planning" not in by_name:
        return None
    rescored = 2 * int(paper.planner.opt.top_k) * int(paper.budget.horizon)
    return by_name["opt"]["extrapolated_hours"] + rescored * by_name["planning"]["seconds_per_unit"] / 3600.0


def whole_state(overrides: list[str], paper: Run, scene: Scene, args) -> dict:
    """``pipeline.bench._state.measure_state`` on the state after ``args.full_state`` views, at ``paper``'s full
    counts, with the threads it ran on."""
    device = resolve_device(str(paper.device))
    episode = recorded_episode(paper, scene, args.full_state, args.records, device)
    try:
        found, _ = measure_state(overrides, episode)
    finally:
        episode.close()
    return found | {"threads": torch.get_num_threads()}


def state_episode_hours(state: dict, rows: list[dict], paper: Run, views: int) -> float:
    """A paper episode extrapolated as ``stage_rows`` does, with the rates of the trained whole state where it has
    them (stage 1, the heads, NVF's scoring per candidate with w/o Vis.'s beside it) and the cut stages' for the
    rest (ground truth, candidates, evaluation, mesh metrics)."""
    stages = state["stages"]["nvf"]
    rates = {row["name"]: row["seconds_per_unit"] for row in rows}
    rates["ground_truth"] = rates.get("ground_truth_paper_samples", rates["ground_truth"])
    rates["backbone"] = stages["backbone"]["seconds"] / stages["backbone"]["iters"]
    rates["variance"] = stages["variance"]["seconds"] / max(1.0, stages["variance"]["iters"])
    rates["visibility"] = stages["visibility"]["seconds"] / (stages["visibility"]["iters"] * state["views"])
    rates["planning"] = state["score_seconds"]["nvf+wo_vis"] / state["candidates"]
    names = (
        "ground_truth",
        "backbone",
        "variance",
        "visibility",
        "candidates",
        "planning",
        "evaluation",
        "mesh_metrics",
    )
    return sum(rates[name] * paper_units(name, paper, views) for name in names if name in rates) / 3600.0


def main(argv: list[str]) -> None:
    args = parse_args(argv)
    start = time.perf_counter()
    torch.set_num_threads(torch_threads())
    setups = {scene: configs(args.budget, scene, args.overrides) for scene in args.scenes}
    scenes = {name: load(cfg) for name, (cfg, _) in setups.items()}  # a missing asset: one line, before any stage
    first, first_paper = next(iter(setups.values()))
    out = report_path(args.out, first.paths.results, "paper_shape")
    device = resolve_device(str(first.device))
    kind = device.type
    rows: list[dict] = []
    problems, hours, opt_hours = {}, {}, {}
    load_average = {"start": os.getloadavg()}
    for name, (cfg, paper) in setups.items():
        threads = torch.get_num_threads()
        print(f"paper_shape: {name}, budget={args.budget} with counts cut, on {device} ({threads} threads)")
        meter = StageMeter(device, done=print_stage)
        problems[name] = measure(cfg, paper, scenes[name], args.eval_views, meter)
        views = int(scenes[name].init_poses.shape[0])
        predicted = stage_peaks(cfg, views, min(args.eval_views, EVAL_VIEWS), on_device=kind == "cuda")
        found = stage_rows(name, meter.stages, predicted, paper, views)
        rows += found
        hours[name] = sum(row["extrapolated_hours"] or 0.0 for row in found if row["name"] != "opt")
        opt_hours[name] = opt_extra_hours(found, paper)
    state = None
    if args.full_state:
        name = args.scenes[0]
        _, paper = setups[name]
        print(f"paper_shape: one whole state of {name} after {args.full_state} views at budget={args.budget}")
        state = whole_state([f"budget={args.budget}", f"scene={name}", *args.overrides], paper, scenes[name], args)
        state_rows = [row for row in rows if row["scene"] == name]
        hours[f"{name}_from_state"] = state_episode_hours(
            state, state_rows, paper, int(scenes[name].init_poses.shape[0])
        )
    report = {
        "benchmark": "paper_shape",
        "command": " ".join(["python -m pipeline.bench paper_shape", *argv]),
        "budget": args.budget,
        "device": str(device),
        "device_name": torch.cuda.get_device_name(device) if kind == "cuda" else platform.processor() or None,
        "machine": platform.platform(),
        "torch_threads": torch.get_num_threads(),
        "load_average_1_5_15_min": load_average | {"end": os.getloadavg()},
        "memory_gib": host_memory() / GIB,
        "peak_rss": PEAK_RSS,
        "peak_rss_missing": meter.missing,
        "sizes": {key: first_paper.setting(path) for key, path in SIZE_KEYS.items()},
        "cuts": cuts(first, first_paper, args.eval_views),
        "stages": rows,
        "problems": problems,
        "state": state,
        "state_hours_cpu": None if state is None or kind != "cpu" else state["process_seconds"] / 3600.0,
        f"extrapolated_episode_hours_{kind}": hours,
        f"extrapolated_opt_extra_hours_{kind}": opt_hours,
        "fits_in_memory": all(
            (row["peak_rss_gib"] or 0.0) + (row["worker_peak_rss_gib"] or 0.0) < host_memory() / GIB for row in rows
        ),
        "seconds": time.perf_counter() - start,
    }
    write_report(report, out)
    for row in rows:
        measured = "n/a" if row["peak_rss_gib"] is None else f"{row['peak_rss_gib']:.2f}"
        print(f"{row['scene']:>8} {row['name']:27} peak {measured} GiB, model {row['predicted_gib']:.2f} GiB")
    print(f"a paper episode from these rates ({kind}): " + ", ".join(f"{k} {v:.1f} h" for k, v in hours.items()))
    print(f"wrote {out}")
