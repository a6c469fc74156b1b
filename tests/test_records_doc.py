"""scripts/records_doc.py: docs/RECORDS.md's keys are the record schema's (pipeline.records.schema), each field with
its docstring."""

import dataclasses
import importlib.util
from pathlib import Path

import pytest

from pipeline.config.key_help import field_docs
from pipeline.records.schema import RECORD_VERSION, Metrics, RunInfo, StepRow

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "records_doc.py"


def load():
    spec = importlib.util.spec_from_file_location("records_doc", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_committed_doc_is_the_one_the_schema_gives():
    """Regenerated from the schema, RECORDS.md's keys equal the committed ones (the prose around them is not
    touched); run ``python scripts/records_doc.py`` after changing the schema."""
    script = load()
    doc = script.DOC.read_text(encoding="utf-8")
    assert script.with_text(doc) == doc


def test_every_record_class_and_field_is_documented():
    """Each class a record holds (reached from run.json's and a row's) has a docstring and a table, each field a
    docstring of its own."""
    script = load()
    reached = [cls for cls, _ in script.classes()]
    assert reached[0] is StepRow and RunInfo in reached and Metrics in reached
    for cls in reached:
        assert cls.__doc__ and not cls.__doc__.startswith(cls.__name__ + "(")  # its own, not dataclass's signature
        undocumented = {field.name for field in dataclasses.fields(cls)} - set(field_docs(cls))
        assert not undocumented, (cls.__name__, undocumented)


def test_the_doc_follows_the_schema():
    script = load()
    text = script.text()
    assert f"Record version written today: **{RECORD_VERSION}**." in text
    lines = text.splitlines()
    assert any(
        line.startswith("| `n_views` | an integer from 1 to 1000000 | yes | Views the step trained on")
        for line in lines
    )
    assert any(line.startswith("| `psnr` | a number from 0 to 100 or null |") for line in lines)  # metrics.info's
    assert "| `train` | an object: stage name -> `StageSummary` |  |" in text
    assert "| `ground_truth` | an object, `GroundTruth` or null |  |" in text
    assert "- **1 → 2** (`version_1_to_2`)" in text
    with pytest.raises(ValueError, match="needs one"):
        script.with_text("no markers here")
