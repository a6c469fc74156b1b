"""The shape of the code itself: module names that say what they hold, each once."""

import dataclasses
from collections import defaultdict
from pathlib import Path

import pytest

from nvf.methods import NVF, Method
from pipeline.config.catalog import method_configs
from pipeline.config.method import PRESENTATION_KEYS, MethodError, build_method, presentation

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


def test_results_hold_data_and_notes_not_code():
    """``results/`` holds records, tables, READMEs and the commands that made them; a pilot's own code lives in
    ``scripts/pilots/`` (linted and type-checked with the rest), never beside its data."""
    code = sorted(str(p.relative_to(REPO)) for p in (REPO / "results").rglob("*.py"))
    assert not code, code


def test_the_method_library_knows_nothing_of_tables():
    """How results show a method (its label, row order, the experiments it joins) is the harness's: a method
    yaml declares it beside the method's own keys, ``build_method`` checks it, and no ``nvf.methods.Method``
    field holds it."""
    assert set(PRESENTATION_KEYS) == {"label", "rank", "experiments"}
    assert not {f.name for f in dataclasses.fields(Method)} & set(PRESENTATION_KEYS)
    node = method_configs()["nvf"]
    assert isinstance(build_method(node), NVF) and presentation(node).label == "NVF"
    for key, value, says in (("rank", "first", "method.rank='first' must be a int"), ("label", None, "is missing")):
        changed = {k: v for k, v in node.items() if k != key} | ({key: value} if value is not None else {})
        with pytest.raises(MethodError, match=says):
            build_method(changed)
