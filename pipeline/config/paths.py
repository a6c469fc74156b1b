"""Directories a command writes in, checked before it starts: ``paths.outputs`` (runs) and
``paths.results`` (tables). Imports nothing heavy (``pipeline.tables`` uses it without torch)."""

import os
from pathlib import Path


def unwritable(key: str, path: Path) -> str | None:
    """One line saying why ``path`` (the value of ``key``) cannot be written in, or None when it is a
    directory this process can write in, or can be created as one."""
    path = Path(path)
    existing = path
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if existing.exists() and not existing.is_dir():
        where = "is" if existing == path else f"lies under {existing}, which is"
        return f"{key}={path} {where} a file, not a directory; pass {key}=DIR"
    if not os.access(existing, os.W_OK | os.X_OK):
        where = "is" if existing == path else f"would be created in {existing}, which is"
        return f"{key}={path} {where} not writable here; pass {key}=DIR"
    return None
