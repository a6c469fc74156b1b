"""nvf-bench harness: Hydra entry points, scenes, ground-truth rendering, episodes, metrics, records, tables."""
