"""The benchmarks' JSON reports: written atomically, so a killed benchmark leaves the old one."""

import json
from pathlib import Path


def write_report(report: dict, path: Path) -> None:
    """Write ``report`` as JSON to ``path`` atomically (parent directories created)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(report, indent=2) + "\n")
    tmp.replace(path)
