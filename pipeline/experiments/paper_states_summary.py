"""The tables of ``python -m pipeline.experiments.paper_states``, from its ``states.jsonl``; the shapes of its
files as they are read back (``STATE``, ``SETTING``).

``summary.csv``: a row per budget, scene (and ``all``, over the scenes) and rival of NVF the states hold (w/o
Vis., FisherRF, ActiveNeRF, and any contender a call added): ``states``; ``spearman_mean, spearman_low,
spearman_high`` (the rank correlation of NVF's and the rival's scores over a state's candidates: the mean over the
states, and a 95% Student-t interval over them taken on Fisher's z, ``correlation_interval``);
``same_pick`` (the share of states where both pick the same candidate); ``nvf_relative_std`` and
``rival_relative_std`` (the mean over states of each score's standard deviation over its mean's magnitude:
near 0, a flat score); ``auc_labels`` and ``auc_head`` (mean over states of the labels' and NVF's head's AUC
against the mesh's line of sight); ``outcomes, gain_mean, gain_low, gain_high`` (where the picks differ and the
outcome was taken: NVF's pick's held-out PSNR minus the rival's, dB, interval over those states) and
``state_hours`` (mean wall-clock hours of a whole state at that budget, times its torch threads).

``summary.md``: the same table, and beneath it each paper-budget row beside its cpu-budget twin.
``python -m pipeline.experiments.paper_states_summary [paths.results=DIR]`` rewrites both.

``--pool FOLDER`` (repeatable: folders of the same command made with another setting, e.g. pyrender's ground truth):
also ``pooled.csv`` and ``pooled.md``, the same tables over this folder's states and theirs together (a state
held twice is refused), headed by where each state came from; the command's own runs rewrite ``summary.*``
only.
"""

import sys
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.atomic_write import atomic_write_text
from pipeline.cli import ArgumentParser, description, fail, run_command
from pipeline.config.validation import compose_run
from pipeline.experiments.provenance import MADE_WITH, SOURCE_RECORD
from pipeline.experiments.row_files import EXTENDS, current_rows, row_digest
from pipeline.records.checked_files import Each, Entries, Number, Optional, Text, read_json, read_json_lines
from pipeline.records.files import RecordError
from pipeline.records.schema import MAX_HORIZON
from pipeline.records.store import MAX_SEED
from pipeline.tables.escape import as_csv
from pipeline.tables.stats import Interval
from pipeline.tables.table_formats import markdown_table

FOLDER = "paper_states"
ALL = "all"
SETTING = {
    "overrides": Each(Text()),
    "state_budget": Text(),
    "threads": Optional(Number(1, 4096, integer=True)),
    "vis_points": Optional(Number(1, 1 << 20, integer=True)),
}
LEGACY_VIS_POINTS = 4096  # what a setting written before it held ``vis_points`` was made with (its rows say so)
SPREAD = {
    "count": Number(0, 1 << 31, integer=True),
    "min": Number(),
    "mean": Number(),
    "max": Number(),
    "std": Number(0.0),
    "ties_at_max": Number(0, 1 << 31, integer=True),
    "relative_std": Number(0.0, null=True),
}
MAX_SECONDS = 1e7  # about 116 days: no state takes longer
SECONDS = {"train": Number(0.0, MAX_SECONDS), "prepare": Number(0.0, MAX_SECONDS), "score": Number(0.0, MAX_SECONDS)}
STATE = {
    "scene": Text(),
    "seed": Number(0, MAX_SEED, integer=True),
    "step": Number(0, MAX_HORIZON, integer=True),
    "budget": Text(),
    "state_budget": Text(),
    "source": Text(),
    "ground_truth": Text(),
    "views": Number(1, 1 << 16, integer=True),
    "candidates": Number(1, 1 << 31, integer=True),
    "threads": Number(1, 4096, integer=True),
    "made_with": Optional(MADE_WITH),
    "source_record": Optional(SOURCE_RECORD),
    "extends": Optional(Text()),
    "contenders": Entries(
        {
            "pick": Number(0, 1 << 31, integer=True),
            "pose": Optional(Each(Number())),
            "reused": Optional(bool),
            "spread": SPREAD,
            "shared_training": bool,
            "seconds": SECONDS,
        },
        required=("nvf",),
    ),
    "against_nvf": Entries({"spearman": Number(-1.0, 1.0, null=True), "same_pick": bool}),
    "visibility": {
        "points": Number(1, 1 << 31, integer=True),
        "seen_fraction": Number(0.0, 1.0),
        "auc_labels": Number(0.0, 1.0, null=True),
        "auc_head": Number(0.0, 1.0, null=True),
    },
    "outcomes": Entries(
        {
            "nvf_psnr": Number(0.0, 100.0),
            "rival_psnr": Number(0.0, 100.0),
            "gain": Number(-100.0, 100.0),
            "seconds": Number(0.0, MAX_SECONDS),
            "reused": Optional(Each(Text())),
        }
    ),
    "seconds": Number(0.0, MAX_SECONDS),
}


