"""Run (or resume) one episode into its run record: validate the config, derive the run directory from the
run's keys, take the run's lock (one writer per run), verify what is recorded there, skip a finished run
(refusing one that finished with other settings), repeat a failed run's reason, resume an unfinished one
at its first missing step, and record every step atomically; a step that cannot complete marks the run
failed with a one-line reason. A Blender worker that does not answer in time (``render.timeout``) stops
the run with a one-line reason and leaves it to resume.
"""

import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from nvf.planning import NoCandidatesError
from nvf.training import TrainingDiverged
from pipeline.config.validation import resolve_device, validate
from pipeline.episode.loop import Episode
from pipeline.episode.progress import EpisodeProgress
from pipeline.metrics.image import LpipsMetric
from pipeline.records.images import save_step_images
from pipeline.records.lock import RunLock
from pipeline.records.store import RunRecord, run_dir
from pipeline.records.verify import verified
from pipeline.scenes.blender import BlenderTimeout, blender_python
from pipeline.scenes.ground_truth import ground_truth_info
from pipeline.scenes.loading import load_scene
from pipeline.tables.summary import run_pictures, summarize_run
from pipeline.tables.trajectory import outline_of_scene


class StepFailed(RuntimeError):
    """The run failed (now, or when it last ran; its record holds this one-line reason), or stopped for a
    reason outside its settings and is left unfinished, to resume (a Blender worker that did not answer)."""


class RunRefused(ValueError):
    """The run cannot start: its directory holds a record of another run (other settings)."""


@dataclass(frozen=True)
class Outcome:
    """What ``run_episode`` did: ``done`` (ran to its horizon) or ``skipped`` (had finished before)."""

    directory: Path
    status: str


