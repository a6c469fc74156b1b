"""A study's JSON-lines files (the duel's decisions and outcomes, the paper states' rows, the visibility study's
decisions): rows appended whole through the file layer, checked against their shape when read, one current row per
key (a later row supersedes an earlier only where it names it)."""

import hashlib
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pipeline.atomic_write import atomic_write_text
from pipeline.records.checked_files import read_json_lines
from pipeline.records.files import RecordError, append_plain_file
from pipeline.records.store import dumps, to_jsonable

EXTENDS = "extends"  # a row's key: the ``row_digest`` of the earlier row of its key that it supersedes


def row_digest(row: dict) -> str:
    """``sha256:<hex>`` of a row's one-line JSON (``dumps``): what a later row names to supersede it."""
    return "sha256:" + hashlib.sha256(dumps(row).encode("utf-8")).hexdigest()


def current_rows(rows: list[dict], key: Callable[[dict], tuple], where: str) -> list[dict]:
    """``rows`` without those a later row supersedes: a row repeating an earlier row's key must name that row's
    ``row_digest`` under ``EXTENDS`` (it extends the earlier row, which the file keeps as it was); otherwise a
    ``RecordError`` naming both lines of ``where``."""
    current: list[dict] = []
    lines: dict[tuple, tuple[int, int]] = {}  # key -> (its index in current, its line)
    for number, row in enumerate(rows, start=1):
        found = key(row)
        if found not in lines:
            lines[found] = (len(current), number)
            current.append(row)
            continue
        index, line = lines[found]
        if row.get(EXTENDS) != row_digest(current[index]):
            raise RecordError(
                f"{where}: line {number} repeats the row {found} of line {line} (two writers of one state?); delete "
                "one of them"
            )
        current[index] = row
        lines[found] = (index, number)
    return current


class JsonLines:
    """The rows of a JSON-lines file, each checked against ``shape`` when read (``pipeline.records.checked_files``:
    never through a symbolic link; a bad line is one ``RecordError`` naming it). Rows are appended in one write each
    call through the file layer (never into a file with another name), so a killed writer leaves whole rows (a
    row cut off by a kill is dropped when the file is next opened), and writers of other scenes or seeds can
    append side by side. With ``key`` (a row's identity, e.g. its scene, seed, step and set) ``rows`` are the
    current rows (``current_rows``: a later row of a key replaces the earlier only where it names it under
    ``EXTENDS``, and the file keeps both), a file holding two rows of one key otherwise is refused when read, and
    ``add`` refuses a row whose key the file already holds, rows other writers appended since included, unless it
    extends the current one."""

    def __init__(self, path: Path, shape: Any, key: Callable[[dict], tuple] | None = None):
        self.path, self.shape, self.key = path, shape, key
        lines, whole = read_json_lines(path, shape)
        self.rows = self._current(lines)
        if os.path.lexists(path) and os.lstat(path).st_size != whole:
            atomic_write_text(path, "".join(dumps(row) + "\n" for row in lines))

    def _current(self, lines: list[dict]) -> list[dict]:
        return lines if self.key is None else current_rows(lines, self.key, str(self.path))

    def add(self, rows: list[dict[str, Any]]) -> None:
        rows = [to_jsonable(row) for row in rows]
        if self.key is not None:
            held = {self.key(row): row for row in self._current(read_json_lines(self.path, self.shape)[0])}
            for row in rows:
                earlier = held.get(self.key(row))
                if earlier is not None and row.get(EXTENDS) != row_digest(earlier):
                    raise RecordError(
                        f"{self.path} already holds the row {self.key(row)}: another process wrote it; run one "
                        "writer per scene and seed"
                    )
                held[self.key(row)] = row
            self.rows = list(held.values())
        else:
            self.rows.extend(rows)
        append_plain_file(self.path, "".join(dumps(row) + "\n" for row in rows).encode(), "a duel's rows")
