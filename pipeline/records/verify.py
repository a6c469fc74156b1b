"""Verify a run record on read: ``pipeline.run`` (before it skips, repeats or resumes a run) and
``pipeline.tables`` (before a record counts) use a record only when its files agree and every value in
them is one the code can use. Records are untrusted input (copied between machines, edited by hand).

- Every value of run.json and of each row: nested at most ``MAX_DEPTH`` deep, text of at most
  ``MAX_TEXT`` characters without control characters, integers within int64, finite numbers
  (``record_value_problem``); the record files are regular files (never read through a symbolic link)
  of at most ``MAX_RECORD_BYTES``.
- run.json is a JSON object with the identity keys (plain names of at most 64 characters, a seed from 0
  to 2^63-1) and a ``config`` object. Rows are never adopted without a run.json (steps.jsonl, DONE or FAILED
  alone: the settings they were made with are unknown).
- steps.jsonl holds steps 0, 1, ... in order.
- The record, read as the current version (``pipeline.records.upgrade``), has the types and ranges the schema
  declares (``pipeline.records.schema``: ``RunInfo``, ``StepRow``; ``schema_problem``): each row ``ok`` with its
  metrics each within its range (``pipeline.metrics.info``'s bounds), ``n_views`` and a ``selected_pose`` (what a
  resumed run replays and the tables draw), whose quaternion is a unit one (within ``QUATERNION_TOLERANCE``) and
  whose position lies inside the record's camera box (``config.scene.camera_box``) widened by ``BOX_MARGIN`` of its
  size on each side, or, for records that do not hold the box, within ``MAX_COORDINATE`` of the origin.
- A finished run (``done``) has one row per step of its horizon (``config.budget.horizon``), and a
  finished or failed record still has the digest its version took when it ended: ``record_digest`` of run.json's
  content and steps.jsonl (version 3), ``steps_digest`` of steps.jsonl alone (version 2), none (version 1). A digest
  a record holds is checked whatever its version.

A record that fails a check raises ``RecordError``: one line naming the file and the problem.
"""

import dataclasses
import math
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

from pipeline.records.files import is_plain_file, read_plain_file
from pipeline.records.schema import INT64, MAX_HORIZON, Length, Range, RunInfo, StepRow
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
from pipeline.records.upgrade import record_version, upgraded

QUATERNION_TOLERANCE = 1e-3  # | |q| - 1 |: poses are recorded from float32 unit quaternions (off by 1e-7)
BOX_MARGIN = 0.1  # a recorded position may lie this share of the camera box's size outside it
MAX_COORDINATE = 1000.0  # scene units: a position of a record without its camera box (scenes span less than 20)
BOUND_TOLERANCE = 1e-6  # a number may pass its range by rounding (a correlation of 1 + 1e-16)
MAX_DEPTH = 32  # JSON nesting of run.json or a row (the committed records nest 8 deep)
MAX_TEXT = 4096  # characters of one text value or key (the committed records' longest text has 109)
DIGESTS = {2: LEGACY_DIGEST_KEY, 3: DIGEST_KEY}  # the digest each record version takes when a run ends


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


ABSENT = object()  # the value of a required key a record lacks


@dataclass(frozen=True)
class Problem:
    """Where a record departs from its schema: the dotted ``key``, the ``value`` there (``ABSENT`` for a required key
    it lacks), what the value should be (``expected``) and, for a number of the right type outside its range, the
    ``range``."""

    key: str
    value: Any
    expected: str
    range: Range | None = None


def annotation_parts(annotation: Any) -> tuple[Any, tuple[Any, ...]]:
    """An annotation without ``Annotated``, and the metadata ``Annotated`` gave it."""
    if typing.get_origin(annotation) is Annotated:
        base, *meta = typing.get_args(annotation)
        return base, tuple(meta)
    return annotation, ()


def _is_union(base: Any) -> bool:
    return typing.get_origin(base) in (typing.Union, types.UnionType)


def _members(union: Any, meta: tuple[Any, ...]) -> list[tuple[Any, tuple[Any, ...]]]:
    """Each member of a union type with its metadata, the union's own (a range of ``float | None``) given to every
    member but null."""
    members = [annotation_parts(member) for member in typing.get_args(union)]
    return [(base, own if base is type(None) else (*own, *meta)) for base, own in members]


def _of(meta: tuple[Any, ...], kind: type) -> Any:
    return next((m for m in meta if isinstance(m, kind)), None)


def _number(value: int | float) -> str:
    """A range's end as the messages and docs write it."""
    if value == INT64:
        return "2^63-1"
    return str(int(value)) if math.isfinite(value) and value == int(value) else f"{value:g}"


