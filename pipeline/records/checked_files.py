"""Files a command wrote and reads back (a study's rows, settings and diagnostics, an experiment's summaries): read
through the file layer (``pipeline.records.files``: never through a symbolic link, at most ``MAX_FILE_BYTES``) and
every value a reader uses checked against its declared shape and range before use. A file can be edited, cut by a
kill or replaced, so it is untrusted input like a run record: one that fails is a ``RecordError``, one line naming
the file, the line or row, and the key.

A shape is a ``Number`` (a range, whole or not, null allowed or not), ``Text``, ``bool`` (``Flag``: null allowed
too), a dict of keys to shapes (an object with those keys; ``Optional`` for a key that may be missing, other keys
are not read), ``Each`` (a list of one shape), ``Entries`` (an object whose every value has one shape) or
``Anything`` (any JSON value). Every value is also checked as a record value is (``record_value_problem``:
nesting, text length, control characters, finite numbers).
"""

import io
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from pipeline.records.files import RecordError, read_plain_file
from pipeline.records.verify import record_value_problem

MAX_FILE_BYTES = 64 << 20  # a study's decisions.jsonl: about 2 kB a row


@dataclass(frozen=True)
class Number:
    """A number in ``[low, high]`` (whole when ``integer``; null too when ``null``)."""

    low: float | int = -math.inf
    high: float | int = math.inf
    integer: bool = False
    null: bool = False


@dataclass(frozen=True)
class Text:
    """A text (null too when ``null``)."""

    null: bool = False


@dataclass(frozen=True)
class Flag:
    """True or false (null too when ``null``); plain ``bool`` as a shape allows no null."""

    null: bool = False


@dataclass(frozen=True)
class Optional:
    """A key that may be missing; where present, its value has ``shape``."""

    shape: Any


@dataclass(frozen=True)
class Each:
    """A list whose every item has ``shape``."""

    shape: Any


@dataclass(frozen=True)
class Anything:
    """Any JSON value (a setting's value, which may be a number, a text, a list or null)."""


@dataclass(frozen=True)
class Entries:
    """An object whose every value has ``shape`` (any keys, ``required`` among them)."""

    shape: Any
    required: tuple[str, ...] = ()


def _number_problem(value: object, shape: Number) -> str | None:
    if value is None:
        return None if shape.null else "null, not a number"
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return f"{str(value)[:40]!r}, not a number"
    if not math.isfinite(value):
        return f"{value}, not a finite number"
    if shape.integer and not (isinstance(value, int) or float(value).is_integer()):
        return f"{value:.6g}, not a whole number"
    if not shape.low <= value <= shape.high:
        return f"{value:.6g}, not from {shape.low:g} to {shape.high:g}"
    return None


def shape_problem(value: object, shape: Any, where: str = "") -> str | None:
    """``<key>: <problem>`` for the first value of ``value`` that does not have ``shape``, or None."""
    key = where or "the value"
    if isinstance(shape, Anything):
        return None
    if isinstance(shape, Number):
        problem = _number_problem(value, shape)
        return None if problem is None else f"{key} is {problem}"
    if isinstance(shape, Text):
        return None if isinstance(value, str) or (value is None and shape.null) else f"{key} is not a text"
    if shape is bool or isinstance(shape, Flag):
        allowed = value is None and isinstance(shape, Flag) and shape.null
        return None if isinstance(value, bool) or allowed else f"{key} is not true or false"
    if isinstance(shape, Each):
        if not isinstance(value, list):
            return f"{key} is not a list"
        return next(filter(None, (shape_problem(v, shape.shape, f"{key}.{i}") for i, v in enumerate(value))), None)
    if not isinstance(value, Mapping):
        return f"{key} is not an object"
    if isinstance(shape, Entries):
        missing = [name for name in shape.required if name not in value]
        if missing:
            return f"{where}.{missing[0]} is missing" if where else f"{missing[0]} is missing"
        items = [(name, shape.shape) for name in value]
    else:
        items = list(shape.items())
    for name, inner in items:
        child = f"{where}.{name}" if where else name
        if name not in value:
            if isinstance(inner, Optional):
                continue
            return f"{child} is missing"
        problem = shape_problem(value[name], inner.shape if isinstance(inner, Optional) else inner, child)
        if problem is not None:
            return problem
    return None


