"""A trained state at the paper's sizes, for the benchmarks that measure one (``paper_profile``, ``speedups``,
``paper_shape --full-state``): the scene's initial views plus the poses a committed NVF cpu episode selected
before them (``recorded_episode``), its backbone trained at the budget's counts (``trained_backbone``), kept on
disk between benchmark runs (half an hour of one thread at the paper's 5000 iterations), and a whole state as
a decision takes it, timed (``measure_state``)."""

import argparse
import dataclasses
import hashlib
import io
import json
import time
from pathlib import Path

import torch

from nvf.cameras import matrix_to_pose
from nvf.model import SceneModel
from nvf.observations import Observations
from nvf.planning import candidate_poses, prepare_scorer, score_poses_together
from nvf.seeding import generator_factory, seeded_generator
from nvf.training import train_model
from nvf.uncertainty import ViewScorer
from pipeline.atomic_write import atomic_write_bytes
from pipeline.cli import fail
from pipeline.config.typed_run import Run
from pipeline.config.validation import compose_run
from pipeline.episode.loop import Episode
from pipeline.episode.settings import EpisodeSettings
from pipeline.episode.shared_training import train_models
from pipeline.metrics.image import LpipsMetric
from pipeline.records.store import run_dir
from pipeline.repo import RUNS
from pipeline.scenes.scene import Scene
from pipeline.tables.load import load_run

RECORD_SEED = 100  # the committed NVF cpu episode whose poses a state takes
STAGE_ONE_KEYS = ("backbone", "schedule", "target_samples", "lr_decay_horizon", "precision")  # train.* stage 1 reads
MAX_STATE_VIEWS = 64


def add_state_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of a benchmark that trains a state (``--scene``, ``--views``, ``--records``, ``--cache``,
    ``--budget``); ``check_state_arguments`` bounds them after parsing."""
    parser.add_argument("--scene", default="default", help="the scene (default: default)")
    parser.add_argument(
        "--views", type=int, default=10, help=f"training views of the state (1..{MAX_STATE_VIEWS}, default 10)"
    )
    parser.add_argument("--records", type=Path, default=RUNS, help=f"where the NVF cpu record is (default {RUNS})")
    parser.add_argument(
        "--cache", type=Path, default=None, help="trained backbones (default ${paths.outputs}/bench_states)"
    )
    parser.add_argument("--budget", default="paper", help="the budget (default paper; smoke: a dry run)")


def check_state_arguments(args: argparse.Namespace) -> None:
    """One ``error:`` line for a state's view count out of bounds."""
    if not 1 <= args.views <= MAX_STATE_VIEWS:
        fail(f"--views {args.views}: must be 1..{MAX_STATE_VIEWS}")


def recorded_episode(cfg: Run, scene: Scene, views: int, records: Path, device: torch.device) -> Episode:
    """An episode of ``cfg`` on ``scene`` that has observed ``views`` views: the initial ones, then the poses the
    committed NVF cpu episode of seed 100 selected (``records``); fails in one line without that record."""
    init = int(scene.init_poses.shape[0])
    directory = run_dir(records, scene.name, "nvf", "argmax", "none", "cpu", RECORD_SEED)
    try:
        _, rows = load_run(directory)
    except (ValueError, OSError) as err:
        fail(f"no usable NVF cpu record at {directory}: {err}; pass --records DIR holding it")
    if not init <= views <= init + len(rows):
        fail(
            f"--views {views}: must be {init}..{init + len(rows)} ({scene.name}'s initial views and its record's steps)"
        )
    episode = Episode(EpisodeSettings.of(cfg, scene), scene, device, LpipsMetric())
    episode.replay(rows[: views - init])
    return episode


def _cache_key(episode: Episode) -> str:
    """What a trained backbone depends on: the settings stage 1 reads (of ``train``: ``STAGE_ONE_KEYS``), the scene,
    the observed poses and images."""
    s = episode.settings
    parts = {
        "field": dataclasses.asdict(s.field),
        "sampler": dataclasses.asdict(s.sampler),
        "train": {key: value for key, value in dataclasses.asdict(s.train).items() if key in STAGE_ONE_KEYS},
        "seed": s.seed,
        "scene": episode.scene.name,
        "poses": [pose.tolist() for pose in episode.poses],
    }
    digest = hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode())
    for image in episode.images:
        digest.update(image.tobytes())
    return digest.hexdigest()[:16]


def trained_backbone(episode: Episode, cache: Path | None) -> tuple[SceneModel, float]:
    """The episode's next step's model with stage 1 trained as that step trains it (its seed, ``train.backbone``),
    and the seconds the training took (0 when read from ``cache``, a folder where it is kept by its settings and
    observations)."""
    step = len(episode.poses) - int(episode.scene.init_poses.shape[0])
    s, obs = episode.settings, episode.observations()
    path = None if cache is None else cache / f"{episode.scene.name}-{_cache_key(episode)}.pt"
    model = episode.new_model(step)
    if path is not None and path.is_file():
        model.load_state_dict(torch.load(path, map_location=episode.device, weights_only=True))
        return model, 0.0
    generator = seeded_generator(s.seed, step, "train", episode.device)
    stats = train_model(model, obs, s.train, {"backbone"}, s.entropy, generator)
    if path is not None:
        buffer = io.BytesIO()
        torch.save(model.state_dict(), buffer)
        atomic_write_bytes(path, buffer.getvalue())
    return model, stats.stages["backbone"]["seconds"]


