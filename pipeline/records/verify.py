"""Verify a run record on read: ``pipeline.run`` (before it skips, repeats or resumes a run) and
``pipeline.tables`` (before a record counts) use a record only when its files agree.

- run.json is a JSON object with the identity keys and a ``config`` object; rows are never adopted
  without it (steps.jsonl, DONE or FAILED alone: the settings they were made with are unknown).
- steps.jsonl holds steps 0, 1, ... in order, each row ``ok`` with its ``metrics`` object, ``n_views``
  and a ``selected_pose`` of 7 finite numbers (what a resumed run replays).
- A finished run (``done``) has one row per step of its horizon (``config.budget.horizon``), and a
  finished record's steps.jsonl still has the digest run.json took when it finished
  (``DIGEST_KEY``; records written before digests have structure checks only).

A record that fails a check raises ``RecordError``: one line naming the file and the problem.
"""

import math
from pathlib import Path

from pipeline.records.store import (
    DIGEST_KEY,
    DONE,
    FAILED,
    IDENTITY_KEYS,
    STEPS,
    RecordError,
    RunRecord,
    check_key,
    file_digest,
    read_steps,
)

POSE_SIZE = 7  # [qx, qy, qz, qw, x, y, z]


def row_problem(row: dict) -> str | None:
    """What makes a step row unusable, or None."""
    if row.get("status") != "ok":
        return f"has status {row.get('status')!r}, not 'ok'"
    if not isinstance(row.get("metrics"), dict):
        return "has no metrics object"
    views = row.get("n_views")
    if not isinstance(views, int) or isinstance(views, bool) or views < 1:
        return f"has n_views={views!r}, not a positive integer"
    pose = row.get("selected_pose")
    numbers = isinstance(pose, list) and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in pose)
    if not numbers or len(pose) != POSE_SIZE or not all(math.isfinite(v) for v in pose):
        return f"has selected_pose={pose!r}, not {POSE_SIZE} finite numbers"
    return None


def check_rows(path: Path, rows: list[dict]) -> None:
    """Steps 0, 1, ... in order, every row usable (``row_problem``); RecordError naming the line."""
    for index, row in enumerate(rows):
        if row["step"] != index:
            raise RecordError(f"{path}: line {index + 1} holds step {row['step']}, expected step {index} (a step is missing or repeated)")
        problem = row_problem(row)
        if problem is not None:
            raise RecordError(f"{path}: step {index} {problem}")


def check_info(record: RunRecord, info: dict) -> None:
    """run.json's identity keys (plain names, an integer seed) and its config object."""
    missing = [key for key in (*IDENTITY_KEYS, "config") if key not in info]
    if missing:
        raise RecordError(f"{record.run_json}: lacks {', '.join(missing)}")
    try:
        for key in IDENTITY_KEYS[:-1]:
            check_key(key, info[key])
    except ValueError as err:
        raise RecordError(f"{record.run_json}: {err}") from None
    seed = info["seed"]
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
        raise RecordError(f"{record.run_json}: seed {seed!r} is not a non-negative integer")
    if not isinstance(info["config"], dict):
        raise RecordError(f"{record.run_json}: config is not an object")


def verified(record: RunRecord) -> tuple[dict, list[dict]]:
    """run.json and the step rows of a record that passes every check (``{}`` and ``[]`` when the run
    has not started); read-only: a truncated last line of an unfinished run is left out, not repaired."""
    info = record.info()
    if not info:
        orphans = [p.name for p in (record.steps_path, record.directory / DONE, record.directory / FAILED) if p.is_file()]
        if orphans:
            raise RecordError(
                f"{record.directory}: {' and '.join(orphans)} without run.json, so the settings they were made with "
                "are unknown; delete the directory"
            )
        return {}, []
    check_info(record, info)
    rows, dropped = read_steps(record.steps_path)
    check_rows(record.steps_path, rows)
    status = record.status()
    if status == "done":
        if dropped is not None:
            raise RecordError(f"{dropped} of a finished run")
        budget = info["config"].get("budget")
        horizon = budget.get("horizon") if isinstance(budget, dict) else None
        if not isinstance(horizon, int) or isinstance(horizon, bool):
            raise RecordError(f"{record.run_json}: config.budget.horizon is {horizon!r}, not an integer")
        if len(rows) != horizon:
            raise RecordError(f"{record.steps_path}: {len(rows)} rows, but the run is marked done with a horizon of {horizon} steps")
    if status != "unfinished" and DIGEST_KEY in info:
        digest = file_digest(record.steps_path) if record.steps_path.is_file() else None
        if digest != info[DIGEST_KEY]:
            raise RecordError(
                f"{record.directory / STEPS}: differs from the digest run.json took when the run finished "
                f"({DIGEST_KEY}); the rows were changed afterwards"
            )
    return info, rows
