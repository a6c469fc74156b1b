"""pipeline/records/experiment_columns.py: the experiments' CSV columns, declared once for their writers and
readers, describe every committed file of their kind."""

from pathlib import Path

import pytest

from pipeline.experiments import budget_curve, discriminate, duel_summary, visibility_summary
from pipeline.records.checked_files import Optional, read_csv
from pipeline.records.experiment_columns import (
    DISCRIMINATE_PER_SEED_COLUMNS,
    DISCRIMINATE_SUMMARY_COLUMNS,
    DUEL_DETAIL_COLUMNS,
    DUEL_SUMMARY_COLUMNS,
    STUDY_SUMMARY_COLUMNS,
    STUDY_SURFACE_COLUMNS,
)
from pipeline.tables import site

PILOTS = Path(__file__).resolve().parents[1] / "results" / "pilots"
FILES = [
    ("duel/summary.csv", DUEL_SUMMARY_COLUMNS),
    ("duel/details.csv", DUEL_DETAIL_COLUMNS),
    ("visibility_study/summary.csv", STUDY_SUMMARY_COLUMNS),
    ("visibility_study/surface.csv", STUDY_SURFACE_COLUMNS),
    *((str(p.relative_to(PILOTS)), DISCRIMINATE_SUMMARY_COLUMNS) for p in PILOTS.glob("discriminate/*/summary.csv")),
    *((str(p.relative_to(PILOTS)), DISCRIMINATE_PER_SEED_COLUMNS) for p in PILOTS.glob("discriminate/*/per_seed.csv")),
]


def test_writers_and_readers_take_their_columns_from_one_declaration():
    assert duel_summary.COLUMNS == tuple(DUEL_SUMMARY_COLUMNS) and site.DUEL_COLUMNS is DUEL_SUMMARY_COLUMNS
    assert duel_summary.DETAIL_COLUMNS == tuple(DUEL_DETAIL_COLUMNS)
    assert visibility_summary.COLUMNS == tuple(STUDY_SUMMARY_COLUMNS)
    assert visibility_summary.SURFACE_COLUMNS == tuple(STUDY_SURFACE_COLUMNS)
    assert discriminate.SUMMARY_COLUMNS == tuple(DISCRIMINATE_SUMMARY_COLUMNS)
    assert budget_curve.SUMMARY is DISCRIMINATE_SUMMARY_COLUMNS
    for reader in (discriminate.PER_SEED, visibility_summary.PER_SEED):
        assert all(DISCRIMINATE_PER_SEED_COLUMNS[name] is shape for name, shape in reader.items())


@pytest.mark.parametrize(("name", "columns"), FILES, ids=[name for name, _ in FILES])
def test_every_committed_experiment_file_has_its_declared_columns(name, columns):
    """Its header is the declaration's columns in order (an ``Optional`` one may be missing: the oldest files) and
    every cell reads back within its declared shape."""
    path = PILOTS / name
    header = path.read_text().splitlines()[0].split(",")
    assert header == [c for c, shape in columns.items() if c in header or not isinstance(shape, Optional)]
    assert read_csv(path, columns) is not None
