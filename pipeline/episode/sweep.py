"""What a sweep reports (``python -m pipeline.run -m ...``): a Hydra callback (``conf/config.yaml``,
``hydra.callbacks``) that checks ``paths.outputs`` before Hydra writes anything there, has each job
leave ``job_report.json`` in its Hydra job directory (status, reason, overrides), and ends the sweep
with one summary line (done / skipped / failed), one line per failed job and its reason, where each finished
job's run went (its records, pictures and table: ``summary.md``) and the command that tabulates them all, and a
non-zero exit when any job failed.

Reports go through files because a launcher may run each job in another process or on another
machine (joblib, submitit): ``on_job_end`` runs where the job ran, ``on_multirun_end`` where the
sweep started. A job that ended without a report (killed) counts as failed.
"""

import json
import sys
import time
from pathlib import Path
from typing import Any

from hydra.core.utils import JobReturn
from hydra.experimental.callback import Callback
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from pipeline.atomic_write import atomic_write_text
from pipeline.cli import error_line
from pipeline.config.validation import ConfigError, check_paths

JOB_REPORT = "job_report.json"
STATUSES = ("done", "skipped", "failed")
UNREPORTED = "the job ended without a report (killed, or its process died)"


def job_result(job: JobReturn) -> dict[str, Any]:
    """``{"status", "reason"}`` of a finished Hydra job: what ``pipeline.run.main`` returned, or the
    exception it raised (a failure)."""
    try:
        value = job.return_value  # raises the job's exception when it failed
    except Exception as error:
        return {"status": "failed", "reason": f"{type(error).__name__}: {' '.join(str(error).split())}"}
    if isinstance(value, dict) and value.get("status") in STATUSES:
        return {"status": value["status"], "reason": value.get("reason"), "directory": value.get("directory")}
    return {"status": "failed", "reason": f"the job returned {value!r}, not a status"}


def summary(reports: list[dict]) -> list[str]:
    """The sweep's closing lines: counts per status, then each failed job with its overrides and reason."""
    counts = {status: sum(r["status"] == status for r in reports) for status in STATUSES}
    lines = [f"sweep: {len(reports)} jobs: " + ", ".join(f"{count} {status}" for status, count in counts.items())]
    for report in reports:
        if report["status"] == "failed":
            overrides = " ".join(report.get("overrides") or []) or "no overrides"
            lines.append(
                f"failed: job {report.get('num', '?')} ({overrides}): {report.get('reason') or 'no reason given'}"
            )
    return lines


def where(reports: list[dict], outputs: str) -> list[str]:
    """Where each finished job's run went (its records, pictures and one-run table, ``summary.md``) and the command
    that tabulates every run under ``outputs``."""
    lines = [
        f"job {r.get('num', '?')} ({' '.join(r.get('overrides') or []) or 'no overrides'}): {r['directory']}"
        for r in reports
        if r["status"] != "failed" and r.get("directory")
    ]
    return [*lines, f"the tables of them all: python -m pipeline.tables paths.outputs={outputs}"] if lines else []


class SweepReport(Callback):
    """Checks ``paths.outputs`` first; writes and collects the job reports of a multirun."""

    def __init__(self) -> None:
        self.started = time.time()

    def _check_outputs(self, config: DictConfig) -> None:
        try:
            check_paths({"paths.outputs": str(config.paths.outputs)})
        except (ConfigError, OmegaConfBaseException) as err:  # a bad value, or an override that does not resolve
            print(error_line(err), file=sys.stderr)
            sys.exit(2)

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        self._check_outputs(config)

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        self.started = time.time()
        self._check_outputs(config)

    def _write(self, config: DictConfig, report: dict) -> None:
        if config.hydra.mode != RunMode.MULTIRUN:
            return
        overrides = OmegaConf.to_container(config.hydra.overrides.task)
        report = {**report, "num": int(config.hydra.job.num), "overrides": overrides}
        atomic_write_text(Path(config.hydra.runtime.output_dir) / JOB_REPORT, json.dumps(report) + "\n")

    def on_job_start(self, config: DictConfig, **kwargs: Any) -> None:
        self._write(config, {"status": "failed", "reason": UNREPORTED})

    def on_job_end(self, config: DictConfig, job_return: JobReturn, **kwargs: Any) -> None:
        self._write(config, job_result(job_return))

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        reports = []
        for path in Path(str(config.hydra.sweep.dir)).rglob(JOB_REPORT):
            if path.stat().st_mtime >= self.started - 1.0:  # not a report of an earlier sweep in the same directory
                reports.append(json.loads(path.read_text(encoding="utf-8")))
        reports.sort(key=lambda r: r.get("num", -1))
        lines = summary(reports)
        print("\n".join([*where(reports, str(config.paths.outputs)), lines[0]]), flush=True)
        if len(lines) > 1:
            print("\n".join(lines[1:]), file=sys.stderr, flush=True)
            sys.exit(1)
