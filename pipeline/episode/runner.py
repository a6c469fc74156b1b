"""Run (or resume) one episode into its run record: derive the run directory from the run's
keys, take the run's lock (one writer per run), verify what is recorded there, skip a finished run
(refusing one that finished with other settings), repeat a failed run's reason, resume an unfinished one
at its first missing step, and record every step atomically; a step that cannot complete marks the run
failed with a one-line reason. A Blender worker that does not answer in time (``render.timeout``) stops
the run with a one-line reason and leaves it to resume.

It takes the typed run (``pipeline.config.typed_run.Run``, validated by the entry point): its composed form
is recorded (run.json), and the episode gets the settings built from it (``pipeline.episode.settings``).
The summary and pictures of a finished run are the entry point's (``pipeline.run``), from the ``Outcome``.
"""

import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from hydra.core.hydra_config import HydraConfig

from nvf.device import resolve_device
from nvf.planning import NoCandidatesError
from nvf.stage_recorder import TrainingDiverged
from nvf.uncertainty import StepScorer
from pipeline.cli import BadInput, Failed, cores
from pipeline.config.typed_run import Run
from pipeline.config.validation import ConfigError
from pipeline.episode.loop import Episode
from pipeline.episode.progress import EpisodeProgress
from pipeline.episode.settings import EpisodeSettings
from pipeline.metrics.image import LpipsMetric
from pipeline.records.images import save_step_images
from pipeline.records.lock import RunLock
from pipeline.records.schema import RunStart, as_json
from pipeline.records.store import RunRecord, run_dir
from pipeline.records.verify import verified
from pipeline.scenes.blender import BlenderTimeout, blender_python
from pipeline.scenes.ground_truth import built_differently, ground_truth_info, renderer_problem
from pipeline.scenes.loading import load_scene
from pipeline.scenes.scene import Scene


class StepFailed(Failed, RuntimeError):
    """The run failed (now, or when it last ran; its record holds this one-line reason), or stopped for a
    reason outside its settings and is left unfinished, to resume (a Blender worker that did not answer)."""


class RunRefused(BadInput, ValueError):
    """The run cannot start: its directory holds a record of another run (other settings)."""


@dataclass(frozen=True)
class Outcome:
    """What ``run_episode`` did: ``done`` (ran to its horizon; ``scene`` is the scene it observed, of
    ``scene_kind``) or ``skipped`` (had finished before)."""

    directory: Path
    status: str
    scene: Scene | None = None
    scene_kind: str = "object"