def expected(base: Any, meta: tuple[Any, ...] = ()) -> str:
    """What a value of a schema type is, in words: ``an integer from 1 to 1000000``, ``text or null``."""
    if _is_union(base):
        return " or ".join(expected(*member) for member in _members(base, meta))
    span: Range | None = _of(meta, Range)
    if base in (int, float):
        noun = "an integer" if base is int else "a number"
        if span is None:
            return "int" if base is int else noun
        if span.high == math.inf:
            return f"{noun} >= {_number(span.low)}"
        return f"{noun} from {_number(span.low)} to {_number(span.high)}"
    origin = typing.get_origin(base)
    if origin is Literal:
        return " or ".join(repr(option) for option in typing.get_args(base))
    if origin is list:
        size: Length | None = _of(meta, Length)
        item, item_meta = annotation_parts(typing.get_args(base)[0])
        if size is not None and item in (int, float):
            return f"{size.items} finite numbers"
        count = f" of {size.items}" if size is not None else ""
        return f"a list{count} ({expected(item, item_meta)} each)"
    names = {type(None): "null", bool: "bool", str: "text", Any: "any value"}
    return names.get(base, "an object")


def _fields_problem(value: Mapping, cls: type, key: str) -> Problem | None:
    """The first field of the record class ``cls`` that ``value`` (an object) lacks though required, or holds with
    another type or outside its range; keys ``cls`` does not declare are not looked at."""
    for field in dataclasses.fields(cls):
        dotted = f"{key}.{field.name}" if key else field.name
        if field.name not in value:
            if field.name in getattr(cls, "REQUIRED", ()):
                return Problem(dotted, ABSENT, "present")
            continue
        problem = _problem(value[field.name], *annotation_parts(field.type), dotted)
        if problem is not None:
            return problem
    return None


def _problem(value: Any, base: Any, meta: tuple[Any, ...], key: str) -> Problem | None:
    """The first place where ``value`` is not of the schema type ``base`` (with its ``Annotated`` ``meta``)."""
    wrong = Problem(key, value, expected(base, meta))
    if _is_union(base):
        found = [_problem(value, *member, key) for member in _members(base, meta)]
        if any(problem is None for problem in found):
            return None
        # the member whose type the value has tells more (a key inside an object, a range) than "not A or B"
        inner = next((p for p in found if p is not None and p.key != key), None)
        outside = next((p for p in found if p is not None and p.range is not None), None)
        return inner or (dataclasses.replace(wrong, range=outside.range) if outside is not None else wrong)
    if base is Any:
        return None
    if base is type(None) or base is bool or base is str:
        return None if (value is None if base is type(None) else isinstance(value, base)) else wrong
    if base in (int, float):
        if isinstance(value, bool) or not isinstance(value, int if base is int else (int, float)):
            return wrong
        span: Range | None = _of(meta, Range)
        slack = BOUND_TOLERANCE if base is float else 0
        if span is not None and not span.low - slack <= value <= span.high + slack:
            return dataclasses.replace(wrong, range=span)
        return None
    origin = typing.get_origin(base)
    if origin is Literal:
        return None if isinstance(value, str) and value in typing.get_args(base) else wrong
    if origin is list:
        size: Length | None = _of(meta, Length)
        if not isinstance(value, list) or (size is not None and len(value) != size.items):
            return wrong
        item = annotation_parts(typing.get_args(base)[0])
        for index, element in enumerate(value):
            problem = _problem(element, *item, f"{key}.{index}")
            if problem is not None:  # a list of plain values is named whole, a list of objects by the item
                return problem if dataclasses.is_dataclass(item[0]) else wrong
        return None
    if not isinstance(value, Mapping):
        return wrong
    if origin is dict:
        entry = annotation_parts(typing.get_args(base)[1])
        for name, element in value.items():
            problem = _problem(element, *entry, f"{key}.{name}")
            if problem is not None:
                return problem
        keys = next((m for m in meta if dataclasses.is_dataclass(m)), None)  # Annotated[dict, Class]: its keys
        return _fields_problem(value, keys, key) if isinstance(keys, type) else None
    return _fields_problem(value, base, key)


def schema_problem(value: Mapping, cls: type) -> Problem | None:
    """The first place where ``value`` (run.json's content or a row, read as the current version) departs from the
    schema's record class ``cls`` (``RunInfo``, ``StepRow``); None when it has every type and range."""
    return _fields_problem(value, cls, "")


