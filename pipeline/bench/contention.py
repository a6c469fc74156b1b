"""``python -m pipeline.bench contention [--out PATH] [--repeats N] [--threads T] [overrides]``: how an episode
shares the cores. One short episode (``budget=cpu budget.horizon=2`` on the default scene unless overridden) runs
in a child process (``python -m pipeline.run``, its records in a temporary folder) alone and then beside one busy
single-thread process (``python3 -c "while True: pass"``), alternating, with OpenMP's wait policy as the project
sets it (passive: ``pipeline/__init__.py``) and, as the comparison, with ``OMP_WAIT_POLICY=ACTIVE`` (idle threads
spin). Each run has ``--threads`` torch threads (``OMP_NUM_THREADS``; default: every core this process may run on,
as one job gets) and its seconds per step are its record's (the steps' train, eval and plan seconds).

Reports per policy the seconds per step alone and beside the busy process and their paired ratio (beside over
alone, per repeat), each as median, min and max over ``--repeats`` (1 to 20; default 3); the project's target
is a median ratio of at most 2.5. Writes ``${paths.results}/bench/contention.json`` (or ``--out``). The
measurement needs an otherwise idle machine: other load changes both sides of every ratio.
"""

import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from pipeline.bench._paired import ratio_spread
from pipeline.bench._report import report_path, write_report
from pipeline.cli import ArgumentParser, Failed, bounded, cores, description
from pipeline.config.validation import compose_run
from pipeline.records.store import RunRecord, run_dir
from pipeline.repo import REPO

DEFAULTS = ("budget=cpu", "budget.horizon=2")  # each unless an override names its key
MAX_REPEATS = 20
POLICIES = {"project": None, "active": "ACTIVE"}  # OMP_WAIT_POLICY: None leaves it to pipeline/__init__.py
BUSY = "while True: pass"
TARGET_RATIO = 2.5  # beside one busy process, over alone (a fair share of two cores would be about 1.5)


def with_defaults(overrides: list[str]) -> list[str]:
    """``DEFAULTS`` whose key no override names, then the overrides."""
    named = {o.split("=", 1)[0].lstrip("+~") for o in overrides}
    return [*(d for d in DEFAULTS if d.split("=", 1)[0] not in named), *overrides]


def child_env(policy: str | None, threads: int) -> dict[str, str]:
    """This process's environment with ``threads`` OpenMP threads and the wait policy ``policy`` (None: unset,
    so the child's ``pipeline`` sets the project's)."""
    env = {key: value for key, value in os.environ.items() if key != "OMP_WAIT_POLICY"}
    env["OMP_NUM_THREADS"] = str(threads)
    return env | ({"OMP_WAIT_POLICY": policy} if policy is not None else {})


def timed_run(overrides: list[str], outputs: Path, env: dict[str, str], beside: bool) -> dict:
    """One episode in a child process (beside a busy process when ``beside``): its wall seconds, steps and
    seconds per step (its record's); ``Failed`` naming the run when it fails."""
    command = [sys.executable, "-m", "pipeline.run", *overrides, f"paths.outputs={outputs}"]
    command.append(f"paths.results={outputs / 'results'}")
    busy = subprocess.Popen([sys.executable, "-c", BUSY]) if beside else None
    try:
        start = time.perf_counter()
        done = subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True, check=False)
        wall = time.perf_counter() - start
    finally:
        if busy is not None:
            busy.kill()
            busy.wait()
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["no message"])[-1]
        raise Failed(f"the episode {' '.join(overrides)} failed (exit {done.returncode}): {last}")
    cfg = compose_run([*overrides, f"paths.outputs={outputs}"])
    rows = RunRecord(run_dir(outputs, *cfg.names, int(cfg.seed))).completed_steps()
    per_step = [sum(row["seconds"].values()) for row in rows]
    return {"wall_seconds": wall, "steps": len(rows), "seconds_per_step": sum(per_step) / max(1, len(rows))}


def spread(values: list[float]) -> dict[str, float]:
    """Median, min and max of ``values``."""
    return {"median": statistics.median(values), "min": min(values), "max": max(values)}


def main(argv: list[str]) -> None:
    parser = ArgumentParser(prog="python -m pipeline.bench contention", description=description(__doc__))
    parser.add_argument("overrides", nargs="*", help="config overrides of the episode, e.g. budget=smoke")
    parser.add_argument(
        "--out", type=Path, default=None, help="JSON report path (default: ${paths.results}/bench/contention.json)"
    )
    parser.add_argument("--repeats", type=int, default=3, help=f"paired runs per policy (1..{MAX_REPEATS})")
    parser.add_argument("--threads", type=int, default=None, help="torch threads per episode (default: the cores)")
    args = parser.parse_intermixed_args(argv)
    bounded("--repeats", args.repeats, 1, MAX_REPEATS)
    threads = bounded("--threads", cores() if args.threads is None else args.threads, 1, cores(), "the cores")
    overrides = with_defaults(args.overrides)
    cfg = compose_run(overrides)  # a bad override is one line now
    out = report_path(args.out, cfg.paths.results, "contention")  # checked before any work
    start, load = time.perf_counter(), {"start": os.getloadavg()}
    runs: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="contention-") as tmp:
        for repeat in range(args.repeats):
            order = list(POLICIES) if repeat % 2 == 0 else list(reversed(POLICIES))
            for policy in order:
                for beside in (False, True):
                    outputs = Path(tmp) / f"run{len(runs)}"
                    found = timed_run(overrides, outputs, child_env(POLICIES[policy], threads), beside)
                    runs.append({"repeat": repeat, "policy": policy, "beside_busy": beside, **found})
                    where = "beside a busy process" if beside else "alone"
                    print(f"contention: {policy} policy, {where}: {found['seconds_per_step']:.2f} s a step", flush=True)
    summary = {}
    for policy in POLICIES:
        alone, busy = (
            [r["seconds_per_step"] for r in runs if r["policy"] == policy and r["beside_busy"] == b]
            for b in (False, True)
        )
        summary[policy] = {"alone": spread(alone), "beside": spread(busy), "ratio": ratio_spread(busy, alone)}
    report = {
        "overrides": overrides,
        "threads": threads,
        "cores": cores(),
        "repeats": args.repeats,
        "policies": {name: value or "PASSIVE (as pipeline/__init__.py sets it)" for name, value in POLICIES.items()},
        "target_ratio": TARGET_RATIO,
        "within_target": summary["project"]["ratio"]["median"] <= TARGET_RATIO,
        "summary": summary,
        "runs": runs,
        "load_average": load | {"end": os.getloadavg()},
        "seconds": time.perf_counter() - start,
    }
    write_report(report, out)
    for policy, found in summary.items():
        ratio = found["ratio"]
        print(
            f"{policy}: {found['alone']['median']:.2f} s a step alone, {found['beside']['median']:.2f} beside; ratio "
            f"{ratio['median']:.2f} [{ratio['min']:.2f}, {ratio['max']:.2f}]"
        )
    print(f"wrote {out}")
