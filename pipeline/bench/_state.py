"""A trained state at the paper's sizes, for the benchmarks that measure one (``paper_profile``, ``speedups``,
``paper_shape --state``): the scene's initial views plus the poses a committed NVF cpu episode selected before
them (``recorded_episode``), and its backbone trained at the budget's counts (``trained_backbone``), kept on
disk between benchmark runs (an hour of one thread at the paper's 5000 iterations)."""

import dataclasses
import hashlib
import json
from pathlib import Path

import torch

from nvf.model import SceneModel
from nvf.seeding import seeded_generator
from nvf.training import Observations, backbone_lr, train_model
from pipeline.cli import fail
from pipeline.config.typed import Run
from pipeline.episode.loop import Episode
from pipeline.episode.settings import EpisodeSettings
from pipeline.metrics.image import LpipsMetric
from pipeline.records.store import run_dir
from pipeline.scenes.scene import Scene
from pipeline.tables.load import load_run

RECORD_SEED = 100  # the committed NVF cpu episode whose poses a state takes


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
    """What a trained backbone depends on: the settings stage 1 reads, the scene, the observed poses and images."""
    s = episode.settings
    parts = {
        "field": dataclasses.asdict(s.field),
        "sampler": dataclasses.asdict(s.sampler),
        "train": dataclasses.asdict(s.train),
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
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        torch.save(model.state_dict(), tmp)
        tmp.replace(path)
    return model, stats.stages["backbone"]["seconds"]


def continued_backbone(
    model: SceneModel, obs: Observations, s: EpisodeSettings, iters: int, generator: torch.Generator
) -> dict[str, float]:
    """``iters`` more stage-1 iterations of a trained backbone, run as its last iterations run: at the lr of
    iteration ``train.backbone.iters`` and with the occupancy grid past its warm-up (a continued run counts its
    iterations from 0). Returns the stage's summary (``nvf.training.TrainStats``)."""
    lr = backbone_lr(s.train, s.train.backbone.iters)
    train = dataclasses.replace(s.train, backbone=dataclasses.replace(s.train.backbone, iters=iters, lr=lr))
    grid = model.grid.cfg
    model.grid.cfg = dataclasses.replace(grid, warmup_iters=0)
    try:
        return train_model(model, obs, train, {"backbone"}, s.entropy, generator).stages["backbone"]
    finally:
        model.grid.cfg = grid
