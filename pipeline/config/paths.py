"""Directories a command writes in, checked before it starts: ``paths.outputs`` (runs) and
``paths.results`` (tables). Imports nothing heavy (``pipeline.tables`` uses it without torch)."""

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException

from pipeline.cli import error_line
from pipeline.config.plain_containers import as_dict
from pipeline.config.structured_configs import PathsConfig
from pipeline.repo import CONF


def configured_paths(overrides: Mapping[str, str]) -> dict[str, Path]:
    """The ``paths`` group (the schema's ``PathsConfig`` and ``conf/paths/default.yaml``) with ``paths.<key>=value``
    overrides applied and its interpolations (``${paths.outputs}/results``, ``NVF_ASSETS``) resolved, without
    composing the whole config; a key the group does not have, or a value that does not resolve
    (``${oc.env:UNSET}``, ``${``), is a ValueError of one line naming the key."""
    declared: Any = OmegaConf.load(Path(CONF) / "paths" / "default.yaml") or {}
    node = OmegaConf.create({"paths": OmegaConf.merge(OmegaConf.structured(PathsConfig), declared)})
    for key, value in overrides.items():
        if OmegaConf.select(node, key, default=None) is None and key.split(".", 1)[-1] not in node.paths:
            raise ValueError(f"unknown key {key!r}: use {', '.join(f'paths.{k}=DIR' for k in node.paths)}")
        OmegaConf.update(node, key, value)
    try:
        return {key: Path(value) for key, value in as_dict(node.paths).items()}
    except OmegaConfBaseException as err:
        raise ValueError(error_line(err).removeprefix("error: ")) from None


def paths_from_args(args: Sequence[str], keys: Sequence[str]) -> dict[str, Path]:
    """``configured_paths`` of a command's ``key=value`` arguments, each key one of ``keys``; a ValueError
    naming the arguments the command takes otherwise."""
    overrides = {}
    for arg in args:
        key, sep, value = arg.partition("=")
        if not sep or not value or key not in keys:
            raise ValueError(f"unknown argument {arg!r}: use {' and/or '.join(f'{k}=DIR' for k in keys)}")
        overrides[key] = value
    return configured_paths(overrides)


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
