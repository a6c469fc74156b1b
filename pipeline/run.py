"""Entry point: ``python -m pipeline.run [overrides]`` runs one episode; ``-m`` sweeps (Hydra).

``pipeline.episode.runner`` validates, locks, verifies, records and resumes; a finished run's summary and
pictures are drawn here (``pipeline.tables.summary.finish_run``). Expected failures print one line. Exit status 2: the
run was refused before it started (a bad config or override, an unusable
``paths.outputs``, a scene that cannot load, another process writing the run, a record that fails a
check or holds other settings). Exit status 1: the run failed, now or when it last ran (its record
says why), or stopped because Blender's worker did not answer within ``render.timeout`` (left to resume). In a sweep
every job runs; each failure is reported by the job and the sweep ends with a
summary and exits 1 if any job failed (``pipeline.episode.sweep``).
"""

import logging
import os
import sys
import traceback

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.errors import HydraException
from hydra.types import RunMode
from omegaconf import DictConfig

from pipeline.config.schema import register_configs
from pipeline.config.validation import ConfigError, error_line, validate
from pipeline.episode.runner import RunRefused, StepFailed, run_episode
from pipeline.records.lock import RunLocked
from pipeline.records.store import RecordError
from pipeline.scenes.scene import SceneError
from pipeline.tables.summary import finish_run

register_configs()

REFUSED = (ConfigError, SceneError, RunLocked, RecordError, RunRefused)  # exit 2: nothing ran


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> dict:
    """One episode; in a sweep, returns ``{"status": done | skipped | failed, "reason"}`` for the report."""
    multirun = HydraConfig.get().mode == RunMode.MULTIRUN
    logging.getLogger("OpenGL").setLevel(logging.WARNING)  # PyOpenGL announces a missing optional module
    try:
        outcome = run_episode(validate(cfg))
    except (*REFUSED, StepFailed) as err:
        print(f"error: {err}", file=sys.stderr)
        if multirun:
            return {"status": "failed", "reason": str(err)}
        sys.exit(2 if isinstance(err, REFUSED) else 1)
    except Exception as err:
        if not multirun:
            raise
        traceback.print_exc()  # an unexpected error: its traceback in the job's log, the sweep goes on
        return {"status": "failed", "reason": f"{type(err).__name__}: {' '.join(str(err).split())}"}
    if outcome.status == "done" and outcome.scene is not None:
        finish_run(outcome.directory, outcome.scene, outcome.scene_kind)
    if not multirun:
        directory = outcome.directory
        print(f"images:  {directory / 'images'} (every step), {directory / 'grid.png'} (labelled)")
        print(f"curve:   {directory / 'psnr.png'}")
        print(f"cameras: {directory / 'trajectory.png'} (initial and chosen views, from above and from the side)")
        print(f"records: {directory / 'run.json'}, {directory / 'steps.jsonl'}")
        print(f"table:   {directory / 'summary.md'}")
    return {"status": outcome.status, "reason": None}


def cli() -> None:
    """``python -m pipeline.run``: ``main`` behind Hydra, except that a config Hydra cannot compose (an unknown
    group option or key, a value of the wrong type, a malformed override) exits with one line (status 2, like
    every other bad input here) instead of Hydra's report."""
    os.environ["HYDRA_FULL_ERROR"] = "1"  # Hydra then raises its errors to us instead of printing a report
    try:
        main()
    except HydraException as err:
        print(error_line(err), file=sys.stderr)
        sys.exit(2)
    except KeyboardInterrupt:
        print(
            "\ninterrupted: every finished step is recorded; run the same command again to resume at the first "
            "missing step",
            file=sys.stderr,
        )
        sys.exit(130)


if __name__ == "__main__":
    cli()
