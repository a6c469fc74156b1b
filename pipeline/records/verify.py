"""Verify a run record on read: ``pipeline.run`` (before it skips, repeats or resumes a run) and
``pipeline.tables`` (before a record counts) use a record only when its files agree and every value in
them is one the code can use. Records are untrusted input (copied between machines, edited by hand).

- Every value of run.json and of each row: nested at most ``MAX_DEPTH`` deep, text of at most
  ``MAX_TEXT`` characters without control characters, integers within int64, finite numbers
  (``record_value_problem``); the record files are regular files (never read through a symbolic link)
  of at most ``MAX_RECORD_BYTES``.
- run.json is a JSON object with the identity keys (plain names of at most 64 characters, a seed from 0
  to 2^63-1) and a ``config`` object; the keys the tables and the runner read have their types
  (``TYPED``: labels are text, ranks integers, the horizon at most ``MAX_HORIZON`` steps). Rows are
  never adopted without a run.json (steps.jsonl, DONE or FAILED alone: the settings they were made
  with are unknown).
- steps.jsonl holds steps 0, 1, ... in order, each row ``ok`` with its ``metrics`` object (names to
  numbers or null, each metric within its ``pipeline.metrics.info`` bounds, counts whole and >= 0),
  ``n_views`` and a ``selected_pose`` (what a resumed run replays and the tables draw): a unit quaternion
  (within ``QUATERNION_TOLERANCE``) and a position inside the record's camera box (``config.scene.
  camera_box``) widened by ``BOX_MARGIN`` of its size on each side, or, for records that do not hold the
  box, within ``MAX_COORDINATE`` of the origin.
- A finished run (``done``) has one row per step of its horizon (``config.budget.horizon``), and a
  finished or failed record still has the digest run.json took when it ended: ``record_digest`` of
  run.json's content and steps.jsonl. Records that ended before it hold ``steps_digest``, the digest of
  steps.jsonl alone, and are checked against that; records older still have the checks above only. Which
  kind a record is comes from its own content: every version that takes a digest writes ``DIGEST_ERA_KEY``
  into run.json and no earlier one did, so a record holding it and no digest had its digest removed.

A record that fails a check raises ``RecordError``: one line naming the file and the problem.
"""

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pipeline.metrics.info import METRICS
from pipeline.records.files import is_plain_file, read_plain_file
from pipeline.records.store import (
    CONTROL,
    DIGEST_KEY,
    DONE,
    FAILED,
    IDENTITY_KEYS,
    LEGACY_DIGEST_KEY,
    MAX_RECORD_BYTES,
    STEPS,
    RecordError,
    RunRecord,
    check_key,
    check_seed,
    file_digest,
    read_steps,
    record_digest,
)

POSE_SIZE = 7  # [qx, qy, qz, qw, x, y, z]
QUATERNION_TOLERANCE = 1e-3  # | |q| - 1 |: poses are recorded from float32 unit quaternions (off by 1e-7)
BOX_MARGIN = 0.1  # a recorded position may lie this share of the camera box's size outside it
MAX_COORDINATE = 1000.0  # scene units: a position of a record without its camera box (scenes span less than 20)
BOUND_TOLERANCE = 1e-6  # a metric may pass its bounds by rounding (a correlation of 1 + 1e-16)
COUNTS = ("num_points",)  # metrics that count: whole numbers >= 0
DIGEST_ERA_KEY = "candidate_filters"  # run.json: written by every version that takes a digest, by none before
MAX_DEPTH = 32  # JSON nesting of run.json or a row (the committed records nest 8 deep)
MAX_TEXT = 4096  # characters of one text value or key (the committed records' longest text has 109)
MAX_HORIZON = 1000  # steps of a run: every step rewrites steps.jsonl whole; the paper's horizon is 20
MAX_VIEWS = 1_000_000  # n_views of a row
INT64 = 2**63 - 1