def _shown(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else f"a {type(value).__name__}"


def info_problem(problem: Problem) -> str:
    """A problem of run.json as its message says it."""
    if problem.value is ABSENT:
        return f"lacks {problem.key}"
    return f"{problem.key} is {_shown(problem.value)}, not {problem.expected}"


def row_problem_text(problem: Problem) -> str:
    """A problem of a row as its message says it (a metric's range as ``[low, high]``)."""
    if problem.value is ABSENT:
        return f"lacks {problem.key}"
    group, _, name = problem.key.partition(".")
    if group == "metrics" and name:
        if problem.range is not None:
            low, high = _number(problem.range.low), _number(problem.range.high)
            return f"has metric {name} = {problem.value:.6g}, outside its range [{low}, {high}]"
        return f"has metric {name[:40]!r} = {str(problem.value)[:40]!r}, not {problem.expected}"
    return f"has {problem.key}={_shown(problem.value)}, not {problem.expected}"


def camera_box(info: Mapping) -> list[list[float]] | None:
    """The record's ``config.scene.camera_box`` (rows min, max), or None when it does not hold one."""
    scene = info.get("config", {}).get("scene") if isinstance(info.get("config"), Mapping) else None
    return scene.get("camera_box") if isinstance(scene, Mapping) else None


def box_problem(box: object) -> str | None:
    """What makes a recorded camera box unusable (not two corners of 3 numbers, min <= max), or None."""
    corners = box if isinstance(box, list) and len(box) == 2 else []
    if (
        not all(
            isinstance(c, list)
            and len(c) == 3
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in c)
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
    """What makes a step row (read as the current version) unusable, or None (``box``: the record's camera box,
    ``camera_box``)."""
    problem = record_value_problem(row)
    if problem is not None:
        return f"holds {problem}"
    found = schema_problem(row, StepRow)
    if found is not None:
        return row_problem_text(found)
    return pose_problem(row["selected_pose"], box)


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
    object, its record version, and, read as the current version, the schema's types and ranges (``RunInfo``)."""
    problem = record_value_problem(info)
    if problem is not None:
        raise RecordError(f"{record.run_json}: holds {problem}")
    missing = [key for key in RunInfo.REQUIRED if key not in info]
    if missing:
        raise RecordError(f"{record.run_json}: lacks {', '.join(missing)}")
    try:
        for key in IDENTITY_KEYS[:-1]:
            check_key(key, info[key])
        check_seed(info["seed"])
        record_version(info)
    except ValueError as err:
        raise RecordError(f"{record.run_json}: {err}") from None
    if not isinstance(info["config"], dict):
        raise RecordError(f"{record.run_json}: config is not an object")
    found = schema_problem(upgraded(info, [])[0], RunInfo)
    if found is not None:
        raise RecordError(f"{record.run_json}: {info_problem(found)}")
    box = camera_box(info)
    problem = box_problem(box) if box is not None else None
    if problem is not None:
        raise RecordError(f"{record.run_json}: {problem}")


def _check_digest(record: RunRecord, info: dict) -> None:
    """run.json and steps.jsonl as they were when the run ended: the digest the record holds (``DIGEST_KEY``, or
    ``LEGACY_DIGEST_KEY``), and one at all where its version takes one (``DIGESTS``)."""
    steps = read_plain_file(record.steps_path, MAX_RECORD_BYTES)
    version = record_version(info)
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
    if version in DIGESTS and DIGESTS[version] not in info:
        raise RecordError(
            f"{record.run_json}: no {DIGESTS[version]}, though the version that wrote it (record version {version}) "
            "takes one when a run ends; the digest was removed after the run ended: delete the run"
        )


def verified(record: RunRecord) -> tuple[dict, list[dict]]:
    """run.json and the step rows of a record that passes every check, as recorded (``{}`` and ``[]`` when the run
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
    budget = info["config"].get("budget")
    horizon = budget.get("horizon") if isinstance(budget, dict) else None
    if len(rows) > (horizon if horizon is not None else MAX_HORIZON):
        raise RecordError(
            f"{record.steps_path}: {len(rows)} rows, more than the run's horizon of "
            f"{horizon if horizon is not None else MAX_HORIZON} steps"
        )
    current, current_rows = upgraded(info, rows)
    check_rows(record.steps_path, current_rows, camera_box(current))
    status = record.status()
    if status == "done":
        if dropped is not None:
            raise RecordError(f"{dropped} of a finished run")
        if horizon is None:
            raise RecordError(f"{record.run_json}: config.budget.horizon is missing, so the run's length is unknown")
        if len(rows) != horizon:
            raise RecordError(
                f"{record.steps_path}: {len(rows)} rows, but the run is marked done with a horizon of {horizon} steps"
            )
    if status != "unfinished":
        _check_digest(record, info)
    return info, rows


def verified_current(record: RunRecord) -> tuple[dict, list[dict]]:
    """``verified``, read as the current record version (``pipeline.records.upgrade.upgraded``): what the tables
    and experiments read."""
    info, rows = verified(record)
    return upgraded(info, rows) if info else (info, rows)
