"""One writer per run directory: an exclusive ``fcntl.flock`` on ``<run>/.lock``, taken before anything
in the directory is read or written and held until the run ends. The kernel releases it when its
process dies (a kill -9 leaves no stale lock). The holder writes ``host pid start-time`` into the
file, so a second writer is refused with one line naming it.
"""

import fcntl
import os
import socket
from pathlib import Path
from types import TracebackType

from pipeline.records.store import utc_now

LOCK_FILE = ".lock"


class RunLocked(RuntimeError):
    """Another process holds the run's lock; the message is one line naming it."""


class RunLock:
    """``with RunLock(directory, root):`` holds the lock of a run directory (created with its parents).

    On release the lock file is removed, and so are the run directory and its parents below ``root``
    if nothing else was written in them (a run refused before its record started leaves no trace).
    A process that opened the file before it was removed notices (another inode) and opens it again.
    """

    def __init__(self, directory: Path, root: Path | None = None):
        self.directory = Path(directory)
        self.root = Path(root) if root is not None else self.directory
        self.path = self.directory / LOCK_FILE
        self._fd: int | None = None

    def __enter__(self) -> "RunLock":
        while self._fd is None:
            self.directory.mkdir(parents=True, exist_ok=True)
            try:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o666)
            except FileNotFoundError:  # the previous holder removed the empty directory meanwhile
                continue
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.read(fd, 512).decode("utf-8", "replace").strip() or "a process that has not named itself yet"
                os.close(fd)
                raise RunLocked(
                    f"run {self.directory} is being written by {holder}; wait for it to end or stop it "
                    f"(if that process is gone, delete {self.path})"
                ) from None
            if self._same_file(fd):
                os.ftruncate(fd, 0)
                os.write(fd, f"host {socket.gethostname()} pid {os.getpid()} started {utc_now()}\n".encode())
                self._fd = fd
            else:  # released and removed by its previous holder after we opened it
                os.close(fd)
        return self

    def _same_file(self, fd: int) -> bool:
        try:
            return os.stat(self.path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            return False

    def __exit__(
        self, kind: type[BaseException] | None, error: BaseException | None, traceback: TracebackType | None
    ) -> None:
        if self._fd is None:
            return
        self.path.unlink(missing_ok=True)  # before unlocking: a waiting opener then sees another inode
        os.close(self._fd)
        self._fd = None
        self._remove_empty_directories()

    def _remove_empty_directories(self) -> None:
        directory = self.directory
        while directory != self.root and self.root in directory.parents:
            try:
                directory.rmdir()
            except OSError:  # not empty, or another writer is using it
                return
            directory = directory.parent