def state_key(row: dict) -> tuple:
    """A state row's identity: its scene, seed, step and budget (``states.jsonl`` holds one row of each)."""
    return row["scene"], row["seed"], row["step"], row["budget"]


COLUMNS = (
    "budget", "scene", "rival", "states", "spearman_mean", "spearman_low", "spearman_high", "same_pick",
    "nvf_relative_std", "rival_relative_std", "auc_labels", "auc_head", "outcomes", "gain_mean", "gain_low",
    "gain_high", "state_hours",
)  # fmt: skip


def correlation_interval(values: np.ndarray) -> tuple[float, float, float]:
    """Mean of correlations with a 95% interval over them, taken on Fisher's z (``atanh``, the scale on which a
    correlation's error is about normal) and mapped back, so it stays inside [-1, 1]."""
    values = values[np.isfinite(values)]
    if len(values) == 0:
        return float("nan"), float("nan"), float("nan")
    z = Interval.of(np.arctanh(np.clip(values, -1 + 1e-9, 1 - 1e-9)))
    return float(values.mean()), float(np.tanh(z.low)), float(np.tanh(z.high))


def _mean(values: list) -> float:
    kept = [v for v in values if v is not None]
    return float(np.mean(kept)) if kept else float("nan")


def summary_rows(states: list[dict]) -> list[dict]:
    """The ``summary.csv`` rows of the module docstring."""
    out = []
    budgets = sorted({r["budget"] for r in states}, key=lambda b: (b != "paper", b))
    for budget in budgets:
        rows = [r for r in states if r["budget"] == budget]
        scenes = sorted({r["scene"] for r in rows})
        for scene in [*scenes, ALL]:
            chosen = [r for r in rows if scene == ALL or r["scene"] == scene]
            for rival in dict.fromkeys(name for r in rows for name in r["against_nvf"]):  # in the rows' order
                have = [r for r in chosen if rival in r["against_nvf"]]
                if not have:
                    continue
                rho = correlation_interval(np.array([r["against_nvf"][rival]["spearman"] for r in have], dtype=float))
                gains = [r["outcomes"][rival]["gain"] for r in have if rival in r["outcomes"]]
                gain = Interval.of(np.array(gains, dtype=float))
                out.append(
                    {
                        "budget": budget,
                        "scene": scene,
                        "rival": rival,
                        "states": len(have),
                        "spearman_mean": rho[0],
                        "spearman_low": rho[1],
                        "spearman_high": rho[2],
                        "same_pick": float(np.mean([r["against_nvf"][rival]["same_pick"] for r in have])),
                        "nvf_relative_std": _mean([r["contenders"]["nvf"]["spread"]["relative_std"] for r in have]),
                        "rival_relative_std": _mean([r["contenders"][rival]["spread"]["relative_std"] for r in have]),
                        "auc_labels": _mean([r["visibility"]["auc_labels"] for r in have]),
                        "auc_head": _mean([r["visibility"]["auc_head"] for r in have]),
                        "outcomes": len(gains),
                        "gain_mean": gain.mean,
                        "gain_low": gain.low,
                        "gain_high": gain.high,
                        "state_hours": _mean([r["seconds"] * r["threads"] / 3600.0 for r in have]),
                    }
                )
    return out


def _cell(value: object) -> str:
    if isinstance(value, float):
        return "-" if not np.isfinite(value) else f"{value:.3f}"
    return str(value)


