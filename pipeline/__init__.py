"""nvf-bench harness: Hydra entry points, scenes, ground-truth rendering, episodes, metrics, records, tables.

Every process that imports the harness keeps large freed blocks for reuse (``pipeline.allocator``)."""

from pipeline.allocator import keep_freed_memory

keep_freed_memory()