def _text(path: Path) -> str | None:
    data = read_plain_file(path, MAX_FILE_BYTES)
    if data is None:
        return None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as err:
        raise RecordError(f"{path}: not UTF-8 text ({err.reason} at byte {err.start}); delete or restore it") from None


def _parsed(text: str) -> tuple[Any, str | None]:
    """A JSON text's value and what makes it unusable (not JSON, a record value problem), or None."""
    try:
        value = json.loads(text)
    except (json.JSONDecodeError, RecursionError):
        return None, "not valid JSON"
    problem = record_value_problem(value)
    return value, None if problem is None else f"holds {problem}"


def read_json(path: Path, shape: Any) -> Any:
    """The JSON value of ``path``, checked against ``shape``; None when the file does not exist."""
    text = _text(path)
    if text is None:
        return None
    value, problem = _parsed(text)
    problem = problem or shape_problem(value, shape)
    if problem is not None:
        raise RecordError(f"{path}: {problem}; delete or restore it")
    return value


def read_json_lines(path: Path, shape: Any) -> tuple[list, int]:
    """The rows of a JSON-lines file (``[]`` when it does not exist), each checked against ``shape``, and the length
    in bytes of its whole lines: a last line without its newline (cut by a kill) is left out, one that fails
    elsewhere is a ``RecordError`` naming the line."""
    text = _text(path) or ""
    complete = text[: text.rfind("\n") + 1]
    rows = []
    for number, line in enumerate(complete.splitlines(), start=1):
        row, problem = _parsed(line)
        problem = problem or shape_problem(row, shape)
        if problem is not None:
            raise RecordError(f"{path}: line {number} {problem}; fix or delete that line")
        rows.append(row)
    return rows, len(complete.encode("utf-8"))


def read_csv(path: Path, columns: Mapping[str, Any]) -> pd.DataFrame | None:
    """A CSV file's rows with at least ``columns`` (``Number`` or ``Text``; an ``Optional`` column may be missing:
    it is read as empty), each cell of them checked (an empty cell is null); None when the file does not exist."""
    text = _text(path)
    if text is None:
        return None
    try:
        frame = pd.read_csv(io.StringIO(text), dtype=str, keep_default_na=False)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, ValueError) as err:
        raise RecordError(f"{path}: not a CSV table ({' '.join(str(err).split())}); delete or restore it") from None
    missing = [name for name, shape in columns.items() if name not in frame.columns and not isinstance(shape, Optional)]
    if missing:
        raise RecordError(f"{path}: lacks the column(s) {', '.join(missing)}; delete or restore it")
    for name, declared in columns.items():
        shape = declared.shape if isinstance(declared, Optional) else declared
        if name not in frame.columns:
            frame[name] = ""
        values = [_cell(cell, shape) for cell in frame[name]]
        for row, value in enumerate(values, start=1):
            problem = shape_problem(value, shape, f"row {row}, column {name}")
            if problem is not None:
                raise RecordError(f"{path}: {problem}; delete or restore it")
        frame[name] = pd.Series(values, index=frame.index, dtype=float if isinstance(shape, Number) else object)
    return frame


def _cell(cell: str, shape: Number | Text) -> object:
    """A CSV cell as the value its shape reads: empty is null; a number's text a float (``nan`` null)."""
    if cell == "":
        return None
    if not isinstance(shape, Number):
        return cell
    try:
        value = float(cell)
    except ValueError:
        return cell
    return None if math.isnan(value) else value