def twins(states: list[dict]) -> list[dict]:
    """Each state trained at the paper's budget beside the same state at the cpu budget, per rival."""
    cpu = {(r["scene"], r["seed"], r["step"]): r for r in states if r["budget"] == "cpu"}
    out = []
    for r in states:
        if r["budget"] != "paper":
            continue
        twin = cpu.get((r["scene"], r["seed"], r["step"]))
        for rival, found in r["against_nvf"].items():
            other = None if twin is None else twin["against_nvf"].get(rival)
            out.append(
                {
                    "scene": r["scene"],
                    "seed": r["seed"],
                    "step": r["step"],
                    "rival": rival,
                    "paper_spearman": found["spearman"],
                    "cpu_spearman": None if other is None else other["spearman"],
                    "paper_same_pick": found["same_pick"],
                    "cpu_same_pick": None if other is None else other["same_pick"],
                    "paper_gain": r["outcomes"].get(rival, {}).get("gain"),
                    "paper_auc_head": r["visibility"]["auc_head"],
                    "cpu_auc_head": None if twin is None else twin["visibility"]["auc_head"],
                }
            )
    return out


def state_problem(row: dict) -> str | None:
    """What makes a state row unusable beyond its shape: a pick outside its candidates, or a rival compared with NVF,
    or an outcome, of a contender the row does not hold; None when it is whole."""
    stray = next((name for name, found in row["contenders"].items() if found["pick"] >= row["candidates"]), None)
    if stray is not None:
        pick = row["contenders"][stray]["pick"]
        return f"contenders.{stray}.pick {pick} is not one of its {row['candidates']} candidates"
    for part in ("against_nvf", "outcomes"):
        stray = next((name for name in row[part] if name not in row["contenders"] or name == "nvf"), None)
        if stray is not None:
            return f"{part}.{stray} names no rival among its contenders ({', '.join(row['contenders'])})"
    return None


def read_states(folder: Path) -> list[dict]:
    """``folder``'s ``states.jsonl``, its current rows (a row extended by a later one is left out,
    ``decisions.current_rows``); a state held twice otherwise, or a row naming a rival it does not hold, is refused
    (``RecordError`` naming it)."""
    path = folder / "states.jsonl"
    rows = read_json_lines(path, STATE)[0]
    states = [with_kept_spearman(row, rows) for row in current_rows(rows, state_key, str(path))]
    for row in states:
        problem = state_problem(row)
        if problem is not None:
            raise RecordError(f"{path}: the state {state_key(row)}: {problem}; fix or delete its line")
    return states


def with_kept_spearman(row: dict, rows: list[dict]) -> dict:
    """``row`` with the Spearman correlations of the row it extends (``row_files.EXTENDS``, among ``rows``) where it
    has none: an extension that scores a rival again on the backbone but keeps NVF's pick from the earlier row has
    no NVF scores to correlate with, while the earlier row measured both on the same state (the extension checked
    that the rival's pick came out the same); a rival whose pick differs from the earlier row's keeps None."""
    earlier = next((r for r in rows if row.get(EXTENDS) is not None and row_digest(r) == row[EXTENDS]), None)
    if earlier is None:
        return row
    against = dict(row["against_nvf"])
    for name, found in against.items():
        before = earlier["against_nvf"].get(name)
        same = all(
            who in earlier["contenders"] and earlier["contenders"][who]["pick"] == row["contenders"][who]["pick"]
            for who in ("nvf", name)
        )
        if found["spearman"] is None and before is not None and before["spearman"] is not None and same:
            against[name] = found | {"spearman": before["spearman"]}
    return row | {"against_nvf": against}


def _refuse_repeats(states: list[dict], where: str) -> None:
    identities = [state_key(row) for row in states]
    repeated = next((key for key in identities if identities.count(key) > 1), None)
    if repeated is not None:
        raise RecordError(f"{where} holds the state {repeated} twice; delete one of its rows")


def write_summary(folder: Path) -> list[Path]:
    """``summary.csv`` and ``summary.md`` of ``folder``'s states."""
    return _write_tables(folder, "summary", read_states(folder), "", "`states.jsonl`")


POOLED_SETTING = ("state_budget", "vis_points", "threads")  # what pooled folders share; their overrides may differ


