"""The command-line convention every entry point follows: config values as Hydra-style ``key=value``
overrides (``paths.assets=DIR``, ``paths.results=DIR``), argparse only for what is not config, ``--help``
from the module's docstring, and bad input as one ``error: ...`` line on stderr with exit status 2."""

import sys
from typing import NoReturn

BAD_INPUT = 2  # exit status of every command for bad input (a config, a scene, an argument)


def description(doc: str | None) -> str:
    """The first paragraph of a module docstring, as one line (argparse's description)."""
    return " ".join((doc or "").strip().split("\n\n")[0].split())


def fail(message: str) -> NoReturn:
    """Print ``error: <message>`` (one line) on stderr and exit with ``BAD_INPUT``."""
    print(f"error: {' '.join(str(message).split())}", file=sys.stderr)
    raise SystemExit(BAD_INPUT)
