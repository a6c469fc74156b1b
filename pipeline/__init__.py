"""nvf-bench harness: Hydra entry points, scenes, ground-truth rendering, episodes, metrics, records, tables.

Importing it sets OpenMP's wait policy to passive for this process and its children (``OMP_WAIT_POLICY``, read
when torch loads OpenMP, so before any torch import; a value the user set wins): an idle OpenMP thread sleeps
instead of spinning, so a job beside other busy processes does not burn their cores (docs/ARCHITECTURE.md,
"Devices"; ``python -m pipeline.bench contention`` measures it). Thread counts are never chosen from the
load: a record's numbers depend on its thread count."""

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
