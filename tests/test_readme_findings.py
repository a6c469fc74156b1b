"""scripts/readme_findings.py: README.md's findings are the ones the committed summaries give, and the README stays
a page a newcomer reads."""

import importlib.util
from pathlib import Path

import pandas as pd

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "readme_findings.py"
MAX_LINES = 120


def load():
    spec = importlib.util.spec_from_file_location("readme_findings", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_committed_findings_are_the_ones_the_summaries_give():
    """Regenerated from the duel's summary and the transfer table, the README's findings equal the committed ones:
    a figure edited by hand, or a summary changed without ``python scripts/readme_findings.py``, fails here."""
    script = load()
    doc = script.DOC.read_text(encoding="utf-8")
    assert script.with_findings(doc) == doc
    assert len(doc.splitlines()) <= MAX_LINES
    duel_doc = script.DUEL_DOC.read_text(encoding="utf-8")
    assert script.with_findings(duel_doc, script.DUEL_DOC) == duel_doc


def test_an_edited_figure_is_caught():
    script = load()
    doc = script.DOC.read_text(encoding="utf-8")
    line = next(line for line in doc.splitlines() if line.startswith("- **FisherRF**"))
    edited = doc.replace(line, line.replace("dB", "dB (edited)", 1))
    assert script.with_findings(edited) == doc


def test_a_line_per_pooled_rival_and_its_paper_scale_verdict():
    script = load()
    duel = pd.read_csv(script.DUEL)
    lines = script.findings().splitlines()
    assert len([line for line in lines if not line.startswith("- Room")]) == (duel["scene"] == "all").sum()
    assert any("at the paper's scale" in line and "not measured" not in line for line in lines)
    assert (
        script.interval(0.1234, -0.5, 0.75) == "+0.12 [-0.50, +0.75]"
        and script.interval(0.1, float("nan"), 1) == "+0.10"
    )


def test_the_coverage_pilots_figures_are_the_ones_the_records_give():
    """results/pilots/uncertainty_vs_coverage: its episodes.txt and its README's tables and figures equal what
    ``scripts/pilots/uncertainty_vs_coverage.py`` computes from the committed records (a record remade, or a figure
    edited by hand, without running it fails here)."""
    path = SCRIPT.parent / "pilots" / "uncertainty_vs_coverage.py"
    spec = importlib.util.spec_from_file_location("uncertainty_vs_coverage", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.main(["--check"]) == 0
    doc = module.DOC.read_text(encoding="utf-8")
    edited = doc.replace("| NVF | ", "| NVF | +9.99 ", 1)
    found = {baseline: module.differences(baseline) for baseline in module.COVERAGE}
    regenerated = module.generated_section.with_section(edited, module.BEGIN, module.END, module.section(found), path)
    assert edited != doc and regenerated == doc
