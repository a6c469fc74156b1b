"""Diagnostics that a benchmark and an experiment both run: measurements on a model trained apart from an
episode (``initial_view_model``), such as how the visibility sources separate seen from unseen surface
(``visibility_report``)."""
