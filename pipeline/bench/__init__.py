"""Performance benchmarks: ``python -m pipeline.bench NAME [args]`` runs ``pipeline.bench.NAME.main(args)``."""
