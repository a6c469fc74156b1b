"""Entry point: ``python -m pipeline.run [overrides]`` runs one episode; ``-m`` sweeps (Hydra).
``python -m pipeline.run --help-keys [overrides]`` lists every config key with its default and what it does
(``pipeline.config.key_help``), before Hydra reads the command line.

``pipeline.episode.runner`` validates, locks, verifies, records and resumes; a finished run's summary and
pictures are drawn here (``pipeline.tables.summary.finish_run``), and so are those of a finished run that is
skipped without them (killed between its last step and its pictures). Expected failures print one line
(``pipeline.cli.run_command``). Exit status 2: the
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
from hydra.types import RunMode
from omegaconf import DictConfig

from pipeline.cli import EXPECTED, exit_with, fail, run_command
from pipeline.config import key_help
from pipeline.config.structured_configs import register_configs
from pipeline.config.validation import validate
from pipeline.episode.runner import run_episode
from pipeline.tables.summary import finish_run, missing_pictures, recorded_outline
from pipeline.tables.trajectory import outline_of_scene

register_configs()
HELP_KEYS = "--help-keys"  # every config key, its default and its line (pipeline.config.key_help)
HYDRA_FLAGS = {  # the options Hydra's command line takes (with a value: the next word), and this command's own
    "--help", "-h", "--hydra-help", "--version", "--cfg", "-c", "--resolve", "--package", "-p", "--run", "-r",
    "--multirun", "-m", "--shell-completion", "-sc", "--config-path", "-cp", "--config-name", "-cn", "--config-dir",
    "-cd", "--info", "-i", "--experimental-rerun", HELP_KEYS,
}  # fmt: skip


def unknown_flag(argv: list[str]) -> str | None:
    """The first word of ``argv`` that looks like an option and is none of Hydra's or this command's (Hydra would
    print its whole usage for it), or None; ``key=value`` overrides are not options."""
    return next((a for a in argv if a.startswith("-") and "=" not in a and a.split("=")[0] not in HYDRA_FLAGS), None)


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> dict:
    """One episode; in a sweep, returns ``{"status": done | skipped | failed, "reason"}`` for the report."""
    multirun = HydraConfig.get().mode == RunMode.MULTIRUN
    logging.getLogger("OpenGL").setLevel(logging.WARNING)  # PyOpenGL announces a missing optional module
    try:
        outcome = run_episode(validate(cfg))
    except EXPECTED as err:
        if not multirun:
            exit_with(err)  # here, not through Hydra, which would add its own report of the job
        print(f"error: {err}", file=sys.stderr)
        return {"status": "failed", "reason": str(err)}
    except Exception as err:
        if not multirun:
            raise  # a bug: its traceback
        traceback.print_exc()  # an unexpected error: its traceback in the job's log, the sweep goes on
        return {"status": "failed", "reason": f"{type(err).__name__}: {' '.join(str(err).split())}"}
    directory = outcome.directory
    if outcome.status == "done" and outcome.scene is not None:
        finish_run(directory, outline_of_scene(outcome.scene, outcome.scene_kind))
    elif missing_pictures(directory):  # finished, but killed before its pictures were drawn
        print(f"drawing the pictures of {directory}: its run ended before it drew them")
        finish_run(directory, recorded_outline(directory, cfg.paths.assets))
    if not multirun:
        shown = (
            ("images: ", directory / "grid.png", "(every step's images in images/, labelled)"),
            ("curve:  ", directory / "psnr.png", ""),
            ("cameras:", directory / "trajectory.png", "(initial and chosen views, from above and from the side)"),
            ("records:", directory / "run.json", f"and {directory / 'steps.jsonl'}"),
            ("table:  ", directory / "summary.md", ""),
        )
        for name, path, note in shown:
            if path.is_file():
                print(f"{name} {path} {note}".rstrip())
    return {"status": outcome.status, "reason": None, "directory": str(directory)}


def hydra_main() -> None:
    """``main`` behind Hydra, which raises its errors (a config it cannot compose, an override it cannot
    resolve, an unknown group option or key) to ``run_command`` instead of printing a report; Ctrl-C says how
    to resume. ``--help-keys`` lists the config keys instead (the other arguments are overrides)."""
    os.environ["HYDRA_FULL_ERROR"] = "1"
    flag = unknown_flag(sys.argv[1:])
    if flag is not None:
        fail(f"python -m pipeline.run: unknown option {flag}; the others are key=value overrides (see --help)")
    if HELP_KEYS in sys.argv[1:]:
        key_help.main([arg for arg in sys.argv[1:] if arg != HELP_KEYS])
        return
    try:
        main()
    except KeyboardInterrupt:
        print(
            "\ninterrupted: every finished step is recorded; run the same command again to resume at the first "
            "missing step",
            file=sys.stderr,
        )
        sys.exit(130)


if __name__ == "__main__":
    run_command(hydra_main)
