"""``python -m pipeline.bench episode [overrides]``: wall time of one default episode
(``python -m pipeline.run``'s configuration unless overridden) and its per-phase seconds.

Writes ``results/bench/episode.json`` with ``episode_seconds`` and the summed train / eval / plan
seconds of its steps. The run goes to a temporary outputs directory, so nothing is resumed.
"""

import json
import tempfile
import time

import torch
from hydra import compose, initialize_config_dir

from pipeline.records import RunRecord
from pipeline.run import REPO, run_episode


def main(argv: list[str]) -> None:
    with tempfile.TemporaryDirectory() as tmp, initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose("config", overrides=[*argv, f"paths.outputs={tmp}"])
        start = time.perf_counter()
        directory = run_episode(cfg)
        seconds = time.perf_counter() - start
        rows = RunRecord(directory).completed_steps()
    phases = {phase: sum(r["seconds"][phase] for r in rows) for phase in ("train", "eval", "plan")}
    report = {
        "episode_seconds": seconds,
        "steps": len(rows),
        "seconds_per_step": seconds / max(1, len(rows)),
        **{f"{phase}_seconds": value for phase, value in phases.items()},
        "final_psnr": rows[-1]["metrics"]["psnr"] if rows else None,
        "scene": cfg.scene.name, "method": cfg.method.name, "budget": cfg.budget.name, "field": cfg.field.kind,
        "torch_threads": torch.get_num_threads(), "overrides": argv,
    }  # fmt: skip
    out = REPO / "results" / "bench" / "episode.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=2) + "\n")
    print(json.dumps(report, indent=2))
