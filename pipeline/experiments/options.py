"""What the experiment commands share on their command lines: the tables' seeds and comma-separated lists,
as argparse ``type=`` converters (a bad list is argparse's one ``error:`` line, ``pipeline.cli``); the overrides
that make a setting, and the thread count a folder's rows were made with; a folder's ``command.txt`` of the commands
that wrote into it."""

import argparse
import shlex
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from pipeline.atomic_write import atomic_write_text
from pipeline.records.checked_files import MAX_FILE_BYTES
from pipeline.records.files import read_plain_file
from pipeline.repo import REPO

SEEDS = (100, 101, 102)  # the tables' three seeds: every experiment's default
T = TypeVar("T")


def comma_list(cast: Callable[[str], T], what: str) -> Callable[[str], tuple[T, ...]]:
    """An argparse ``type=``: ``"a,b,c"`` as a tuple of distinct ``cast`` values (``what`` names one in the
    error, e.g. "integers")."""

    def convert(text: str) -> tuple[T, ...]:
        try:
            values = tuple(cast(part) for part in text.split(","))
        except ValueError:
            values = ()
        if not values or len(set(values)) != len(values):
            raise argparse.ArgumentTypeError(f"{text!r}: give distinct {what} separated by commas")
        return values

    return convert


def seed_list(text: str) -> tuple[int, ...]:
    """``--seeds 100,101,102``: distinct integers."""
    return comma_list(int, "integers, e.g. 100,101,102")(text)


def name_list(text: str) -> tuple[str, ...]:
    """``--scenes hotdog,hubble``: distinct non-empty names."""
    return comma_list(_name, "names, e.g. hotdog,hubble")(text)


def step_list(text: str) -> tuple[int, ...]:
    """``--steps 0,3,6``: distinct step numbers >= 0."""
    return comma_list(_step, "step numbers >= 0, e.g. 0,3,6")(text)


def _step(part: str) -> int:
    step = int(part)
    if step < 0:
        raise ValueError(f"step {step} < 0")
    return step


def _name(part: str) -> str:
    if not part.strip():
        raise ValueError("an empty name")
    return part.strip()


def setting_overrides(overrides: list[str]) -> list[str]:
    """The overrides that make a setting, in their order: ``paths.*`` (also ``+paths.*``, ``~paths.*``) says where
    files lie, not what is computed."""
    return [o for o in overrides if not o.lstrip("+~").startswith("paths.")]


def other_threads(folder: Path, threads: int, counts: set[int]) -> str | None:
    """Why ``folder`` takes no rows made with ``threads`` torch threads: its files were made with another count
    (``counts``: its setting's, or its rows'), and their numbers depend on it; None when it takes them."""
    other = sorted(counts - {threads})
    if not other:
        return None
    return (
        f"{folder} was made with --threads {'/'.join(map(str, other))}, not --threads {threads}: its numbers depend "
        f"on the thread count; pass --threads {other[0]} to add to it, or paths.results=DIR for another count"
    )


def portable(word: str) -> str:
    """A command's word as ``command.txt`` keeps it: an absolute path outside the repository (``paths.*=PATH``,
    ``--records PATH``) as ``DIR``, which names no folder of the machine it ran on."""
    key, _, value = word.rpartition("=")
    path = Path(value)
    if path.is_absolute() and not path.resolve().is_relative_to(REPO):
        return f"{key}=DIR" if key else "DIR"
    return word


def add_command(folder: Path, words: list[str]) -> None:
    """Add the command ``words`` (``portable``) to ``folder/command.txt`` (one per line, each once, in first-run
    order)."""
    path = folder / "command.txt"
    commands = (read_plain_file(path, MAX_FILE_BYTES) or b"").decode("utf-8", "replace").splitlines()
    line = shlex.join(portable(word) for word in words)
    atomic_write_text(path, "\n".join(dict.fromkeys([*commands, line])) + "\n")
