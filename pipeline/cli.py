"""The command-line convention every entry point follows: config values as Hydra-style ``key=value``
overrides (``paths.assets=DIR``, ``paths.results=DIR``), argparse only for what is not config, ``--help``
from the module's docstring, and bad input as one ``error: ...`` line on stderr with exit status 2."""

import argparse
import re
import sys
from typing import NoReturn

BAD_INPUT = 2  # exit status of every command for bad input (a config, a scene, an argument)
LITERAL = re.compile(r"``(.+?)``", re.DOTALL)


def plain(text: str) -> str:
    """A docstring as a terminal shows it: ````code```` marks dropped."""
    return LITERAL.sub(r"\1", text)


def description(doc: str | None) -> str:
    """The first paragraph of a module docstring, as one plain line (argparse's description)."""
    return " ".join(plain(doc or "").strip().split("\n\n")[0].split())


def help_page(doc: str | None) -> str:
    """A whole module docstring as a ``--help`` page: plain text, its paragraphs and lists kept."""
    return plain(doc or "").strip()


def fail(message: str) -> NoReturn:
    """Print ``error: <message>`` (one line) on stderr and exit with ``BAD_INPUT``."""
    print(f"error: {' '.join(str(message).split())}", file=sys.stderr)
    raise SystemExit(BAD_INPUT)


class ArgumentParser(argparse.ArgumentParser):
    """argparse whose errors (an unknown option, a missing argument) follow the convention: one line and
    ``BAD_INPUT``, not argparse's usage block."""

    def error(self, message: str) -> NoReturn:
        fail(f"{self.prog}: {message} (see --help)")
