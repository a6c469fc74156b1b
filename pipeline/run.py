"""Entry point: ``python -m pipeline.run [overrides]`` runs one episode; ``-m`` sweeps (Hydra).

``pipeline.episode.runner`` validates, records and resumes. Expected failures (bad config, missing
mesh, no candidate left, diverged training) print one line; in a sweep the failing job is recorded
and the sweep goes on.
"""

import logging
import os
import sys

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.errors import HydraException
from hydra.types import RunMode
from omegaconf import DictConfig

from pipeline.config.schema import register_configs
from pipeline.config.validation import ConfigError, error_line
from pipeline.episode.runner import StepFailed, run_episode
from pipeline.scenes.scene import SceneError

register_configs()


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    multirun = HydraConfig.get().mode == RunMode.MULTIRUN
    logging.getLogger("OpenGL").setLevel(logging.WARNING)  # PyOpenGL announces a missing optional module
    try:
        directory = run_episode(cfg)
    except (ConfigError, SceneError, StepFailed, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        if multirun:
            return  # recorded; the sweep goes on with the other jobs
        sys.exit(1)
    if not multirun:
        from pipeline.tables.summary import summarize_run

        table = summarize_run(directory)
        print(f"images:  {directory / 'images'}")
        print(f"records: {directory / 'run.json'}, {directory / 'steps.jsonl'}")
        print(f"table:   {table}")


def cli() -> None:
    """``python -m pipeline.run``: ``main`` behind Hydra, except that a config Hydra cannot compose (an unknown
    group option or key, a value of the wrong type, a malformed override) exits with one line (status 1, like
    every other bad input here) instead of Hydra's report."""
    os.environ["HYDRA_FULL_ERROR"] = "1"  # Hydra then raises its errors to us instead of printing a report
    try:
        main()
    except HydraException as err:
        print(error_line(err), file=sys.stderr)
        sys.exit(1)


if __name__ == "__main__":
    cli()
