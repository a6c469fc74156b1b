"""What the experiment commands share on their command lines: the tables' seeds and comma-separated lists,
as argparse ``type=`` converters (a bad list is argparse's one ``error:`` line, ``pipeline.cli``)."""

import argparse
from collections.abc import Callable
from typing import TypeVar

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
