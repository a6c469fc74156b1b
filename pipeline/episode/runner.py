"""Run (or resume) one episode into its run record: validate the config, derive the run directory from the
run's keys, skip a finished run (refusing one that finished with other settings), resume an unfinished
one at its first missing step, and record every step atomically; a step that cannot complete marks
the run failed with a one-line reason.
"""

import os
import sys
import time
from pathlib import Path

import numpy as np
import torch
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf
from tqdm import tqdm

from nvf.planning import NoCandidatesError
from nvf.training import TrainingDiverged
from pipeline.config.validation import validate
from pipeline.episode.images import save_step_images
from pipeline.episode.loop import Episode
from pipeline.episode.settings import resolve_device
from pipeline.metrics.image import LpipsMetric
from pipeline.records.store import RunRecord, run_dir
from pipeline.scenes.scene import load_scene


class StepFailed(RuntimeError):
    """A step could not complete; the run is recorded as failed with this one-line reason."""


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


def run_info(cfg: DictConfig, scene_source: str, device: torch.device, lpips_reason: str | None) -> dict:
    return {
        **run_settings(cfg),
        "scene_source": scene_source,
        "field": cfg.field.kind,
        "device": str(device),
        "torch_threads": torch.get_num_threads(),
        "lpips_missing_reason": lpips_reason,
    }


def run_episode(cfg: DictConfig) -> Path:
    """Run (or resume) one episode; returns its run directory."""
    validate(cfg)
    directory = record_dir(cfg)
    record = RunRecord(directory)
    if record.is_done():
        changed = record.difference(run_settings(cfg))
        if changed is not None:
            raise ValueError(
                f"run {directory} finished with a different {changed}; "
                "pass paths.outputs=DIR to record this run elsewhere, or delete that run to replace it"
            )
        print(f"skipping finished run {directory}")
        return directory
    torch.set_num_threads(torch_threads())
    torch.manual_seed(int(cfg.seed))
    np.random.seed(int(cfg.seed) % 2**32)
    scene = load_scene(cfg.scene, Path(cfg.paths.assets))
    device = resolve_device(cfg.device)
    lpips = LpipsMetric()
    episode = Episode(cfg, scene, device, lpips)
    done_rows = record.completed_steps()
    record.start(run_info(cfg, scene.source, device, lpips.missing))
    episode.replay(done_rows)
    horizon = int(cfg.budget.horizon)
    if done_rows:
        print(f"resuming {directory} at step {len(done_rows)} of {horizon}")
    interactive = sys.stderr.isatty()
    steps = tqdm(range(len(done_rows), horizon), desc="steps", unit="step", disable=not interactive, initial=len(done_rows), total=horizon)
    inner = tqdm(desc="train", unit="it", leave=False, disable=not interactive)

    def on_train(stage: str, iteration: int, total: int, loss: float) -> None:
        if iteration == 0:
            inner.reset(total=total)
            inner.set_description(stage)
        inner.update(1)
        if iteration % 25 == 0:
            inner.set_postfix(loss=f"{loss:.4g}")

    for step in steps:
        start = time.perf_counter()
        try:
            row, images = episode.step(step, on_train)
        except (TrainingDiverged, NoCandidatesError, FloatingPointError) as err:
            reason = f"step {step}: {err}"
            record.mark_failed(reason)
            raise StepFailed(reason) from None
        if cfg.save_images:
            save_step_images(directory / "images", step, images)
        record.append_step(row)
        episode.observe_pose(row["selected_pose"])
        psnr = row["metrics"]["psnr"]
        message = f"step {step:2d}: {row['n_views']} views, PSNR {psnr:.2f} dB, {time.perf_counter() - start:.1f} s"
        steps.set_postfix_str(message.split(": ", 1)[1])
        if not interactive:
            print(f"[{cfg.scene.name}/{cfg.method.name}] {message}", flush=True)
    inner.close()
    steps.close()
    record.mark_done()
    return directory
