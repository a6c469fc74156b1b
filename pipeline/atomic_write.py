"""Files written atomically: the new content goes to a temp file of this writer beside the target, is flushed to
disk and renamed over the target's name, and the directory is synced, so a reader (or a process killed mid-write)
sees the old file or the new one, never a half-written one, and a write never goes into an existing file (nor
through a link planted at its name). Every file the harness writes goes through here; a folder that replaces
another is built beside it (``temp_folder``) and swapped in by renames (``replace_folder``); no heavy imports."""

import os
import re
import secrets
import shutil
from pathlib import Path

TEMP_SUFFIX = ".tmp"  # a temp file's name: .<name>.<pid>.<random>.tmp beside its target


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically (``atomic_write_bytes``)."""
    atomic_write_bytes(path, text.encode("utf-8"))


def temp_file(path: Path) -> tuple[int, Path]:
    """A new, empty temp file beside ``path``, unique to this writer: ``.<name>.<pid>.<random>.tmp``.

    Opened write-only with mode 0o666 less the umask, the mode any new file of this process gets
    (``tempfile.mkstemp`` would make it 0600). Returns the descriptor and the path."""
    path.parent.mkdir(parents=True, exist_ok=True)
    while True:
        tmp = path.parent / f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}{TEMP_SUFFIX}"
        try:
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666), tmp
        except FileExistsError:
            continue


def writer_alive(pid: int) -> bool:
    """Whether a process ``pid`` runs on this machine (one of another user counts as running)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_abandoned_folders(path: Path) -> list[Path]:
    """Remove the folders ``temp_folder`` and ``replace_folder`` left beside ``path`` (``.<name>.<pid>.<random>.new``
    or ``.old``) whose writer no longer runs: a writer killed before its renames (``kill -9``) leaves them behind.
    A folder of a running process is kept. Returns the removed paths."""
    pattern = re.compile(rf"\.{re.escape(path.name)}\.(\d+)\.[0-9a-f]{{8}}\.(new|old)")
    removed: list[Path] = []
    if not path.parent.is_dir():
        return removed
    for entry in sorted(path.parent.iterdir()):
        found = pattern.fullmatch(entry.name)
        if found is None or entry.is_symlink() or not entry.is_dir() or writer_alive(int(found[1])):
            continue
        shutil.rmtree(entry, ignore_errors=True)
        removed.append(entry)
    return removed


def temp_folder(path: Path) -> Path:
    """A new, empty folder beside ``path``, unique to this writer (``.<name>.<pid>.<random>.new``), made as any new
    folder of this process is (0o777 less the umask): where a folder that will replace ``path`` is built. Folders
    that killed writers left beside ``path`` are removed first (``remove_abandoned_folders``)."""
    remove_abandoned_folders(path)
    while True:
        folder = path.parent / f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.new"
        try:
            os.mkdir(folder, 0o777)
            return folder
        except FileExistsError:
            continue


def replace_folder(new: Path, path: Path) -> None:
    """Put the folder ``new`` (beside ``path``) in the place of ``path`` by renames: ``path`` (a folder, a link or
    nothing) renamed aside, ``new`` renamed to ``path`` (the old one put back if that fails), then the old one
    removed. A reader sees the old folder or the new one whole, never a mix."""
    old = None
    if os.path.lexists(path):
        old = path.parent / f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.old"
        os.rename(path, old)
    try:
        os.rename(new, path)
    except BaseException:
        if old is not None:
            os.rename(old, path)
        raise
    if old is not None and (old.is_symlink() or not old.is_dir()):
        old.unlink()
    elif old is not None:
        shutil.rmtree(old)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a temp file of this writer in the same directory (``temp_file``),
    fsync and ``os.replace``; the file's mode follows the umask."""
    fd, tmp = temp_file(path)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    dir_fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)