CONTINUED_LR = 1e-5  # a continued stage 1's: Adam's first steps move every parameter by about the lr


def continued_backbone(
    model: SceneModel, obs: Observations, s: EpisodeSettings, iters: int, generator: torch.Generator
) -> dict[str, float]:
    """``iters`` more stage-1 iterations of a trained backbone, for timing them: the work of its last iterations
    (the same batches, renders, losses, Adam steps and occupancy-grid updates past its warm-up; a continued run
    counts its iterations from 0) at a small learning rate (``CONTINUED_LR``), since a fresh optimiser's first
    steps at the schedule's would move the trained model (a loss jump that the collapse rule stops). Returns the
    stage's summary (``nvf.training.TrainStats``)."""
    train = dataclasses.replace(s.train, backbone=dataclasses.replace(s.train.backbone, iters=iters, lr=CONTINUED_LR))
    grid = model.grid.cfg
    model.grid.cfg = dataclasses.replace(grid, warmup_iters=0)
    try:
        return train_model(model, obs, train, {"backbone"}, s.entropy, generator).stages["backbone"]
    finally:
        model.grid.cfg = grid


def state_candidates(episode: Episode, model: SceneModel, count: int | None = None) -> torch.Tensor:
    """The candidate poses ``episode``'s planner draws at its next step from ``model`` (the step's own generator,
    the filters of its method), the first ``count`` of them (all by default)."""
    s, device = episode.settings, episode.device
    step = len(episode.poses) - int(episode.scene.init_poses.shape[0])
    poses = candidate_poses(
        model,
        s.planner,
        episode.scene.camera_box.to(device),
        matrix_to_pose(episode.poses[-1]).to(device),
        s.tau,
        s.collision_free,
        generator_factory(s.seed, step, device)("candidates"),
        line_of_sight=episode.renderer.unoccluded,
    )
    return poses if count is None else poses[:count]


SCORED = {  # the methods a paper-size state scores, and their overrides
    "nvf": [],
    "wo_vis": ["ablation=wo_vis"],
    "fisherrf": ["method=fisherrf"],
    "activenerf": ["method=activenerf"],
}


def measure_state(cfg_overrides: list[str], episode: Episode) -> tuple[dict, SceneModel]:
    """One paper-size state as a decision takes it, after ``episode``'s views: NVF's, w/o Vis.'s, FisherRF's and
    ActiveNeRF's models trained at the budget's counts (``train_models``: one stage 1 for all four, NVF's model
    serving w/o Vis. and FisherRF), NVF's planner's candidates drawn, FisherRF's Fisher diagonal prepared and every
    candidate scored by each (one render for the per-pixel scorers of a model, timed apart from FisherRF's
    whole-view scores). Returns the seconds of each part and in all (wall clock, and ``process_seconds``: the CPU
    time of this process, all its threads, which a busy machine does not inflate as much), the training stages'
    summaries and NVF's trained model (``cfg_overrides``: ``episode``'s own)."""
    start, cpu_start = time.perf_counter(), time.process_time()
    obs, device = episode.observations(), episode.device
    step = len(episode.poses) - int(episode.scene.init_poses.shape[0])
    episodes = {
        name: episode.as_method(EpisodeSettings.of(compose_run([*cfg_overrides, *overrides]), episode.scene))
        for name, overrides in SCORED.items()
    }
    trained = train_models(episodes, obs, step)
    s = episodes["nvf"].settings
    generators = generator_factory(s.seed, step, device)
    planning = trained["nvf"].model
    candidates = state_candidates(episode, planning)
    prepare, scorers = {}, {}
    for name, one in episodes.items():
        begin = time.perf_counter()
        scorers[name] = prepare_scorer(one.scorer, trained[name].model, obs, generators, s.planner.score_chunk_rays)
        prepare[name] = time.perf_counter() - begin
    groups: dict[tuple[int, bool], list[str]] = {}  # (model, per pixel) -> scorers
    for name in SCORED:
        groups.setdefault((id(trained[name].model), isinstance(scorers[name], ViewScorer)), []).append(name)
    score = {}
    for names in groups.values():
        chosen = [scorer for scorer in (scorers[name] for name in names) if scorer is not None]
        begin = time.perf_counter()
        model = trained[names[0]].model
        score_poses_together(model, chosen, candidates, episode.plan_intrinsics, s.planner.score_chunk_rays)
        score["+".join(names)] = time.perf_counter() - begin
    report = {
        "views": obs.num_images,
        "candidates": int(candidates.shape[0]),
        "trainings": {name: trained[name].seconds for name in SCORED},
        "stages": {name: trained[name].stages for name in ("nvf", "activenerf")},
        "prepare_seconds": prepare,
        "score_seconds": score,
        "seconds": time.perf_counter() - start,
        "process_seconds": time.process_time() - cpu_start,
    }
    return report, planning