def torch_threads() -> int:
    """Threads per job: the machine's cores divided among the launcher's parallel jobs (measured:
    two 2-thread jobs on 2 cores ran 3.5x slower than two 1-thread jobs)."""
    cores = os.cpu_count() or 1
    jobs = 1
    if HydraConfig.initialized():
        jobs = HydraConfig.get().launcher.get("n_jobs", 1) or 1
    jobs = cores if jobs < 1 else min(jobs, cores)  # joblib's n_jobs=-1 means one job per core
    return max(1, cores // jobs)


def record_dir(cfg: DictConfig) -> Path:
    return run_dir(
        Path(cfg.paths.outputs), cfg.scene.name, cfg.method.name, cfg.planner.name, cfg.ablation.name,
        cfg.budget.name, int(cfg.seed),
    )  # fmt: skip


def run_settings(cfg: DictConfig) -> dict:
    """The run's identity keys and resolved config: what makes two records the same run."""
    return {
        "scene": cfg.scene.name,
        "method": cfg.method.name,
        "planner": cfg.planner.name,
        "ablation": cfg.ablation.name,
        "budget": cfg.budget.name,
        "seed": int(cfg.seed),
        "config": OmegaConf.to_container(cfg, resolve=True),
    }


def run_info(cfg: DictConfig, episode: Episode, lpips_reason: str | None, ground_truth: dict) -> dict:
    """run.json's content: the run's settings, the scene's source, ``ground_truth`` (backend and asset file:
    ``pipeline.scenes.ground_truth.ground_truth_info``), the resolved collision-free choice, device, threads
    and why LPIPS is missing (if it is)."""
    return {
        **run_settings(cfg),
        "scene_source": episode.scene.source,
        "ground_truth": ground_truth,
        "collision_free": episode.settings.collision_free,  # M29's candidate sampler, as resolved for the scene
        "candidate_filters": episode.scorer is not None or episode.settings.planner.random_filters,  # M28, M29
        "field": cfg.field.kind,
        "device": str(episode.device),
        "torch_threads": torch.get_num_threads(),
        "lpips_missing_reason": lpips_reason,
    }


def run_episode(cfg: DictConfig) -> Outcome:
    """Run (or resume) one episode under its run's lock (``pipeline.records.lock``).

    Raises ``ConfigError`` (a bad value), ``RunLocked`` (another process writes the run), ``RecordError``
    (its record fails a check), ``RunRefused`` (a record of other settings), ``SceneError`` (the scene
    cannot load): all before the record starts. ``StepFailed`` once the run failed (recorded as such) or
    stopped (``BlenderTimeout``: left unfinished).
    """
    validate(cfg)
    directory = record_dir(cfg)
    with RunLock(directory, root=Path(cfg.paths.outputs)):
        return _run_locked(cfg, directory)


def _run_locked(cfg: DictConfig, directory: Path) -> Outcome:
    record = RunRecord(directory)
    previous, _ = verified(record)
    status = record.status()
    changed = record.difference(run_settings(cfg)) if previous else None
    if changed is not None:
        verb = {"done": "finished", "failed": "failed"}.get(status, "was started")
        raise RunRefused(
            f"run {directory} {verb} with a different {changed}; "
            "pass paths.outputs=DIR to record this run elsewhere, or delete that run to replace it"
        )
    if status == "done":
        print(f"skipping finished run {directory}")
        return Outcome(directory, "skipped")
    if status == "failed":
        raise StepFailed(f"run {directory} failed: {record.failure()} (delete it to run it again)")
    print(f"run {directory}: building the scene and its ground truth (the step bar follows)", flush=True)
    torch.set_num_threads(torch_threads())
    torch.manual_seed(int(cfg.seed))
    np.random.seed(int(cfg.seed) % 2**32)
    scene = load_scene(cfg.scene, Path(cfg.paths.assets), blender_python(cfg.paths.blender_python))
    device = resolve_device(cfg.device)
    lpips = LpipsMetric()
    try:
        episode = Episode(cfg, scene, device, lpips)
        try:
            return _run_steps(cfg, directory, record, episode, lpips)
        finally:
            episode.close()
    except BlenderTimeout as err:
        raise StepFailed(
            f"run {directory} stopped at step {len(record.completed_steps())}: {err}; every finished step is "
            "recorded: run the same command again to resume"
        ) from None


def _run_steps(cfg: DictConfig, directory: Path, record: RunRecord, episode: Episode, lpips: LpipsMetric) -> Outcome:
    """Record and run the steps of ``episode`` not yet in ``record``."""
    done_rows = record.completed_steps()
    ground_truth = ground_truth_info(episode.scene, episode.renderer, Path(cfg.paths.assets))
    record.start(run_info(cfg, episode, lpips.missing, ground_truth))
    try:
        episode.replay(done_rows)
        if done_rows:
            print(f"resuming {directory} at step {len(done_rows)} of {int(cfg.budget.horizon)}")
        _record_steps(cfg, directory, episode, record, len(done_rows))
    except (TrainingDiverged, NoCandidatesError, FloatingPointError) as err:
        reason = f"step {len(record.completed_steps())}: {err}"
        record.mark_failed(reason)
        raise StepFailed(reason) from None
    except (OSError, BlenderTimeout):  # writing the record failed, or Blender hung: left unfinished, to resume
        raise
    except Exception as err:  # an unexpected error: recorded, then raised with its traceback
        record.mark_failed(f"step {len(record.completed_steps())}: {type(err).__name__}: {' '.join(str(err).split())}")
        raise
    record.mark_done()
    summarize_run(directory)
    run_pictures(directory, outline_of_scene(episode.scene, str(cfg.scene.kind)))
    return Outcome(directory, "done")


def _record_steps(cfg: DictConfig, directory: Path, episode: Episode, record: RunRecord, first: int) -> None:
    """Steps ``first`` .. horizon - 1, each row (and the step's images) written once the step is complete."""
    label = f"{cfg.scene.name}/{cfg.method.name} {cfg.budget.name} seed {int(cfg.seed)}"
    stages = list(cfg.method.stages)
    with EpisodeProgress(label, first, int(cfg.budget.horizon), stages) as progress:
        for step in range(first, int(cfg.budget.horizon)):
            start = time.perf_counter()
            row, images = episode.step(step, progress.train)
            if cfg.save_images:
                save_step_images(directory / "images", step, images, episode.method.score_unit)
            record.append_step(row)
            episode.observe_pose(row["selected_pose"])
            progress.step_done(step, row["n_views"], row["metrics"]["psnr"], time.perf_counter() - start)
