"""Experiments beside the benchmark's episodes: commands that measure the methods on the committed records'
states rather than run whole episodes (``pipeline.experiments.duel``: paired one-step decisions between two
methods)."""