def torch_threads() -> int:
    """Threads per job: ``OMP_NUM_THREADS`` where it is set (1 to the cores this process may run on; to share
    the cores with other processes, e.g. two sweeps side by side), else those cores divided among the launcher's
    parallel jobs: jobs that together ask for more threads than cores slow each other several-fold
    (docs/USAGE.md)."""
    asked = os.environ.get("OMP_NUM_THREADS", "").strip()
    usable = cores()
    if asked:
        if not asked.isdigit() or not 1 <= int(asked) <= usable:
            raise ConfigError(
                f"OMP_NUM_THREADS={asked!r} must be a whole number 1..{usable} (the cores this process may run on), "
                "or unset (cores / jobs)"
            )
        return int(asked)
    jobs = 1
    if HydraConfig.initialized():
        jobs = HydraConfig.get().launcher.get("n_jobs", 1) or 1
    jobs = usable if jobs < 1 else min(jobs, usable)  # joblib's n_jobs=-1 means one job per core
    return max(1, usable // jobs)


def record_dir(run: Run) -> Path:
    return run_dir(Path(run.paths.outputs), *run.names, int(run.seed))


def run_settings(run: Run) -> dict:
    """The run's identity keys and composed config: what makes two records the same run."""
    scene, method, planner, ablation, budget = run.names
    return {
        "scene": scene,
        "method": method,
        "planner": planner,
        "ablation": ablation,
        "budget": budget,
        "seed": int(run.seed),
        "config": run.composed,
    }


def run_info(settings: dict, episode: Episode, lpips_reason: str | None, ground_truth: dict) -> RunStart:
    """What run.json records of the run (``pipeline.records.schema.RunStart``): the run's ``settings``
    (``run_settings``), the scene's source, ``ground_truth`` (backend and asset file:
    ``pipeline.scenes.ground_truth.ground_truth_info``), the resolved collision-free choice, device, threads, why
    LPIPS is missing (if it is) and the record version."""
    s = episode.settings
    return RunStart(
        **settings,
        scene_source=episode.scene.source,
        ground_truth=ground_truth,
        collision_free=s.collision_free,  # M29's candidate sampler, as resolved for the scene
        candidate_filters=episode.scorer is not None or s.planner.random_filters,  # M28, M29
        field=str(s.field.kind),
        device=str(episode.device),
        torch_threads=torch.get_num_threads(),
        lpips_missing_reason=lpips_reason,
    )


def run_episode(run: Run) -> Outcome:
    """Run (or resume) one episode of the validated ``run`` under its run's lock (``pipeline.records.lock``).

    Raises ``ConfigError`` (a renderer that cannot start, a bad thread count), ``RunLocked`` (another process
    writes the run), ``RecordError`` (its record fails a check), ``RunRefused`` (a record of other settings, or
    of the scene built from another file), ``SceneError`` (the scene cannot load): all before the record starts.
    ``StepFailed`` once the run failed (recorded as such) or stopped (``BlenderTimeout``: left unfinished).
    """
    problem = renderer_problem(run.render, blender_python(run.paths.blender_python))
    if problem is not None:
        raise ConfigError(problem)
    threads = torch_threads()
    directory = record_dir(run)
    with RunLock(directory, root=Path(run.paths.outputs)):
        return _run_locked(run, directory, threads)


def _run_locked(run: Run, directory: Path, threads: int) -> Outcome:
    record = RunRecord(directory)
    previous, rows = verified(record)
    status = record.status()
    settings = run_settings(run)
    changed = record.difference(settings) if previous else None
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
    started = previous.get("torch_threads")
    if rows and isinstance(started, int) and started != threads:
        raise RunRefused(
            f"run {directory} was started with {started} torch threads and this process has {threads}; a record's "
            f"numbers depend on the thread count: resume it with OMP_NUM_THREADS={started}, or delete it"
        )
    print(f"run {directory}: building the scene and its ground truth (the step bar follows)", flush=True)
    torch.set_num_threads(threads)
    torch.manual_seed(int(run.seed))
    np.random.seed(int(run.seed) % 2**32)
    scene = load_scene(run.scene, Path(run.paths.assets), blender_python(run.paths.blender_python))
    built = built_differently(previous, scene) if previous else None
    if built is not None:
        raise RunRefused(
            f"run {directory} was made on another build of scene '{scene.name}': {built}; set scene.asset to the "
            "file it was built from (or paths.assets to a folder without the preferred file), or pass "
            "paths.outputs=DIR to record this run elsewhere"
        )
    device = resolve_device(run.device)
    lpips = LpipsMetric()
    try:
        episode = Episode(EpisodeSettings.of(run, scene), scene, device, lpips)
        try:
            _run_steps(settings, Path(run.paths.assets), directory, record, episode, lpips)
        finally:
            episode.close()
    except BlenderTimeout as err:
        raise StepFailed(
            f"run {directory} stopped at step {len(record.completed_steps())}: {err}; every finished step is "
            "recorded: run the same command again to resume"
        ) from None
    return Outcome(directory, "done", scene, run.scene.kind)


def _run_steps(
    settings: dict, assets: Path, directory: Path, record: RunRecord, episode: Episode, lpips: LpipsMetric
) -> None:
    """Record and run the steps of ``episode`` not yet in ``record`` (``settings``: ``run_settings``)."""
    done_rows = record.completed_steps()
    ground_truth = ground_truth_info(episode.scene, episode.renderer, assets)
    record.start(as_json(run_info(settings, episode, lpips.missing, ground_truth)))
    try:
        episode.replay(done_rows)
        if done_rows:
            print(f"resuming {directory} at step {len(done_rows)} of {episode.settings.budget.horizon}")
        _record_steps(directory, episode, record, len(done_rows))
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


def _record_steps(directory: Path, episode: Episode, record: RunRecord, first: int) -> None:
    """Steps ``first`` .. horizon - 1, each row (and the step's images) written once the step is complete."""
    s = episode.settings
    label = f"{episode.scene.name}/{s.method.name} {s.budget.name} seed {s.seed}"
    whole_views = isinstance(episode.scorer, StepScorer)  # its score map: the candidates from above
    unit = episode.method.score_unit + (", candidates from above" if whole_views else "")
    with EpisodeProgress(label, first, s.budget.horizon, s.stages) as progress:
        for step in range(first, s.budget.horizon):
            start = time.perf_counter()
            row, images = episode.step(step, progress.train)
            if s.save_images:
                save_step_images(directory / "images", step, images, unit)
            record.append_step(as_json(row))
            episode.observe_pose(row.selected_pose)
            psnr = math.nan if row.metrics.psnr is None else row.metrics.psnr
            progress.step_done(step, row.n_views, psnr, time.perf_counter() - start)
