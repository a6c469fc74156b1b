"""Where records and results may be read and written: never through a symbolic link that leaves the
directory they belong to (``paths.outputs`` for runs, ``paths.results`` for tables), and record files
opened without following a link at all (``O_NOFOLLOW``), so a link planted in a run directory or a
results folder can neither redirect a write nor feed a read from elsewhere. A link that stays inside its
root (a run folder linked from another place under ``paths.outputs``) is followed as usual.

``O_NOFOLLOW`` is not enough for a file written in place (a lock file, an appended log): a hard link is
not a link to anything, it is the file itself under a second name, possibly outside the folder, and
writing through it changes the file under that name too. Such a file is opened only when it has no
other name (``open_in_place``); every other file is written to a new temp file and renamed over its name
(``pipeline.atomic_write.atomic_write_bytes``), which never writes into an existing file.

Every problem raises ``RecordError``: one line naming the path and what to do.
"""

import os
import stat
from pathlib import Path

from pipeline.cli import BadInput


class RecordError(BadInput, ValueError):
    """A run record that fails a check; the message is one line naming the file and the problem."""


def escaping_link(root: Path, path: Path) -> tuple[Path, Path] | None:
    """The first component of ``path`` below ``root`` (``path`` included) that is a symbolic link whose
    target lies outside ``root``, with that target; None when there is none (``root`` itself may be a link)."""
    root, path = Path(root), Path(path)
    try:
        parts = path.relative_to(root).parts
    except ValueError:
        return None
    top = root.resolve()
    current = root
    for part in parts:
        current = current / part
        if current.is_symlink():
            target = current.resolve()
            if target != top and top not in target.parents:
                return current, target
    return None


def refuse_escaping_link(root: Path, path: Path) -> None:
    """``RecordError`` naming the link when ``escaping_link(root, path)`` finds one."""
    found = escaping_link(root, path)
    if found is not None:
        link, target = found
        raise RecordError(
            f"{link} is a symbolic link to {target}, outside {root}; records and results are never read or written "
            f"through such a link: remove it (or point it inside {root})"
        )


def refuse_escaping_entries(root: Path, directory: Path) -> None:
    """``RecordError`` naming the first entry of ``directory`` that is a symbolic link leaving ``root``."""
    for entry in sorted(Path(directory).iterdir()):
        if entry.is_symlink():
            refuse_escaping_link(root, entry)


def check_directory(root: Path, path: Path) -> None:
    """``RecordError`` when ``path`` (at or below ``root``; it need not exist) lies behind a symbolic link leaving
    ``root`` or it, or a component of it, is something other than a directory (a file stands in the way)."""
    refuse_escaping_link(root, path)
    current = Path(root)
    for part in ("", *Path(path).relative_to(root).parts):
        current = current / part
        if not os.path.lexists(current):
            return
        if not current.is_dir():
            where = "" if current == Path(path) else f", so {path} cannot be created there"
            raise RecordError(f"{current} is a file, not a directory{where}; move it away")


def make_directory(root: Path, path: Path) -> Path:
    """Create ``path`` (a directory at or below ``root``) with its parents; ``RecordError`` when a component
    is a symbolic link leaving ``root`` or a file stands in its way. Nothing is ever removed, so creating
    directories cannot race with another process."""
    check_directory(root, path)
    try:
        Path(path).mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise RecordError(f"{path}: cannot be created ({err.strerror})") from None
    return Path(path)


def is_plain_file(path: Path) -> bool:
    """Whether ``path`` is a regular file itself (not a symbolic link to one)."""
    try:
        return stat.S_ISREG(os.lstat(path).st_mode)
    except OSError:
        return False


def open_in_place(path: Path, flags: int, what: str) -> int:
    """A descriptor of the regular file ``path`` (``what`` it is; created with ``os.O_CREAT`` in ``flags``)
    opened for writing in place, without following a symbolic link; ``RecordError`` when it is a link, not a
    regular file, or has another name too (a hard link: ``st_nlink`` > 1), before anything is written."""
    try:
        fd = os.open(path, flags | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC, 0o666)
    except OSError as err:
        kind = "a symbolic link" if os.path.islink(path) else err.strerror
        raise RecordError(f"{path}: {kind}, not {what}; remove it and run again") from None
    status = os.fstat(fd)
    problem = None if stat.S_ISREG(status.st_mode) else "not a regular file"
    if problem is None and status.st_nlink > 1:
        problem = f"a file with {status.st_nlink - 1} other name(s) (a hard link), which a write would change too"
    if problem is not None:
        os.close(fd)
        raise RecordError(f"{path}: {problem}, so not {what}; remove it and run again")
    return fd


def append_plain_file(path: Path, data: bytes, what: str) -> None:
    """Append ``data`` to the regular file ``path`` (``what`` it is; created if missing) in one write
    (``open_in_place``)."""
    fd = open_in_place(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, what)
    try:
        os.write(fd, data)
    finally:
        os.close(fd)


def read_plain_file(path: Path, limit: int) -> bytes | None:
    """The bytes of the regular file ``path``, opened without following a symbolic link; None when it does
    not exist. ``RecordError`` when it is a link, not a regular file, or larger than ``limit`` bytes."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        return None
    except OSError as err:
        kind = "a symbolic link" if os.path.islink(path) else err.strerror
        raise RecordError(f"{path}: {kind}, not a record file; records are read only from regular files") from None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise RecordError(f"{path}: not a regular file; records are read only from regular files")
        with os.fdopen(os.dup(fd), "rb") as f:
            data = f.read(limit + 1)
    finally:
        os.close(fd)
    if len(data) > limit:
        raise RecordError(f"{path}: more than {limit} bytes, more than a record file may hold; delete the run")
    return data