NUMBER = (int, float)
TEXT = (str,)
OPTIONAL_TEXT = (str, type(None))
# run.json keys (dotted) that the tables and the runner read, and the types each may have where present
TYPED: dict[str, tuple[type, ...]] = {
    "scene_source": TEXT,
    "failure_reason": OPTIONAL_TEXT,
    "lpips_missing_reason": OPTIONAL_TEXT,
    "collision_free": (bool, type(None)),
    "candidate_filters": (bool, type(None)),
    "ground_truth": (dict, type(None)),
    "ground_truth.asset": OPTIONAL_TEXT,
    "ground_truth.backend": TEXT,
    "ground_truth.samples": (int, type(None)),
    "config.budget": (dict,),
    "config.budget.horizon": (int,),
    "config.method": (dict,),
    "config.method.name": TEXT,
    "config.method.label": TEXT,
    "config.method.rank": (int,),
    "config.ablation": (dict,),
    "config.ablation.name": TEXT,
    "config.ablation.label": TEXT,
    "config.ablation.rank": (int,),
    "config.ablation.of": TEXT,
    "config.planner": (dict,),
    "config.planner.name": TEXT,
    "config.planner.los_source": TEXT,
    "config.planner.collision_free": (bool, type(None)),
    "config.planner.random_filters": (bool,),
    "config.scene": (dict,),
    "config.scene.name": TEXT,
    "config.scene.rank": (int,),
    "config.scene.paper_scene": OPTIONAL_TEXT,
    "config.scene.nerf_asset": (bool,),
    "config.render": (dict,),
    "config.render.backend": TEXT,
    "config.render.samples": (int, type(None)),
}


def record_value_problem(value: Any) -> str | None:
    """What makes a JSON value unusable in a record (``where: problem``), or None: nesting deeper than
    ``MAX_DEPTH``, a text or key longer than ``MAX_TEXT`` or holding a control character, an integer beyond
    int64, a number that is not finite. Walks without recursion, so any depth is answered."""
    stack: list[tuple[str, Any, int]] = [("", value, 1)]
    while stack:
        where, node, depth = stack.pop()
        if depth > MAX_DEPTH:
            return f"{where or 'the value'}: nested more than {MAX_DEPTH} levels deep"
        if isinstance(node, Mapping):
            for key, child in node.items():
                if not isinstance(key, str) or len(key) > MAX_TEXT or CONTROL.search(key):
                    return f"{where or 'the value'}: a key that is not a short line of text"
                stack.append((f"{where}.{key}" if where else key, child, depth + 1))
        elif isinstance(node, list):
            stack.extend((f"{where}.{i}" if where else str(i), child, depth + 1) for i, child in enumerate(node))
        elif isinstance(node, str):
            if len(node) > MAX_TEXT:
                return f"{where}: a text of {len(node)} characters, more than {MAX_TEXT}"
            if CONTROL.search(node):
                return f"{where}: a text with a control character (a line break, a tab, ...)"
        elif isinstance(node, bool) or node is None:
            continue
        elif isinstance(node, int):
            if abs(node) > INT64:
                return f"{where}: an integer of {len(str(abs(node)))} digits, beyond int64"
        elif isinstance(node, float):
            if not math.isfinite(node):
                return f"{where}: {node}, not a finite number"
        else:
            return f"{where}: a {type(node).__name__}, not a JSON value"
    return None


def _lookup(info: Mapping, dotted: str) -> tuple[bool, Any]:
    node: Any = info
    for part in dotted.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return False, None
        node = node[part]
    return True, node


def typed_problem(info: Mapping) -> str | None:
    """The first ``TYPED`` key of run.json whose value has another type (booleans are not integers)."""
    for key, types in TYPED.items():
        present, value = _lookup(info, key)
        if present and (not isinstance(value, types) or (isinstance(value, bool) and bool not in types)):
            names = " or ".join(
                "null" if t is type(None) else {"str": "text", "dict": "an object"}.get(t.__name__, t.__name__)
                for t in types
            )
            shown = repr(value) if len(repr(value)) <= 40 else f"a {type(value).__name__}"
            return f"{key} is {shown}, not {names}"
    return None


def metric_problem(name: str, value: object) -> str | None:
    """What makes a recorded metric value unusable (not a number or null, outside its bounds), or None."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, NUMBER):
        return f"has metric {name[:40]!r} = {str(value)[:40]!r}, not a number or null"
    info = METRICS.get(name)
    if info is not None:
        low, high = info.bounds
        if not low - BOUND_TOLERANCE <= value <= high + BOUND_TOLERANCE:
            return f"has metric {name} = {value:.6g}, outside its range [{low:g}, {high:g}]"
    if name in COUNTS and not (isinstance(value, int) and 0 <= value <= INT64):
        return f"has metric {name} = {value:.6g}, not a count (a whole number >= 0)"
    return None


def camera_box(info: Mapping) -> list[list[float]] | None:
    """The record's ``config.scene.camera_box`` (rows min, max), or None when it does not hold one."""
    present, box = _lookup(info, "config.scene.camera_box")
    return box if present else None


