"""The shape of the code itself: module names that say what they hold, each once."""

from collections import defaultdict
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("nvf", "pipeline")
SHARED = {"__init__.py", "__main__.py"}  # every package has its own


def test_no_two_modules_share_a_file_name():
    """A module's file name is unique across nvf/ and pipeline/ (``__init__`` and ``__main__`` aside), so a name
    in a traceback, a doc or an import points at one file."""
    where = defaultdict(list)
    for package in PACKAGES:
        for path in (REPO / package).rglob("*.py"):
            if path.name not in SHARED:
                where[path.name].append(str(path.relative_to(REPO)))
    shared = {name: paths for name, paths in where.items() if len(paths) > 1}
    assert not shared, shared
