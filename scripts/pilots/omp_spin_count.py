"""A 2-step cpu episode (two torch threads) alone and beside one busy process, with the project's passive wait
policy and ``GOMP_SPINCOUNT`` set to each count given (libgomp spins that many times before it sleeps; the count
overrides the policy's own, 0 for passive). Appends a line per run to ``results/pilots/omp_spin_count/runs.jsonl``.

    python scripts/pilots/omp_spin_count.py 300000 20000
"""

import json
import os
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))  # this checkout's packages

from pipeline.bench.contention import timed_run, with_defaults  # noqa: E402

overrides = with_defaults([])
base = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")}
base["OMP_NUM_THREADS"] = "2"
with tempfile.TemporaryDirectory() as tmp:
    for spin in sys.argv[1:]:
        for beside in (False, True):
            found = timed_run(overrides, Path(tmp) / f"{spin}{beside}", base | {"GOMP_SPINCOUNT": spin}, beside)
            print(spin, "beside" if beside else "alone", round(found["seconds_per_step"], 2), flush=True)
            with open(REPO / "results" / "pilots" / "omp_spin_count" / "runs.jsonl", "a") as out:
                out.write(json.dumps({"spin": spin, "beside": beside, **found}) + "\n")
