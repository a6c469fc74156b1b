"""A doc's generated section: the text between a begin and an end marker comment, rewritten by a script (the prose
around it stays as written) or compared with what the script would write (``--check``). Shared by
``scripts/budgets_table.py`` and ``scripts/records_doc.py``."""

import sys
from collections.abc import Callable
from pathlib import Path


def with_section(doc: str, begin: str, end: str, body: str, name: Path) -> str:
    """``doc`` with ``body`` between its ``begin`` and ``end`` lines; a ValueError naming ``name`` when the markers
    are missing, repeated or out of order."""
    if doc.count(begin) != 1 or doc.count(end) != 1 or doc.index(begin) > doc.index(end):
        raise ValueError(f"{name}: needs one {begin!r} line and one {end!r} line after it")
    head, rest = doc.split(begin + "\n", 1)
    _, tail = rest.split(end, 1)
    return f"{head}{begin}\n\n{body}\n{end}{tail}"  # blank lines: the comments are blocks of their own


def main(argv: list[str], doc_path: Path, expected: Callable[[str], str], script: str, what: str) -> int:
    """Rewrite ``doc_path`` to ``expected(doc)`` (no arguments) or, with ``--check``, exit 1 naming the first line
    where ``what`` differs; 2 with a usage line for any other argument."""
    doc = doc_path.read_text(encoding="utf-8")
    wanted = expected(doc)
    if argv == ["--check"]:
        if wanted == doc:
            return 0
        new, old = wanted.splitlines(), doc.splitlines()
        first = next((i for i, (a, b) in enumerate(zip(new, old, strict=False)) if a != b), min(len(new), len(old)))
        print(f"{doc_path}: {what} at line {first + 1}; run {script}")
        return 1
    if argv:
        print(f"usage: python {script} [--check]", file=sys.stderr)
        return 2
    doc_path.write_text(wanted, encoding="utf-8")
    print(f"wrote {doc_path}")
    return 0
