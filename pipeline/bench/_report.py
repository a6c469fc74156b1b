"""The benchmarks' JSON reports: the path checked before any work (``report_path``), the report written
atomically (``write_report``), so a killed benchmark leaves the old one, by default into the user's own results
folder (``${paths.results}/bench/<name>.json``); the repository's committed reports are rewritten only with
``paths.results=results`` (or ``--out``)."""

import json
import os
import stat
from pathlib import Path

from pipeline.atomic_write import atomic_write_text
from pipeline.cli import fail


def _writable_folder(path: Path) -> Path | None:
    """The nearest existing folder at or above ``path`` if it is a writable folder (not a link), else None."""
    for folder in (path, *path.parents):
        if os.path.lexists(folder):
            ok = stat.S_ISDIR(os.lstat(folder).st_mode) and os.access(folder, os.W_OK)
            return folder if ok else None
    return None


def report_path(out: Path | None, results: str | Path, name: str) -> Path:
    """``out`` (``--out``) if given, else ``<results>/bench/<name>.json`` (``results``: ``paths.results``), checked
    before the benchmark runs: a plain file (or none yet) whose folder exists (``--out``) or can be made (the
    default) and is writable; never a link, a device, a FIFO or a folder. Anything else is one ``error:`` line."""
    if out is not None and str(out).strip() in ("", "."):
        fail("--out: name a file for the JSON report, e.g. --out /tmp/report.json")
    path = Path(out) if out is not None else Path(results) / "bench" / f"{name}.json"
    where = "--out" if out is not None else f"the report {name}.json"
    if os.path.lexists(path) and not stat.S_ISREG(os.lstat(path).st_mode):
        fail(f"{where} {path}: not a plain file (a link, device, FIFO or folder); name a file to write")
    if out is not None and not (os.path.lexists(path.parent) and stat.S_ISDIR(os.lstat(path.parent).st_mode)):
        fail(f"--out {path}: its folder {path.parent} does not exist; make it or name a file in an existing one")
    if _writable_folder(path.parent) is None:
        fail(f"{where} {path}: its folder is not writable; name a file in a writable folder")
    return path


def write_report(report: dict, path: Path) -> None:
    """Write ``report`` as JSON to ``path`` atomically (``pipeline.atomic_write``; parent folders created; ``path``
    still a plain file or none, as ``report_path`` checked)."""
    if os.path.lexists(path) and not stat.S_ISREG(os.lstat(path).st_mode):
        fail(f"the report {path}: not a plain file any more (a link, device, FIFO or folder); nothing written")
    atomic_write_text(path, json.dumps(report, indent=2) + "\n")
