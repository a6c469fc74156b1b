"""Side-by-side timing for the benchmarks' ratios (bf16 over fp32, ...): the alternatives take turns on
the machine, so that drifts of its load (other jobs on shared cores) fall on all of them alike.

- ``lockstep``: long jobs with a per-iteration callback (training) run one at a time, handing over
  after every iteration, each in its own thread (a single job runs on the calling thread, as an episode
  trains); ``IterationClock`` counts a job's own turns only.
- ``ratio_spread``: the median, min and max of paired ratios (one per turn window or repeat).
"""

import statistics
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import TypeVar

import torch
from tqdm import tqdm

T = TypeVar("T")
Turn = Callable[[], None]


def lockstep(jobs: dict[str, Callable[[Turn], T]]) -> dict[str, T]:
    """Run the jobs side by side, one at a time, in the order given, each called with a ``turn`` callable:
    a job calls ``turn()`` at the end of every iteration, which hands over to the next unfinished job
    (round robin) and returns when it is this job's turn again. Returns each job's result; re-raises the
    first error. A single job runs on the calling thread, with a ``turn`` that returns at once."""
    if len(jobs) == 1:
        ((name, job),) = jobs.items()
        return {name: job(lambda: None)}
    names = list(jobs)
    cond = threading.Condition()
    current = [0]
    live = set(range(len(names)))
    results: dict[str, T] = {}
    errors: list[BaseException] = []

    def hand_over(index: int) -> None:  # with cond held
        following = [(index + step) % len(names) for step in range(1, len(names) + 1)]
        current[0] = next((j for j in following if j in live), index)
        cond.notify_all()

    def run(index: int) -> None:
        def turn() -> None:
            with cond:
                hand_over(index)
                cond.wait_for(lambda: current[0] == index)

        with cond:
            cond.wait_for(lambda: current[0] == index)
        try:
            results[names[index]] = jobs[names[index]](turn)
        except BaseException as error:  # noqa: BLE001 - re-raised in the caller's thread
            errors.append(error)
        finally:
            with cond:
                live.discard(index)
                hand_over(index)

    threads = [threading.Thread(target=run, args=(i,), daemon=True) for i in range(len(names))]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    if errors:
        raise errors[0]
    return results


class IterationClock:
    """Training progress callback: a job's own wall and CPU seconds, its model's kept samples and the
    stage after each iteration. ``turn`` (from ``lockstep``) is called after the reading, and the time until it
    returns (other jobs' turns) is not counted. ``counter()`` gives the cumulative samples (kept, marched)."""

    def __init__(self, counter: Callable[[], tuple[int, int]], total: int, desc: str, turn: Turn | None = None):
        self.counter, self.turn = counter, turn
        self.wall: list[float] = []
        self.cpu: list[float] = []
        self.samples: list[int] = []
        self.marched: list[int] = []
        self.stages: list[str] = []
        self._elapsed = [0.0, 0.0]
        self._resumed = (time.perf_counter(), time.process_time())
        self.bar = tqdm(total=total, desc=desc, unit="it", leave=False, disable=not sys.stderr.isatty())

    def __call__(self, stage: str, iteration: int, total: int, loss: float) -> None:
        self._elapsed[0] += time.perf_counter() - self._resumed[0]
        self._elapsed[1] += time.process_time() - self._resumed[1]
        kept, marched = self.counter()
        self.wall.append(self._elapsed[0])
        self.cpu.append(self._elapsed[1])
        self.samples.append(kept)
        self.marched.append(marched)
        self.stages.append(stage)
        self.bar.update(1)
        if self.turn is not None:
            self.turn()
        self._resumed = (time.perf_counter(), time.process_time())

    def rates(self, first: int, last: int | None = None) -> dict[str, float]:
        """Kept samples/s over iterations ``first..last`` (wall, and CPU per thread), ms, kept and
        marched samples per iteration (``first >= 1``)."""
        last = len(self.wall) - 1 if last is None else last
        iters = last - first + 1
        samples = self.samples[last] - self.samples[first - 1]
        wall = self.wall[last] - self.wall[first - 1]
        cpu = (self.cpu[last] - self.cpu[first - 1]) / torch.get_num_threads()
        return {
            "train_samples_per_s": samples / wall,
            "train_samples_per_s_cpu": samples / cpu,
            "train_ms_per_iter": 1e3 * wall / iters,
            "train_samples_per_iter": samples / iters,
            "train_marched_per_iter": (self.marched[last] - self.marched[first - 1]) / iters,
        }

    def stage_seconds(self) -> dict[str, float]:
        """Own wall seconds per training stage (an iteration's time goes to the stage that reported it)."""
        out: dict[str, float] = {}
        for i, stage in enumerate(self.stages):
            out[stage] = out.get(stage, 0.0) + self.wall[i] - (self.wall[i - 1] if i else 0.0)
        return out

    def windows(self, first: int, count: int) -> list[tuple[int, int]]:
        """``count`` consecutive iteration ranges ``(first, last)`` covering ``first..end`` (fewer if
        there are fewer iterations)."""
        bounds = torch.arange(first, len(self.wall)).tensor_split(count)
        return [(int(b[0]), int(b[-1])) for b in bounds if b.numel() > 0]


def ratio_spread(numerators: Sequence[float], denominators: Sequence[float]) -> dict[str, float]:
    """Paired ratios ``numerators[i] / denominators[i]``: their median, min and max, and the count."""
    ratios = [a / b for a, b in zip(numerators, denominators, strict=True)]
    return {"median": statistics.median(ratios), "min": min(ratios), "max": max(ratios), "n": len(ratios)}
