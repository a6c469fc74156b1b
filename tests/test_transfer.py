"""pipeline/experiments/transfer.py: which cpu verdicts hold at the paper's scale, on a small fixture of state
rows and on the committed paper states."""

import json
import math
import shutil

import pytest

from pipeline.experiments import transfer
from pipeline.tables.stats import Interval


def state(budget: str, step: int, gains: dict[str, float | None]) -> dict:
    """A state row holding NVF and each rival of ``gains``: 0 a same pick, None a differing pick without outcome."""
    contenders = {"nvf": {"pick": 0}} | {name: {"pick": 0 if g == 0 else 1} for name, g in gains.items()}
    outcomes = {name: {"gain": g} for name, g in gains.items() if g}
    return {
        "scene": "default",
        "seed": 100,
        "step": step,
        "budget": budget,
        "contenders": contenders,
        "outcomes": outcomes,
    }


def test_a_state_gains_nothing_where_the_picks_agree_and_is_unknown_without_an_outcome():
    row = state("paper", 2, {"fisherrf": 0.0, "cover": None, "wo_vis": -0.3})
    assert transfer.state_gain(row, "fisherrf") == 0.0
    assert transfer.state_gain(row, "cover") is None and transfer.state_gain(row, "warprf") is None
    assert transfer.state_gain(row, "wo_vis") == -0.3


@pytest.mark.parametrize(
    ("cpu", "paper", "verdict"),
    [
        ((0.3, 0.1, 0.5), (0.2, 0.05, 0.35), "holds"),
        ((0.3, 0.1, 0.5), (-0.2, -0.35, -0.05), "flips"),
        ((0.3, -0.1, 0.7), (-0.2, -0.35, -0.05), "flips"),
        ((0.3, 0.1, 0.5), (-0.2, -0.5, 0.1), "unknown at the paper's scale"),
        ((0.0, -0.1, 0.1), (0.2, 0.05, 0.35), "unknown at the cpu budget"),
        ((0.1, -0.1, 0.3), (0.1, math.nan, math.nan), "separated at neither"),
    ],
)
def test_verdicts(cpu, paper, verdict):
    assert transfer.transfer_verdict(Interval(*cpu, 3), Interval(*paper, 3)) == verdict


def test_rows_pair_each_paper_state_with_its_cpu_twin():
    """A rival's gains at the paper's states beside the same states' at the cpu budget; a state without its twin or
    without a gain at one scale is left out of both."""
    states = [
        state("paper", 2, {"fisherrf": 0.5, "cover": 0.0}),
        state("cpu", 2, {"fisherrf": 0.4, "cover": -0.1}),
        state("paper", 8, {"fisherrf": 0.7, "cover": None}),
        state("cpu", 8, {"fisherrf": 0.6, "cover": 0.2}),
        state("paper", 14, {"fisherrf": 0.6}),
        state("cpu", 14, {"fisherrf": 0.0}),
        state("paper", 20, {"fisherrf": 0.9}),  # no twin
    ]
    rows = {r["rival"]: r for r in transfer.transfer_rows(states)}
    fisher, cover = rows["fisherrf"], rows["cover"]
    assert (fisher["states"], fisher["paper_differ"], fisher["cpu_differ"], fisher["sign_agrees"]) == (3, 3, 2, 2)
    assert fisher["paper_gain"] == pytest.approx(0.6) and fisher["cpu_gain"] == pytest.approx(1.0 / 3)
    assert fisher["label"] == "FisherRF" and fisher["verdict"] == "unknown at the cpu budget"  # 0.4, 0.6, 0.0
    assert (cover["states"], cover["paper_differ"], cover["cpu_differ"], cover["sign_agrees"]) == (1, 0, 1, 0)
    assert "NVF against COVER" in transfer.sentence(cover)


def test_the_command_writes_the_table_of_the_committed_states(tmp_path, capsys):
    folder = tmp_path / "pilots" / "paper_states"
    folder.mkdir(parents=True)
    for name in ("states.jsonl", "setting.json"):
        shutil.copy(f"results/pilots/paper_states/{name}", folder)
    transfer.main([f"paths.results={tmp_path}"])
    rows = (folder / "transfer.csv").read_text().splitlines()
    assert rows[0].split(",") == list(transfer.COLUMNS) and any(r.startswith("wo_vis,w/o Vis.,") for r in rows)
    assert "NVF against w/o Vis." in (folder / "transfer.md").read_text()
    with pytest.raises(SystemExit) as exit_:
        transfer.main([f"paths.results={tmp_path / 'none'}"])
    assert exit_.value.code == 2 and "no states.jsonl" in capsys.readouterr().err
    assert json.loads((folder / "setting.json").read_text())["state_budget"] == "cpu"
