"""The benchmarks' JSON reports: written atomically, so a killed benchmark leaves the old one, by default
into the user's own results folder (``${paths.results}/bench/<name>.json``); the repository's committed
reports are rewritten only with ``paths.results=results`` (or ``--out``)."""

import json
from pathlib import Path


def report_path(out: Path | None, results: str | Path, name: str) -> Path:
    """``out`` (``--out``) if given, else ``<results>/bench/<name>.json`` (``results``: ``paths.results``)."""
    return Path(out) if out is not None else Path(results) / "bench" / f"{name}.json"


def write_report(report: dict, path: Path) -> None:
    """Write ``report`` as JSON to ``path`` atomically (parent directories created)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(report, indent=2) + "\n")
    tmp.replace(path)
