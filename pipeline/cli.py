"""The command-line convention every entry point follows: config values as Hydra-style ``key=value``
overrides (``paths.assets=DIR``, ``paths.results=DIR``), argparse only for what is not config, ``--help``
from the module's docstring, and bad input as one ``error: ...`` line on stderr with exit status 2.

Every command's ``main`` runs through ``run_command``: the errors a user can cause (``BadInput``: a bad
argument, config, record, scene or path; OmegaConf's and Hydra's errors for an override they cannot resolve;
an ``OSError`` on a path) are one ``error:`` line and exit status 2, a run that failed (``Failed``) is one
line and status 1, and anything else is a bug: its traceback is kept. Every count a user gives is bounded
(``bounded``: one line naming the range), threads by the cores the process may run on (``cores``)."""

import argparse
import os
import re
import sys
from collections.abc import Callable
from typing import NoReturn

from hydra.errors import HydraException
from omegaconf.errors import OmegaConfBaseException

BAD_INPUT = 2  # exit status of every command for bad input (a config, a scene, an argument)
FAILED = 1  # exit status of a run that failed (its reason recorded)
INTERRUPTED = 130
LITERAL = re.compile(r"``(.+?)``", re.DOTALL)


class BadInput(Exception):
    """Input a command cannot use (an argument, a config value, a record, a scene, a path): its message is one
    line saying what, where and how to fix it. The command's own error types derive from it."""


class Failed(Exception):
    """A run that failed (its reason is the one-line message); the command exits with ``FAILED``."""


def plain(text: str) -> str:
    """A docstring as a terminal shows it: ````code```` marks dropped."""
    return LITERAL.sub(r"\1", text)


def description(doc: str | None) -> str:
    """The first paragraph of a module docstring, as one plain line (argparse's description)."""
    return " ".join(plain(doc or "").strip().split("\n\n")[0].split())


def help_page(doc: str | None) -> str:
    """A whole module docstring as a ``--help`` page: plain text, its paragraphs and lists kept."""
    return plain(doc or "").strip()


def error_line(err: BaseException) -> str:
    """``err`` and its cause as one ``error: ...`` line, without Hydra's config search path and OmegaConf's
    ``full_key: ... object_type=...`` trailer; an ``OSError`` names its file, an OmegaConf error the key whose
    value it could not resolve, and both what to do."""
    key = getattr(err, "full_key", None)
    if isinstance(err, OSError) and not isinstance(err, HydraException):  # Hydra's missing config is an OSError too
        where = f"{err.filename}: " if err.filename is not None else ""
        message = f"{where}{err.strerror or err}; give a path this command can read and write"
    elif isinstance(err, OmegaConfBaseException) and key:
        message = f"{key}: {str(err).split('full_key:')[0].strip()}; correct the value given for {key}"
    else:
        cause = f": {err.__cause__}" if err.__cause__ is not None else ""
        message = f"{err}{cause}".split("Config search path:")[0].split("full_key:")[0]
    return f"error: {' '.join(message.split())}"


def fail(message: str) -> NoReturn:
    """Print ``error: <message>`` (one line) on stderr and exit with ``BAD_INPUT``."""
    print(f"error: {' '.join(str(message).split())}", file=sys.stderr)
    raise SystemExit(BAD_INPUT)


def bounded(name: str, value: int, low: int, high: int, what: str = "") -> int:
    """``value`` (given as ``name``, e.g. ``--sets``) when it lies in ``low..high``, else ``fail`` saying the range
    and, in ``what``, where the bound comes from (e.g. "this machine's cores")."""
    if not low <= value <= high:
        fail(f"{name} {value}: must be {low}..{high}" + (f" ({what})" if what else ""))
    return value


def cores() -> int:
    """The cores this process may run on (its CPU affinity, not the machine's count)."""
    return len(os.sched_getaffinity(0))


def exit_with(err: BaseException) -> NoReturn:
    """Print ``err`` (one of ``EXPECTED``) as its ``error:`` line and exit with ``FAILED`` for a ``Failed``, else
    ``BAD_INPUT``."""
    print(error_line(err), file=sys.stderr)
    raise SystemExit(FAILED if isinstance(err, Failed) else BAD_INPUT) from None


def run_command(main: Callable[..., int | None], *args: object) -> NoReturn:
    """Run a command's ``main(*args)`` and exit with its status (0 for None): an ``EXPECTED`` error is one
    ``error:`` line (``exit_with``: ``Failed`` exits with ``FAILED``, bad input with ``BAD_INPUT``); Ctrl-C exits
    with ``INTERRUPTED``. Any other exception is a bug and keeps its traceback."""
    try:
        status = main(*args)
    except EXPECTED as err:
        exit_with(err)
    except KeyboardInterrupt:
        print("\ninterrupted", file=sys.stderr)
        raise SystemExit(INTERRUPTED) from None
    raise SystemExit(status or 0)


EXPECTED = (BadInput, Failed, OmegaConfBaseException, HydraException, OSError)  # one line, not a traceback


class ArgumentParser(argparse.ArgumentParser):
    """argparse whose errors (an unknown option, a missing argument) follow the convention: one line and
    ``BAD_INPUT``, not argparse's usage block."""

    def error(self, message: str) -> NoReturn:
        fail(f"{self.prog}: {message} (see --help)")
