"""``python -m pipeline.bench episode [--out PATH] [--outputs DIR] [overrides]``: wall time of one
default episode (``python -m pipeline.run``'s configuration unless overridden) and its per-phase
seconds.

Writes ``results/bench/episode.json`` (or ``--out``) with ``episode_seconds``, the summed train /
eval / plan seconds of its steps, and per step the seconds of each training stage and its kept
samples per ray. The run goes to a fresh temporary outputs directory unless ``--outputs`` names
one to keep (an existing finished run there is resumed, not re-timed, so use an empty one).
"""

import json
import tempfile
import time
from pathlib import Path

import torch

from pipeline.bench._report import report_path, write_report
from pipeline.cli import ArgumentParser, description
from pipeline.config.validation import compose_run
from pipeline.episode.runner import run_episode
from pipeline.records.store import RunRecord


def step_summary(row: dict) -> dict:
    """One step's views, phase seconds, and each training stage's seconds and samples per ray."""
    summary = {"step": row["step"], "n_views": row["n_views"], **{k: round(v, 2) for k, v in row["seconds"].items()}}
    for stage, stats in row.get("train", {}).items():
        summary[f"{stage}_seconds"] = round(stats["seconds"], 2)
        if "samples_per_ray" in stats:
            summary[f"{stage}_samples_per_ray"] = round(stats["samples_per_ray"], 2)
    return summary


def main(argv: list[str]) -> None:
    parser = ArgumentParser(prog="python -m pipeline.bench episode", description=description(__doc__))
    parser.add_argument("overrides", nargs="*", help="Hydra overrides, e.g. method=random")
    parser.add_argument(
        "--out", type=Path, default=None, help="JSON report path (default: ${paths.results}/bench/episode.json)"
    )
    parser.add_argument(
        "--outputs", type=Path, default=None, help="keep the run records here (default: a temporary directory)"
    )
    args = parser.parse_intermixed_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        out = report_path(args.out, compose_run(args.overrides).paths.results, "episode")
        outputs = args.outputs.resolve() if args.outputs else Path(tmp)
        cfg = compose_run([*args.overrides, f"paths.outputs={outputs}"])
        start = time.perf_counter()
        directory = run_episode(cfg).directory
        seconds = time.perf_counter() - start
        rows = RunRecord(directory).completed_steps()
    phases = {phase: sum(r["seconds"][phase] for r in rows) for phase in ("train", "eval", "plan")}
    report = {
        "episode_seconds": seconds,
        "steps": len(rows),
        "seconds_per_step": seconds / max(1, len(rows)),
        **{f"{phase}_seconds": value for phase, value in phases.items()},
        "final_psnr": rows[-1]["metrics"]["psnr"] if rows else None,
        "scene": cfg.scene.name,
        "method": cfg.method.name,
        "budget": cfg.budget.name,
        "field": cfg.field.kind,
        "torch_threads": torch.get_num_threads(),
        "overrides": args.overrides,
        "per_step": [step_summary(r) for r in rows],
    }
    write_report(report, out)
    print(json.dumps({k: v for k, v in report.items() if k != "per_step"}, indent=2))