def pooled_setting(folder: Path) -> dict:
    """What of ``folder``'s setting its pooled folders must share (``POOLED_SETTING``; a setting that predates
    ``vis_points`` was made with ``LEGACY_VIS_POINTS``, one that predates ``threads`` with its rows')."""
    made = read_json(folder / "setting.json", SETTING)
    if made is None:
        raise RecordError(f"{folder}: no setting.json; name a folder the paper_states command wrote")
    threads = made.get("threads")
    if threads is None:
        threads = sorted({r["threads"] for r in read_states(folder)})
    return {
        "state_budget": made["state_budget"],
        "vis_points": made.get("vis_points", LEGACY_VIS_POINTS),
        "threads": threads,
    }


def pooled_states(folder: Path, pooled: list[Path]) -> tuple[list[dict], list[str]]:
    """``folder``'s states and ``pooled``'s (folders of the same states' budget, label points and threads;
    ``RecordError`` naming the first that differs, or a state held twice), and where each came from."""
    states, sources, ours = read_states(folder), ["`states.jsonl`"], pooled_setting(folder)
    for other in pooled:
        theirs = pooled_setting(other)
        differs = next((key for key in POOLED_SETTING if theirs[key] != ours[key]), None)
        if differs is not None:
            raise RecordError(
                f"{other} was made with {differs} {theirs[differs]}, {folder} with {ours[differs]}: their states do "
                "not pool; pool folders of one setting"
            )
        found = read_states(other)
        truths = ", ".join(sorted({r["ground_truth"] for r in found})) or "none"
        sources.append(f"`{other / 'states.jsonl'}` ({len(found)} states, ground truth {truths})")
        states += found
    _refuse_repeats(states, f"{folder} pooled with {', '.join(map(str, pooled))}")
    return states, sources


def write_pooled(folder: Path, pooled: list[Path]) -> list[Path]:
    """``pooled.csv`` and ``pooled.md`` in ``folder``: the summary's tables over its states and ``pooled``'s
    (``pooled_states``)."""
    states, sources = pooled_states(folder, pooled)
    return _write_tables(folder, "pooled", states, " --pool ...", " and ".join(sources))


def _write_tables(folder: Path, name: str, states: list[dict], options: str, sources: str) -> list[Path]:
    """``name``.csv and ``name``.md of ``states``, headed by the command (with ``options``) and ``sources``."""
    rows = summary_rows(states)
    table = pd.DataFrame(rows, columns=list(COLUMNS))
    csv_path, md_path = folder / f"{name}.csv", folder / f"{name}.md"
    atomic_write_text(csv_path, as_csv(table, ("budget", "scene", "rival"), "%.4f"))
    pairs = twins(states)
    text = [
        "# Paper-trained states: NVF's decisions against its rivals",
        "",
        f"{len(states)} states ({', '.join(sorted({r['budget'] for r in states}))}); written by "
        f"`python -m pipeline.experiments.paper_states_summary{options}` from {sources}.",
        "",
        *markdown_table(list(COLUMNS), [[_cell(row[c]) for c in COLUMNS] for row in rows], left=3),
        "",
        "## Each paper-budget state beside its cpu-budget twin",
        "",
    ]
    if pairs:
        keys = list(pairs[0])
        text += markdown_table(keys, [[_cell(p[k]) for k in keys] for p in pairs], left=4)
    else:
        text.append("No paper-budget state yet.")
    atomic_write_text(md_path, "\n".join(text) + "\n")
    return [csv_path, md_path]


def main(argv: list[str]) -> None:
    parser = ArgumentParser(
        prog="python -m pipeline.experiments.paper_states_summary", description=description(__doc__)
    )
    parser.add_argument("overrides", nargs="*", help="paths.results=DIR")
    parser.add_argument(
        "--pool",
        action="append",
        type=Path,
        default=[],
        metavar="FOLDER",
        help="also pooled.csv and pooled.md over this folder's states and FOLDER's (another setting's; repeatable)",
    )
    args = parser.parse_intermixed_args(argv)
    cfg = compose_run(args.overrides)
    folder = Path(cfg.paths.results) / "pilots" / FOLDER
    if not (folder / "states.jsonl").is_file():
        fail(f"paths.results={cfg.paths.results}: no {folder / 'states.jsonl'}; run the paper_states command first")
    for other in args.pool:
        if not (other / "states.jsonl").is_file():
            fail(f"--pool {other}: no states.jsonl there; name a folder the paper_states command wrote")
    written = write_summary(folder) + (write_pooled(folder, args.pool) if args.pool else [])
    for path in written:
        print(f"wrote {path}")


if __name__ == "__main__":
    run_command(main, sys.argv[1:])
