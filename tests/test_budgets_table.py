"""scripts/budgets_table.py: docs/BUDGETS.md's table of values is the one the config gives."""

import importlib.util
from pathlib import Path

import pytest

from pipeline.config.catalog import declared

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "budgets_table.py"


def load():
    spec = importlib.util.spec_from_file_location("budgets_table", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_committed_table_is_the_one_the_budgets_give():
    """Regenerated from conf/budget/*.yaml and the schema's defaults, the table equals the committed one (the
    reasons around it are not touched); run ``python scripts/budgets_table.py`` after changing a budget."""
    script = load()
    doc = script.DOC.read_text(encoding="utf-8")
    assert script.with_table(doc) == doc
    assert set(script.BUDGETS) == set(declared("budget"))  # every budget has its column


def test_the_table_follows_the_config():
    script = load()
    paper, cpu = script.budget_values("paper"), script.budget_values("cpu")
    assert paper["budget"]["image_size"] == 512 and cpu["budget"]["image_size"] == 64  # schema default, cpu's yaml
    assert paper["render"]["backend"] == "blender" and cpu["render"]["backend"] == "pyrender"
    rows = {line.split(" | ")[0].lstrip("| "): line for line in script.table().splitlines()}
    assert rows["horizon, steps"] == "| horizon, steps | 20 | 20 | 3 |"
    assert "(**1e-2**)" in rows["variance head iterations × rays (lr)"]  # cpu's head lr departs from the paper's
    with pytest.raises(ValueError, match="needs one"):
        script.with_table("no markers here")