def box_problem(box: object) -> str | None:
    """What makes a recorded camera box unusable (not two corners of 3 numbers, min <= max), or None."""
    corners = box if isinstance(box, list) and len(box) == 2 else []
    if (
        not all(
            isinstance(c, list) and len(c) == 3 and all(isinstance(v, NUMBER) and not isinstance(v, bool) for v in c)
            for c in corners
        )
        or not corners
        or not all(low <= high for low, high in zip(*corners, strict=True))
    ):
        return f"config.scene.camera_box is {str(box)[:80]}, not two corners [min, max] of 3 numbers"
    return None


def pose_problem(pose: list, box: list[list[float]] | None) -> str | None:
    """What makes a recorded pose (7 numbers) unusable: a quaternion that is not a unit one, a position outside
    ``box`` widened by ``BOX_MARGIN`` (or beyond ``MAX_COORDINATE`` without a box); None when it is usable."""
    norm = math.sqrt(sum(v * v for v in pose[:4]))
    if abs(norm - 1.0) > QUATERNION_TOLERANCE:
        return f"has selected_pose with a quaternion of norm {norm:.6g}, not a unit quaternion"
    if box is None:
        low, high = [-MAX_COORDINATE] * 3, [MAX_COORDINATE] * 3
    else:
        margins = [BOX_MARGIN * (hi - lo) for lo, hi in zip(*box, strict=True)]
        low = [lo - m for lo, m in zip(box[0], margins, strict=True)]
        high = [hi + m for hi, m in zip(box[1], margins, strict=True)]
    if not all(lo <= v <= hi for v, lo, hi in zip(pose[4:], low, high, strict=True)):
        where = "the scene's camera box" if box is not None else f"{MAX_COORDINATE:g} of the origin"
        shown = ", ".join(f"{v:.6g}" for v in pose[4:])
        return f"has selected_pose at ({shown}), not within {where}"
    return None


def row_problem(row: dict, box: list[list[float]] | None = None) -> str | None:
    """What makes a step row unusable, or None (``box``: the record's camera box, ``camera_box``)."""
    if row.get("status") != "ok":
        return f"has status {str(row.get('status'))[:40]!r}, not 'ok'"
    problem = record_value_problem(row)
    if problem is not None:
        return f"holds {problem}"
    metrics = row.get("metrics")
    if not isinstance(metrics, dict):
        return "has no metrics object"
    problem = next(filter(None, (metric_problem(name, value) for name, value in metrics.items())), None)
    if problem is not None:
        return problem
    views = row.get("n_views")
    if not isinstance(views, int) or isinstance(views, bool) or not 1 <= views <= MAX_VIEWS:
        return f"has n_views={str(views)[:40]}, not an integer from 1 to {MAX_VIEWS}"
    pose = row.get("selected_pose")
    if not (isinstance(pose, list) and len(pose) == POSE_SIZE) or not all(
        isinstance(v, NUMBER) and not isinstance(v, bool) for v in pose
    ):
        return f"has selected_pose={str(pose)[:80]}, not {POSE_SIZE} finite numbers"
    problem = pose_problem(pose, box)
    if problem is not None:
        return problem
    if not isinstance(row.get("lpips_missing_reason"), OPTIONAL_TEXT):
        return "has an lpips_missing_reason that is not text"
    return None


def check_rows(path: Path, rows: list[dict], box: list[list[float]] | None = None) -> None:
    """Steps 0, 1, ... in order, every row usable (``row_problem`` with the record's camera box ``box``);
    RecordError naming the line."""
    for index, row in enumerate(rows):
        if row["step"] != index:
            step = row["step"] if abs(row["step"]) < 10**9 else "a huge number"
            raise RecordError(
                f"{path}: line {index + 1} holds step {step}, expected step {index} (a step is missing or repeated)"
            )
        problem = row_problem(row, box)
        if problem is not None:
            raise RecordError(f"{path}: step {index} {problem}")


