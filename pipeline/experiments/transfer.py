"""Which of the cpu budget's verdicts hold at the paper's scale: ``python -m pipeline.experiments.transfer
[paths.results=DIR] [--pool FOLDER ...]`` writes ``transfer.csv`` and ``transfer.md`` beside the paper states'
``states.jsonl`` (``${paths.results}/pilots/paper_states/``; ``--pool``: the states of folders of another ground
truth too, as ``paper_states_summary --pool`` takes them).

For each rival of NVF and each scale (``paper``: the states trained at the paper's budget; ``cpu``: their twins,
the same states at the cpu budget), a state's gain is NVF's pick's one-step outcome minus the rival's (held-out
PSNR, dB), 0 where both pick the same candidate (the same view: the same outcome); a state whose rival was not
scored, or whose differing picks have no outcome, is left out. Over the states that have a gain at both scales:
``states``, at each scale ``<scale>_differ`` (states whose picks differ), ``<scale>_gain`` with its paired 95%
Student-t interval (``<scale>_low``, ``<scale>_high``), ``sign_agrees`` (states whose gain has the same sign at
both scales, a same pick's 0 counting as a sign) and ``verdict`` (``transfer_verdict``): whether the cpu budget's
verdict holds at the paper's scale, flips, or is unknown at one of them.
"""

import sys
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.atomic_write import atomic_write_text
from pipeline.cli import ArgumentParser, description, fail, run_command
from pipeline.config.catalog import contender_label
from pipeline.config.validation import compose_run
from pipeline.experiments.paper_states_summary import FOLDER, pooled_states
from pipeline.tables.escape import as_csv
from pipeline.tables.stats import Interval
from pipeline.tables.table_formats import markdown_table

SCALES = ("paper", "cpu")
COLUMNS = (
    "rival", "label", "states", "paper_differ", "paper_gain", "paper_low", "paper_high", "cpu_differ", "cpu_gain",
    "cpu_low", "cpu_high", "sign_agrees", "verdict",
)  # fmt: skip
HOLDS, FLIPS = "holds", "flips"
UNKNOWN_PAPER, UNKNOWN_CPU, NEITHER = (
    "unknown at the paper's scale",
    "unknown at the cpu budget",
    "separated at neither",
)


def state_gain(row: Mapping, rival: str) -> float | None:
    """NVF's pick's outcome minus ``rival``'s at a state row (0 for the same pick), or None where unknown."""
    held = row["contenders"]
    if rival not in held:
        return None
    if held[rival]["pick"] == held["nvf"]["pick"]:
        return 0.0
    outcome = row["outcomes"].get(rival)
    return None if outcome is None else float(outcome["gain"])


def side(interval: Interval) -> int:
    """+1 where the interval lies above zero, -1 below, 0 where it holds zero or is undefined."""
    return 1 if interval.low > 0 else -1 if interval.high < 0 else 0


def transfer_verdict(cpu: Interval, paper: Interval) -> str:
    """``holds`` (both scales separate, the same way), ``flips`` (both separate, opposite ways; or the paper's
    interval excludes the cpu mean's side), ``unknown at the paper's scale`` (the cpu budget separates, the paper's
    states do not), ``unknown at the cpu budget`` (the reverse) or ``separated at neither``."""
    at_cpu, at_paper = side(cpu), side(paper)
    if at_cpu and at_paper:
        return HOLDS if at_cpu == at_paper else FLIPS
    if at_paper and np.sign(cpu.mean) == -at_paper:
        return FLIPS
    if at_cpu:
        return UNKNOWN_PAPER
    return UNKNOWN_CPU if at_paper else NEITHER


