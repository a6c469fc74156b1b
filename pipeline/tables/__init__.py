"""Run records -> tables and figures (``python -m pipeline.tables``): load, aggregate, render, compare with
the paper, figures, one run's summary."""