def check_info(record: RunRecord, info: dict) -> None:
    """run.json's values (``record_value_problem``), identity keys (plain names, a seed in range), its config
    object and the types of the keys that are read (``TYPED``)."""
    problem = record_value_problem(info)
    if problem is not None:
        raise RecordError(f"{record.run_json}: holds {problem}")
    missing = [key for key in (*IDENTITY_KEYS, "config") if key not in info]
    if missing:
        raise RecordError(f"{record.run_json}: lacks {', '.join(missing)}")
    try:
        for key in IDENTITY_KEYS[:-1]:
            check_key(key, info[key])
        check_seed(info["seed"])
    except ValueError as err:
        raise RecordError(f"{record.run_json}: {err}") from None
    if not isinstance(info["config"], dict):
        raise RecordError(f"{record.run_json}: config is not an object")
    problem = typed_problem(info)
    if problem is not None:
        raise RecordError(f"{record.run_json}: {problem}")
    present, horizon = _lookup(info, "config.budget.horizon")
    if present and not 1 <= horizon <= MAX_HORIZON:
        raise RecordError(f"{record.run_json}: config.budget.horizon is {horizon}, not from 1 to {MAX_HORIZON}")
    box = camera_box(info)
    problem = box_problem(box) if box is not None else None
    if problem is not None:
        raise RecordError(f"{record.run_json}: {problem}")


def _check_digest(record: RunRecord, info: dict) -> None:
    """run.json and steps.jsonl as they were when the run ended (``DIGEST_KEY``, or ``LEGACY_DIGEST_KEY``)."""
    steps = read_plain_file(record.steps_path, MAX_RECORD_BYTES)
    if DIGEST_KEY in info:
        if record_digest(info, steps or b"") != info[DIGEST_KEY]:
            raise RecordError(
                f"{record.directory}: run.json or steps.jsonl differs from the digest run.json took when the run ended "
                f"({DIGEST_KEY}); the record was changed afterwards"
            )
    elif LEGACY_DIGEST_KEY in info:
        if (file_digest(steps) if steps is not None else None) != info[LEGACY_DIGEST_KEY]:
            raise RecordError(
                f"{record.directory / STEPS}: differs from the digest run.json took when the run finished "
                f"({LEGACY_DIGEST_KEY}); the rows were changed afterwards"
            )
    elif DIGEST_ERA_KEY in info:
        raise RecordError(
            f"{record.run_json}: no {DIGEST_KEY}, though the version that wrote it ({DIGEST_ERA_KEY} says so) takes "
            "one when a run ends; the digest was removed after the run ended: delete the run"
        )


def verified(record: RunRecord) -> tuple[dict, list[dict]]:
    """run.json and the step rows of a record that passes every check (``{}`` and ``[]`` when the run
    has not started); read-only: a truncated last line of an unfinished run is left out, not repaired."""
    info = record.info()
    if not info:
        candidates = (record.steps_path, record.directory / DONE, record.directory / FAILED)
        orphans = [p.name for p in candidates if is_plain_file(p) or p.is_symlink()]
        if orphans:
            raise RecordError(
                f"{record.directory}: {' and '.join(orphans)} without run.json, so the settings they were made with "
                "are unknown; delete the directory"
            )
        return {}, []
    check_info(record, info)
    rows, dropped = read_steps(record.steps_path)
    present, horizon = _lookup(info, "config.budget.horizon")
    if len(rows) > (horizon if present else MAX_HORIZON):
        raise RecordError(
            f"{record.steps_path}: {len(rows)} rows, more than the run's horizon of "
            f"{horizon if present else MAX_HORIZON} steps"
        )
    check_rows(record.steps_path, rows, camera_box(info))
    status = record.status()
    if status == "done":
        if dropped is not None:
            raise RecordError(f"{dropped} of a finished run")
        if not present:
            raise RecordError(f"{record.run_json}: config.budget.horizon is missing, so the run's length is unknown")
        if len(rows) != horizon:
            raise RecordError(
                f"{record.steps_path}: {len(rows)} rows, but the run is marked done with a horizon of {horizon} steps"
            )
    if status != "unfinished":
        _check_digest(record, info)
    return info, rows
