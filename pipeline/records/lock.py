"""One writer per run directory: an exclusive ``fcntl.flock`` on the run's lock file, taken before anything
in the run directory is read or written and held until the run ends. The kernel releases it when its
process dies (a kill -9 leaves no stale lock). The holder writes ``host pid start-time`` into the
file, so a second writer is refused with one line naming it.

The lock file of ``<root>/<scene>/<group>/<budget>/seed_<n>`` is ``<root>/.locks/<scene>/<group>/<budget>/
seed_<n>.lock``, outside the run directory, so a run refused under its lock (a scene that cannot load)
leaves no run directory behind. It is opened with ``O_NOFOLLOW`` (a symbolic link in its place is refused,
never followed) and never removed, nor is any directory: every writer of a run locks the same file, so
there is no moment at which two processes hold locks on two different files (removing the lock file or
its directory on release let a second writer lock a file a third had just replaced). On release the
holder empties it. A lock file with another name (a hard link) is refused before it is written
(``pipeline.records.files.open_in_place``).
"""

import fcntl
import os
import socket
from pathlib import Path
from types import TracebackType

from pipeline.cli import BadInput
from pipeline.records.files import check_directory, make_directory, open_in_place, refuse_escaping_entries
from pipeline.records.store import utc_now

LOCK_DIRECTORY = ".locks"


class RunLocked(BadInput, RuntimeError):
    """Another process holds the run's lock; the message is one line naming it."""


def lock_path(directory: Path, root: Path) -> Path:
    """The lock file of the run directory ``directory`` (strictly below ``root``)."""
    relative = Path(directory).relative_to(root)
    if not relative.parts:
        raise ValueError(f"a run directory lies below its root, not at it: {directory}")
    return Path(root) / LOCK_DIRECTORY / relative.parent / f"{relative.name}.lock"


class RunLock:
    """``with RunLock(directory, root):`` holds the lock of the run directory ``directory`` below ``root``
    (``paths.outputs``). ``RecordError`` when a component of the run directory or of its lock file, or an
    entry of the run directory, is a symbolic link leaving ``root``, a file stands where a directory
    belongs, or the lock file is not a regular file of its own (a link, a hard link)."""

    def __init__(self, directory: Path, root: Path):
        self.directory = Path(directory)
        self.root = Path(root)
        self.path = lock_path(self.directory, self.root)
        self._fd: int | None = None

    def __enter__(self) -> "RunLock":
        check_directory(self.root, self.directory)
        if self.directory.is_dir():
            refuse_escaping_entries(self.root, self.directory)  # images/, a record file: never written through
        make_directory(self.root, self.path.parent)
        fd = open_in_place(self.path, os.O_RDWR | os.O_CREAT, "the run's lock file")
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = (
                os.pread(fd, 512, 0).decode("utf-8", "replace").strip() or "a process that has not named itself yet"
            )
            os.close(fd)
            raise RunLocked(
                f"run {self.directory} is being written by {' '.join(holder.split())}; wait for it to end or stop it "
                "(the lock is released when that process ends)"
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"host {socket.gethostname()} pid {os.getpid()} started {utc_now()}\n".encode(), 0)
        self._fd = fd
        return self

    def __exit__(
        self, kind: type[BaseException] | None, error: BaseException | None, traceback: TracebackType | None
    ) -> None:
        if self._fd is None:
            return
        os.ftruncate(self._fd, 0)  # the holder's line goes with the lock; the file stays
        os.close(self._fd)
        self._fd = None
