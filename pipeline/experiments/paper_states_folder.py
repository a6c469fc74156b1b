"""A paper states' folder and its setting (``pipeline.experiments.paper_states``): ``setting.json`` checked before
anything is written and written under the folder's lock, the command added to ``command.txt``."""

import hashlib
import json
from pathlib import Path

from pipeline.atomic_write import atomic_write_text
from pipeline.cli import fail
from pipeline.experiments.options import add_command, other_threads
from pipeline.experiments.paper_states_summary import FOLDER, LEGACY_VIS_POINTS, SETTING, STATE
from pipeline.records.checked_files import read_json, read_json_lines
from pipeline.records.files import check_directory, make_directory
from pipeline.records.lock import RunLock

SETTING_LOCK = ".setting"  # setting.json and command.txt are written under this lock of the folder


def setting_problem(folder: Path, setting: dict) -> str | None:
    """Why ``folder`` takes no rows of ``setting``: it holds another setting (overrides, states' budget, label
    points), or was made with another thread count than its setting's or, where the setting predates it, its
    rows'; None when it takes them. Reads only."""
    made = read_json(folder / "setting.json", SETTING)
    if made is None:
        return None
    for key in ("overrides", "state_budget", "vis_points"):
        theirs = made.get(key, LEGACY_VIS_POINTS if key == "vis_points" else None)
        if theirs != setting[key]:
            return (
                f"{folder} holds states made with {key} {theirs}, not {setting[key]}; pass paths.results=DIR for "
                "another setting"
            )
    rows = read_json_lines(folder / "states.jsonl", STATE)[0]
    return other_threads(
        folder, setting["threads"], {made["threads"]} if "threads" in made else {r["threads"] for r in rows}
    )


def check_setting(folder: Path, setting: dict) -> None:
    """One ``error:`` line when ``folder`` takes no rows of ``setting`` (``setting_problem``)."""
    problem = setting_problem(folder, setting)
    if problem is not None:
        fail(problem)


def setting_digest(setting: dict) -> str:
    """A short name of ``setting``: states in progress of one setting never resume another's."""
    return hashlib.sha256(json.dumps(setting, sort_keys=True).encode()).hexdigest()[:16]


def open_folder(root: Path, setting: dict, command: list[str]) -> Path:
    """The folder, its ``setting.json`` checked (``check_setting``: before anything is written) and, under the
    folder's own lock, checked again (another process may have written one since) and written, and the command
    added to ``command.txt``."""
    folder = root / FOLDER
    check_directory(root.parent, folder)
    check_setting(folder, setting)
    make_directory(root.parent, folder)
    with RunLock(folder / SETTING_LOCK, folder):
        check_setting(folder, setting)
        atomic_write_text(folder / "setting.json", json.dumps(setting, indent=2) + "\n")
        add_command(folder, command)
    return folder
