"""``python -m pipeline.bench NAME [args]``: run the benchmark NAME, a module of this package; its report goes to
``${paths.results}/bench/`` and ``python -m pipeline.bench NAME --help`` lists its options.

Each benchmark is a module of this package exposing ``main(argv: list[str]) -> None``; adding a
benchmark is adding a module. Its command is the module's name, or the shorter name ``COMMANDS`` gives it
(``field`` runs ``field_throughput.py``). A missing or unknown name is one ``error:`` line on stderr and exit
status 2.
"""

import ast
import importlib
import pkgutil
import sys
import textwrap
from pathlib import Path

from pipeline.cli import description, fail, run_command

# module -> its command, where the command is shorter than the module's name (a name that says what the module
# measures; the command names stay as they were)
COMMANDS = {
    "device_facts": "device",
    "field_throughput": "field",
    "ground_truth_speed": "render",
    "visibility_diagnostic": "visibility",
}


def modules() -> dict[str, str]:
    """Each benchmark's command -> its module in this package."""
    found = [m.name for m in pkgutil.iter_modules([str(Path(__file__).parent)]) if not m.name.startswith("_")]
    return {COMMANDS.get(name, name): name for name in found}


def available() -> list[str]:
    """The benchmarks' command names."""
    return sorted(modules())


def help_page(names: list[str]) -> str:
    """Usage, what the command does, and each benchmark's first docstring paragraph (read without importing it)."""
    lines = [
        f"usage: python -m pipeline.bench {{{','.join(names)}}} [args]",
        "",
        *textwrap.wrap(description(__doc__), 100),
    ]
    lines += ["", "benchmarks:"]
    for name in names:
        module = modules()[name]
        doc = ast.get_docstring(ast.parse((Path(__file__).parent / f"{module}.py").read_text(encoding="utf-8")))
        lines += textwrap.wrap(description(doc), 100, initial_indent=f"  {name:<11} ", subsequent_indent=" " * 14)
    return "\n".join(lines)


def main(argv: list[str]) -> None:
    names = available()
    if not argv:
        fail(f"name a benchmark: python -m pipeline.bench {{{','.join(names)}}} [args] (--help describes each)")
    if argv[0] in ("-h", "--help"):
        print(help_page(names))
        raise SystemExit(0)
    if argv[0] not in names:
        fail(f"unknown benchmark '{argv[0]}'; choose one of: {', '.join(names)}")
    importlib.import_module(f"pipeline.bench.{modules()[argv[0]]}").main(argv[1:])


if __name__ == "__main__":
    run_command(main, sys.argv[1:])
