"""``python -m pipeline.bench NAME [args]``: run the benchmark module ``pipeline/bench/NAME.py``.

Each benchmark is a module of this package exposing ``main(argv: list[str]) -> None``; adding a
benchmark is adding a module. A missing or unknown name is one ``error:`` line on stderr and exit status 2.
"""

import importlib
import pkgutil
import sys
from pathlib import Path

from pipeline.cli import fail


def available() -> list[str]:
    """Names of the benchmark modules in this package."""
    return sorted(m.name for m in pkgutil.iter_modules([str(Path(__file__).parent)]) if not m.name.startswith("_"))


def main(argv: list[str]) -> None:
    names = available()
    usage = f"python -m pipeline.bench {{{','.join(names)}}} [args]"
    if not argv:
        fail(f"name a benchmark: {usage}")
    if argv[0] in ("-h", "--help"):
        print(f"usage: {usage}")
        raise SystemExit(0)
    if argv[0] not in names:
        fail(f"unknown benchmark '{argv[0]}'; choose one of: {', '.join(names)}")
    importlib.import_module(f"pipeline.bench.{argv[0]}").main(argv[1:])


if __name__ == "__main__":
    main(sys.argv[1:])
