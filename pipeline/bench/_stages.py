"""Stages of a benchmark timed one after another in one process, each with its own peak memory.

Peak resident memory per stage (Linux): before a stage the garbage collector runs, glibc returns its free
heap to the system (``malloc_trim``), and the kernel's high-water mark of the process's resident set
(``VmHWM``) is reset to its current size (writing ``5`` to ``/proc/self/clear_refs``); after the stage
``VmHWM`` is that stage's peak, the state the process already held included. The same is done for the
process's child processes (the Blender worker). Where the reset is not possible the peak is not reported
(``None``, with the reason in ``StageMeter.missing``). On CUDA the stage also reports the device's peak
allocated memory (``torch.cuda.max_memory_allocated`` after ``reset_peak_memory_stats``), and every stage
ends with ``torch.cuda.synchronize`` so that its seconds hold its kernels.
"""

import contextlib
import ctypes
import gc
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import torch

GIB = float(1 << 30)
PEAK_RSS = (
    "per stage: gc and malloc_trim, then VmHWM reset through /proc/<pid>/clear_refs (this process and its "
    "children) before the stage and read after it"
)


def _status_kib(pid: int | str, key: str) -> int | None:
    """``key`` (``VmRSS``, ``VmHWM``) of ``/proc/<pid>/status`` in KiB, or None (no such process or field)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(f"{key}:"):
                return int(line.split()[1])
    except OSError:
        return None
    return None


def _children() -> list[str]:
    """Process ids of this process's live children (``/proc/self/task/*/children``)."""
    pids: list[str] = []
    for task in Path("/proc/self/task").glob("*"):
        with contextlib.suppress(OSError):
            pids += (task / "children").read_text().split()
    return pids


def _reset_peak(pid: int | str) -> bool:
    """Reset ``pid``'s ``VmHWM`` to its current resident size; False where the kernel refuses."""
    try:
        Path(f"/proc/{pid}/clear_refs").write_text("5")
    except OSError:
        return False
    return True


def _release_free_heap() -> None:
    """Collect garbage and hand glibc's free heap back to the system, so a stage's peak is its own."""
    gc.collect()
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6").malloc_trim(0)


@dataclass
class Stage:
    """One stage's measurements: ``count`` units of work (``unit``) in ``seconds``; resident memory at its
    start and its peak (GiB, this process; ``worker_peak_rss_gib``: its child processes together), and on
    CUDA the device's peak allocated memory."""

    name: str
    unit: str
    count: int
    seconds: float = 0.0
    process_seconds: float = 0.0  # this process's CPU time over its threads (not its children's)
    rss_before_gib: float | None = None
    peak_rss_gib: float | None = None
    worker_peak_rss_gib: float | None = None
    peak_device_gib: float | None = None
    samples_per_ray: float | None = None  # kept samples per rendered ray, where the stage counts them

    @property
    def seconds_per_unit(self) -> float:
        return self.seconds / max(1, self.count)


class StageMeter:
    """Measures stages (``stage``) on ``device``; ``stages`` in the order they ran, each passed to ``done``
    as it ends."""

    def __init__(self, device: torch.device, done: Callable[[Stage], None] = lambda stage: None):
        self.device, self.done = device, done
        self.stages: list[Stage] = []
        self.missing: str | None = None

    @contextlib.contextmanager
    def stage(self, name: str, unit: str, count: int) -> Iterator[Stage]:
        """Measure the body as stage ``name``; the body may correct ``count`` on the yielded ``Stage``."""
        record = Stage(name, unit, count)
        cuda = self.device.type == "cuda"
        if cuda:
            torch.cuda.synchronize(self.device)
            torch.cuda.reset_peak_memory_stats(self.device)
        _release_free_heap()
        children = _children()
        reset = _reset_peak("self") and all(_reset_peak(pid) for pid in children)
        if not reset:
            self.missing = "the kernel refused to reset the resident high-water mark (/proc/<pid>/clear_refs)"
        before = _status_kib("self", "VmRSS")
        start, start_cpu = time.perf_counter(), time.process_time()
        yield record
        if cuda:
            torch.cuda.synchronize(self.device)
            record.peak_device_gib = torch.cuda.max_memory_allocated(self.device) / GIB
        record.seconds = time.perf_counter() - start
        record.process_seconds = (time.process_time() - start_cpu) / torch.get_num_threads()
        peak = _status_kib("self", "VmHWM")
        if reset and peak is not None and before is not None:
            record.rss_before_gib, record.peak_rss_gib = before * 1024 / GIB, peak * 1024 / GIB
            workers = [_status_kib(pid, "VmHWM") for pid in set(children) | set(_children())]
            record.worker_peak_rss_gib = sum(kib for kib in workers if kib is not None) * 1024 / GIB
        self.stages.append(record)
        self.done(record)
