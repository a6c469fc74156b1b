"""What one training stage records while it runs (METHOD.md section 10): its loss history, the divergence check,
its optimiser steps (with loss scaling for float16), timing, progress and summary."""

import math
import time
from collections.abc import Callable

import torch
from jaxtyping import Float
from torch import Tensor

from nvf.rendering import Samples

Progress = Callable[[str, int, int, float], None]  # (stage, iteration, total, loss), once per iteration
COLLAPSE_WINDOW = 5  # iterations averaged by the collapse rule (StageRecorder)
COLLAPSE_FACTOR = 4.0  # ... and the rise over the lowest earlier average that counts as a collapse
COLLAPSE_STAGES = frozenset({"backbone", "visibility"})  # non-negative losses (M20, M19)


class TrainingDiverged(RuntimeError):
    """A training loss became NaN or infinite, or collapsed (``StageRecorder``); the message names the stage,
    the iteration and the numbers."""


class StageRecorder:
    """Loss history, divergence check, timing and progress of one stage.

    Divergence: a non-finite loss (any stage, ``check``), or a collapse (``end_iteration``) of a stage
    whose loss cannot be negative (``COLLAPSE_STAGES``: M20's squared error, M19's BCE): at a full
    window, the mean of the last ``COLLAPSE_WINDOW`` iteration losses exceeds both ``COLLAPSE_FACTOR``
    times the lowest such mean before it (over the first ``i + 1`` losses while ``i < COLLAPSE_WINDOW``)
    and the loss of the first iteration (the untrained model: training made it worse).
    The factor sits between what a diverging learning rate does to stage 1's loss and what normal training
    reaches (docs/DEVIATIONS.md, "training divergence", gives both). Variance NLL (M21, bounded above by its
    floor; it can be negative) and the auxiliary losses (M25 can be negative) are checked for non-finite
    values only.

    ``precision="fp16"`` scales the loss (``torch.amp.GradScaler``): float16 gradients of the MLPs
    would otherwise underflow. A step whose gradients overflow is skipped and the scale halved
    (``skipped_steps``); a scale below 1, gradients that overflow float16 unscaled, is divergence.
    """

    def __init__(self, stage: str, total: int, progress: Progress | None, precision: str = "fp32", device: str = "cpu"):
        self.stage, self.total, self.progress = stage, total, progress
        self.scaler = torch.amp.GradScaler(device) if precision == "fp16" else None
        self.losses: list[float] = []
        self.lowest_mean: float | None = None
        self.steps = self.skipped = 0
        self.samples = self.rays = self.batches = 0
        self.start = time.perf_counter()

    def count(self, samples: Samples) -> None:
        """Add one rendered batch to the stage's kept samples per ray."""
        self.samples += samples.num_samples
        self.rays += samples.n_rays
        self.batches += 1

    def check(self, loss: Float[Tensor, ""], iteration: int) -> float:
        value = float(loss.detach())
        if not math.isfinite(value):
            raise TrainingDiverged(f"{self.stage} stage diverged at iteration {iteration}: loss = {value}")
        return value

    def step(self, optimizer: torch.optim.Optimizer, loss: Float[Tensor, ""]) -> None:
        """Adam step on ``loss`` (skipped if nothing requires grad, e.g. a batch with no samples)."""
        optimizer.zero_grad(set_to_none=True)
        if not loss.requires_grad:
            return
        if self.scaler is None:
            loss.backward()
            optimizer.step()
            self.steps += 1
            return
        scale = self.scaler.get_scale()
        self.scaler.scale(loss).backward()
        self.scaler.step(optimizer)
        self.scaler.update()
        if self.scaler.get_scale() < scale:
            self.skipped += 1
        else:
            self.steps += 1
        if self.scaler.get_scale() < 1.0:
            raise TrainingDiverged(
                f"{self.stage} stage diverged after {self.steps + self.skipped} steps: float16 gradients "
                f"overflow at loss scale {self.scaler.get_scale()}"
            )

    def end_iteration(self, iteration: int, loss: float) -> None:
        self.losses.append(loss)
        if self.progress is not None:
            self.progress(self.stage, iteration, self.total, loss)
        if self.stage in COLLAPSE_STAGES:
            self._check_collapse(iteration)

    def _check_collapse(self, iteration: int) -> None:
        """The collapse rule of the class docstring."""
        window = self.losses[-COLLAPSE_WINDOW:]
        mean = sum(window) / len(window)
        lowest = self.lowest_mean
        full = len(window) == COLLAPSE_WINDOW and lowest is not None and lowest > 0
        if full and lowest is not None and mean > COLLAPSE_FACTOR * lowest and mean > self.losses[0]:
            raise TrainingDiverged(
                f"{self.stage} stage collapsed at iteration {iteration}: mean loss {mean:.4g} over the last "
                f"{COLLAPSE_WINDOW} iterations, {mean / lowest:.3g} times its lowest earlier mean {lowest:.4g} and "
                f"above the first iteration's {self.losses[0]:.4g} (limit {COLLAPSE_FACTOR:g}x; a learning rate too "
                "high?)"
            )
        self.lowest_mean = mean if lowest is None else min(lowest, mean)

    def summary(self) -> dict[str, float]:
        """Iterations, optimiser steps, first/last loss, seconds, and for stages that render rays
        ``samples_per_ray`` (the kept samples after alpha skipping, the stage's main cost) and
        ``rays_per_batch`` (mean; it varies with the reference's dynamic batch)."""
        nan = float("nan")
        summary = {
            "iters": float(len(self.losses)),
            "steps": float(self.steps),
            "first_loss": self.losses[0] if self.losses else nan,
            "last_loss": self.losses[-1] if self.losses else nan,
            "seconds": time.perf_counter() - self.start,
        }
        if self.scaler is not None:
            summary["skipped_steps"] = float(self.skipped)
        if self.rays:
            summary["samples_per_ray"] = self.samples / self.rays
            summary["rays_per_batch"] = self.rays / self.batches
        return summary