def transfer_rows(states: list[dict]) -> list[dict]:
    """The rows of ``transfer.csv``: one per rival any paper state scored, in the order the rows name them."""
    twins = {(r["scene"], r["seed"], r["step"]): r for r in states if r["budget"] == "cpu"}
    papers = [r for r in states if r["budget"] == "paper"]
    rivals = list(dict.fromkeys(name for r in papers for name in r["contenders"] if name != "nvf"))
    out = []
    for rival in rivals:
        pairs = []
        for row in papers:
            twin = twins.get((row["scene"], row["seed"], row["step"]))
            gains = (state_gain(row, rival), None if twin is None else state_gain(twin, rival))
            if None not in gains:
                pairs.append(gains)
        if not pairs:
            continue
        found = np.array(pairs, dtype=float)
        paper, cpu = Interval.of(found[:, 0]), Interval.of(found[:, 1])
        out.append(
            {
                "rival": rival,
                "label": contender_label(rival),
                "states": len(pairs),
                "paper_differ": int((found[:, 0] != 0).sum()),
                "paper_gain": paper.mean,
                "paper_low": paper.low,
                "paper_high": paper.high,
                "cpu_differ": int((found[:, 1] != 0).sum()),
                "cpu_gain": cpu.mean,
                "cpu_low": cpu.low,
                "cpu_high": cpu.high,
                "sign_agrees": int((np.sign(found[:, 0]) == np.sign(found[:, 1])).sum()),
                "verdict": transfer_verdict(cpu, paper),
            }
        )
    return out


def _interval(mean: float, low: float, high: float) -> str:
    if not np.isfinite(mean):
        return "-"
    if not np.isfinite(low):
        return f"{mean:+.2f}"
    return f"{mean:+.2f} [{low:+.2f}, {high:+.2f}]"


def sentence(row: Mapping) -> str:
    """One sentence of a rival's verdict at both scales, for the README, the duel's README and the site."""
    return (
        f"NVF against {row['label']}: {_interval(row['cpu_gain'], row['cpu_low'], row['cpu_high'])} dB at the cpu "
        f"budget, {_interval(row['paper_gain'], row['paper_low'], row['paper_high'])} dB at the paper's scale over "
        f"the same {row['states']} states (picks differ at {row['cpu_differ']} and {row['paper_differ']}; the sign "
        f"agrees at {row['sign_agrees']}): {row['verdict']}."
    )


def write_transfer(folder: Path, pooled: list[Path]) -> list[Path]:
    """``transfer.csv`` and ``transfer.md`` in ``folder`` over its states and ``pooled``'s."""
    states, sources = pooled_states(folder, pooled)
    rows = transfer_rows(states)
    table = pd.DataFrame(rows, columns=list(COLUMNS))
    csv_path, md_path = folder / "transfer.csv", folder / "transfer.md"
    atomic_write_text(csv_path, as_csv(table, ("rival",), "%.4f"))
    cells = [
        [
            row["label"],
            str(row["states"]),
            f"{row['cpu_differ']}",
            _interval(row["cpu_gain"], row["cpu_low"], row["cpu_high"]),
            f"{row['paper_differ']}",
            _interval(row["paper_gain"], row["paper_low"], row["paper_high"]),
            str(row["sign_agrees"]),
            row["verdict"],
        ]
        for row in rows
    ]
    header = ["rival", "states", "differ (cpu)", "NVF's gain, cpu (dB)", "differ (paper)", "NVF's gain, paper (dB)"]
    text = [
        "# Which cpu verdicts hold at the paper's scale",
        "",
        f"Written by `python -m pipeline.experiments.transfer` from {' and '.join(sources)}. A state's gain is "
        "NVF's pick's one-step held-out PSNR minus the rival's (0 where they pick the same view); intervals are "
        "paired 95% Student-t over the states that have a gain at both scales.",
        "",
        *markdown_table([*header, "same sign", "verdict"], cells, left=1),
        "",
        *(f"- {sentence(row)}" for row in rows),
    ]
    atomic_write_text(md_path, "\n".join(text) + "\n")
    return [csv_path, md_path]


def main(argv: list[str]) -> None:
    parser = ArgumentParser(prog="python -m pipeline.experiments.transfer", description=description(__doc__))
    parser.add_argument("overrides", nargs="*", help="paths.results=DIR")
    parser.add_argument(
        "--pool", action="append", type=Path, default=[], metavar="FOLDER", help="another folder's states too"
    )
    args = parser.parse_intermixed_args(argv)
    folder = Path(compose_run(args.overrides).paths.results) / "pilots" / FOLDER
    for where in [folder, *args.pool]:
        if not (where / "states.jsonl").is_file():
            fail(f"{where}: no states.jsonl; run the paper_states command first")
    for path in write_transfer(folder, args.pool):
        print(f"wrote {path}")


if __name__ == "__main__":
    run_command(main, sys.argv[1:])
