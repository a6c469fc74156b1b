"""The duel's tables, from the folders ``python -m pipeline.experiments.duel`` writes under
``${paths.results}/pilots/duel/``, beside the recorded episodes of the same contenders.

``summary.csv``: a row per pair and scene and one over the scenes every pair holds (``scene=all``, the same scenes
for every pair so that pooled rows compare; a scene only some pairs hold, e.g. Room, is its own row only): ``n``
(the decisions whose picks differ), ``gain_mean, ci_low, ci_high`` (A's pick's held-out PSNR minus B's in dB,
with the paired 95% Student-t interval over those ``n``), ``same_pick`` (the share of decisions where both pick the
same candidate),
``episode_diff, episode_ci_low, episode_ci_high`` (A's final PSNR minus B's in their finished episodes, paired by
seed, and over scenes by scene and seed; empty unless both have at least 3 seeds on every scene of the row) and
``cpu_hours`` (the duel's own, from its decisions' timings: each state's trainings, once where shared, and scorer
preparations, each decision's scorings and its picks' outcomes, times the torch threads; an outcome shared with
another pair is counted in both, so each pair's hours are what it costs alone).

``details.csv``: per pair and scene, the decisions and states counted, the interval over per-state mean gains
(a state's decisions share its models, so they are not independent; this interval takes the state as the unit),
the share of states whose owner picks from its own planner draw what its record picked (``source_pick_recorded``:
the replayed training reproduces the episode), and ``episode_cpu_hours``, the hours of the episodes compared
(their records' per-step seconds times their torch threads).

``summary.md``: both, with how many rows the duel and the episodes separate (interval excluding zero) and
whether their signs agree where both do; on each row over the scenes (``all``), whether NVF's verdict against
that rival holds at the paper's scale (the paper states' ``transfer.csv`` beside the duel's folder: its verdict,
or "not measured"). ``python -m pipeline.experiments.duel_summary [paths.results=DIR]
[--records DIR]`` rewrites the three; ``--records`` (default: the repository's ``results/runs``, wherever the
command runs from) must hold the records of each pair's states, or the pair is refused in one line.
"""

import math
import os
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.atomic_write import atomic_write_text
from pipeline.cli import ArgumentParser, description, run_command
from pipeline.config.catalog import contender_label
from pipeline.config.validation import compose_run
from pipeline.experiments.decisions import DECISION
from pipeline.records.checked_files import (
    Each,
    Entries,
    Number,
    Optional,
    Text,
    read_csv,
    read_json,
    read_json_lines,
)
from pipeline.records.experiment_columns import (
    DUEL_DETAIL_COLUMNS,
    DUEL_MIN_SEEDS,
    DUEL_SUMMARY_COLUMNS,
    EPISODES_MISSING,
    TRANSFER_COLUMNS,
    TRANSFER_TABLE,
)
from pipeline.records.files import RecordError, make_directory, refuse_escaping_link
from pipeline.records.store import check_key, record_status
from pipeline.repo import RUNS
from pipeline.tables.escape import as_csv
from pipeline.tables.load import load_run
from pipeline.tables.stats import Interval
from pipeline.tables.table_formats import markdown_table

DUEL = "duel"
CONTENDER = {"method": Text(), "ablation": Text()}
SETTING = {
    "method": Text(),
    "rival": Optional(Text()),
    "overrides": Each(Text()),
    "budget": Optional(Text()),
    "contenders": Optional(Entries(CONTENDER)),
    "state_budget": Optional(Text()),
    "threads": Optional(Number(1, 4096, integer=True)),
}  # a pair's setting.json (the rival and contenders once written for the pair; threads since they are recorded)
ALL = "all"
MIN_SEEDS = DUEL_MIN_SEEDS  # episodes compared only with this many paired seeds per scene
COLUMNS = tuple(DUEL_SUMMARY_COLUMNS)  # summary.csv's, declared with their shapes in pipeline.records
TEXT = ("method", "rival", "scene", "budget")  # the csv columns of names (escaped: pipeline.tables.escape.as_csv)
DETAIL_COLUMNS = tuple(DUEL_DETAIL_COLUMNS)  # details.csv's


def read_rows(path: Path) -> list[dict]:
    """A pair's decisions, each checked (``DECISION``; a row cut off by a kill is left out)."""
    return read_json_lines(path, DECISION)[0]


def duel_cpu_hours(rows: list[dict]) -> float:
    """CPU hours of ``rows`` (one pair's decisions): per state its trainings (once where both share a model) and
    scorer preparations, per decision both scorings and both outcomes, times the threads."""
    states, decisions = {}, 0.0
    for r in rows:
        a, b = r["seconds"]["method"], r["seconds"]["rival"]
        train = a["train"] + (0.0 if r["shared_training"] else b["train"])
        states[(r["scene"], r["seed"], r["step"])] = (train + a["prepare"] + b["prepare"]) * r["threads"]
        decisions += (a["score"] + b["score"] + a.get("outcome", 0.0) + b.get("outcome", 0.0)) * r["threads"]
    return (sum(states.values()) + decisions) / 3600.0


def state_interval(rows: list[dict]) -> Interval:
    """The interval over the states' mean gains (states with at least one decision whose picks differ)."""
    frame = pd.DataFrame([r for r in rows if r.get("gain") is not None], columns=["scene", "seed", "step", "gain"])
    return Interval.of(frame.groupby(["scene", "seed", "step"])["gain"].mean().to_numpy(float))


def episode_group(records: Path, scene: str, who: dict, budget: str) -> Path:
    """The folder of contender ``who``'s (``method``, ``ablation``) argmax episodes on ``scene`` at ``budget``;
    ``RecordError`` when a name is not a plain path component."""
    names = {"scene": scene, "budget": budget, "method": who["method"], "ablation": who["ablation"]}
    try:
        key = {name: check_key(name, value) for name, value in names.items()}
    except ValueError as err:
        raise RecordError(f"{err}; a duel writes plain names only") from None
    return Path(records) / key["scene"] / f"{key['method']}-argmax-{key['ablation']}" / key["budget"]


def episodes(records: Path, scene: str, who: dict, budget: str) -> pd.DataFrame:
    """The finished argmax episodes of contender ``who`` (``method``, ``ablation``) on ``scene``: per seed the
    final PSNR and the cpu hours (the steps' seconds times the torch threads); records that fail verification
    are left out, a record reached through a symbolic link leaving ``records`` is a ``RecordError``."""
    group = episode_group(records, scene, who, budget)
    out = []
    for directory in sorted(group.glob("seed_*")):
        refuse_escaping_link(records, directory)
        try:
            info, steps = load_run(directory)
        except (RecordError, ValueError, OSError):
            continue
        if record_status(info, directory) == "done" and steps:
            seconds = sum(sum(row.get("seconds", {}).values()) for row in steps) * info.get("torch_threads", 1)
            out.append({"seed": int(info["seed"]), "psnr": steps[-1]["metrics"]["psnr"], "hours": seconds / 3600.0})
    return pd.DataFrame(out, columns=["seed", "psnr", "hours"]).set_index("seed")


def compare_episodes(records: Path, setting: dict, scenes: list[str]) -> tuple[Interval, float]:
    """A's final PSNR minus B's paired by (scene, seed) over ``scenes``, and the cpu hours of those episodes; an
    empty interval where a scene has fewer than ``MIN_SEEDS`` seeds of both."""
    a, b = (setting["contenders"][setting[role]] for role in ("method", "rival"))
    diffs, hours = [], 0.0
    for scene in scenes:
        ours, theirs = (episodes(records, scene, who, setting["budget"]) for who in (a, b))
        common = ours.index.intersection(theirs.index)
        if len(common) < MIN_SEEDS:
            return Interval.of(np.array([])), math.nan
        diffs.append((ours.loc[common, "psnr"] - theirs.loc[common, "psnr"]).to_numpy(float))
        hours += float(ours.loc[common, "hours"].sum() + theirs.loc[common, "hours"].sum())
    return Interval.of(np.concatenate(diffs)), hours


def check_state_records(folder: Path, setting: dict, rows: list[dict], records: Path) -> None:
    """``RecordError`` unless ``records`` holds, on each scene of ``rows``, episodes of every contender whose
    record gave the pair a state there (the rows' ``source``; both where a row does not name it), at the states'
    budget: a pair decided on records held elsewhere has no episodes to be compared with here."""
    budget = setting.get("state_budget") or setting["budget"]
    for scene in dict.fromkeys(r["scene"] for r in rows):
        sources = {r.get("source") for r in rows if r["scene"] == scene}
        for name in (setting[role] for role in ("method", "rival")):
            group = episode_group(records, scene, setting["contenders"][name], budget)
            if (name in sources or None in sources) and next(group.glob("seed_*"), None) is None:
                raise RecordError(
                    f"--records {records}: no episode of {name} on {scene} at budget {budget} ({group}), though "
                    f"{folder.name}'s states came from one; name the folder the duel read its states from"
                )


def pair_rows(folder: Path, rows: list[dict], records: Path, pooled: set[str]) -> tuple[list[dict], list[dict]]:
    """One pair's ``summary.csv`` and ``details.csv`` rows from its decisions ``rows``: per scene, then over those of
    its scenes in ``pooled``."""
    setting = read_json(folder / "setting.json", SETTING)
    if setting is None or "budget" not in setting or "contenders" not in setting or "rival" not in setting:
        raise RecordError(f"{folder / 'setting.json'}: missing or incomplete; a duel writes its setting there")
    absent = [setting[role] for role in ("method", "rival") if setting[role] not in setting["contenders"]]
    if absent:
        raise RecordError(f"{folder / 'setting.json'}: names no contender {absent[0]!r}; a duel writes both there")
    check_state_records(folder, setting, rows, records)
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    common = [s for s in scenes if s in pooled]
    summary, details = [], []
    for scene, chosen in [*((s, [s]) for s in scenes), *([(ALL, common)] if common else [])]:
        part = [r for r in rows if r["scene"] in chosen]
        gain = Interval.of(np.array([r["gain"] for r in part if r.get("gain") is not None], dtype=float))
        episode, episode_hours = compare_episodes(records, setting, chosen)
        names = {"method": setting["method"], "rival": setting["rival"], "scene": scene}
        summary.append(
            names
            | {"budget": setting["budget"]}
            | {"n": gain.n, "gain_mean": gain.mean, "ci_low": gain.low, "ci_high": gain.high}
            | {"same_pick": float(np.mean([r["same_pick"] for r in part]))}
            | {"episode_diff": episode.mean, "episode_ci_low": episode.low, "episode_ci_high": episode.high}
            | {"cpu_hours": duel_cpu_hours(part)}
        )
        state = state_interval(part)
        recorded = [r["source_pick_recorded"] for r in part if r.get("source_pick_recorded") is not None]
        details.append(
            names
            | {"decisions": len(part), "states": len({(r["scene"], r["seed"], r["step"]) for r in part})}
            | {
                "state_n": state.n,
                "state_gain_mean": state.mean,
                "state_ci_low": state.low,
                "state_ci_high": state.high,
            }
            | {"source_pick_recorded": float(np.mean(recorded)) if recorded else math.nan}
            | {"episode_n": episode.n, "episode_cpu_hours": episode_hours}
        )
    return summary, details


def pair_folders(root: Path) -> list[Path]:
    """Every pair folder under ``root`` (a folder holding a duel's ``setting.json`` or ``decisions.jsonl``), none
    read through a link: a linked one is a ``RecordError`` naming it."""
    folders = []
    for entry in sorted(root.iterdir()) if root.is_dir() else []:
        holds = any(os.path.lexists(entry / name) for name in ("setting.json", "decisions.jsonl"))
        if entry.is_symlink() and holds:
            raise RecordError(f"{entry}: a link; a duel's pair folder is read only where it lies")
        if entry.is_dir() and holds:
            folders.append(entry)
    return folders


def check_records(records: Path) -> None:
    """``RecordError`` unless ``records`` is a folder of run records (``--records`` named wrong would leave every
    episode column empty)."""
    if not Path(records).is_dir() or next(Path(records).glob("*/*/*/seed_*/steps.jsonl"), None) is None:
        raise RecordError(
            f"--records {records}: no run records there (<scene>/<group>/<budget>/seed_<n>/steps.jsonl); name the "
            "folder that holds the episodes the duels are compared with"
        )


def tables(root: Path, records: Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``summary.csv``'s and ``details.csv``'s frames over every pair folder under ``root``."""
    check_records(records)
    decided = {folder: read_rows(folder / "decisions.jsonl") for folder in pair_folders(root)}
    held = [{r["scene"] for r in rows} for rows in decided.values() if rows]
    pooled = set.intersection(*held) if held else set()
    summary, details = [], []
    for folder, rows in decided.items():
        found = pair_rows(folder, rows, records, pooled)
        summary += found[0]
        details += found[1]
    return pd.DataFrame(summary, columns=list(COLUMNS)), pd.DataFrame(details, columns=list(DETAIL_COLUMNS))


def separates(low: float, high: float) -> bool:
    """An interval excluding zero."""
    return Interval(math.nan, low, high, 0).excludes_zero


def _interval(mean: float, low: float, high: float) -> str:
    interval = Interval(mean, low, high, 0)
    return f"**{interval.text()}**" if interval.excludes_zero else interval.text()


def _ratios(scenes: pd.DataFrame, details: pd.DataFrame) -> str:
    """The sentence comparing the duel with the episodes over the rows that have both: the means' sign
    agreement, the median ratio of the interval widths and the ratio of the cpu hours."""
    same_sign = int((np.sign(scenes["gain_mean"]) == np.sign(scenes["episode_diff"])).sum())
    width = (scenes["episode_ci_high"] - scenes["episode_ci_low"]) / (scenes["ci_high"] - scenes["ci_low"])
    cost = details["episode_cpu_hours"].sum() / scenes["cpu_hours"].sum()
    return (
        f" The means have the same sign in {same_sign} of {len(scenes)}; the episodes' interval is "
        f"{width.median():.1f} times as wide as the duel's (median over rows), and their cpu hours "
        f"{cost:.1f} times the duel's."
    )


def _pooled_sentence(summary: pd.DataFrame) -> str:
    """The sentence naming the scenes the ``all`` rows pool (those every pair holds), where any are left out."""
    held = [set(block["scene"]) - {ALL} for _, block in summary.groupby(["method", "rival"], sort=False)]
    pooled, every = (set.intersection(*held), set.union(*held)) if held else (set(), set())
    if pooled == every:
        return ""
    return (
        f" Rows `{ALL}` pool {', '.join(sorted(pooled))}, the scenes every pair holds; "
        f"{', '.join(sorted(every - pooled))} in per-scene rows only."
    )


def paper_scale(row: pd.Series, verdicts: dict[str, str]) -> str:
    """The summary.md cell saying whether NVF's verdict against ``row``'s rival holds at the paper's scale: the
    transfer table's verdict on a row over the scenes of NVF's duel, "not measured" where it has none, "-" on a
    scene's row or another method's duel."""
    if row["scene"] != ALL or row["method"] != "nvf":
        return "-"
    return verdicts.get(row["rival"], "not measured")


def summary_markdown(summary: pd.DataFrame, details: pd.DataFrame, verdicts: dict[str, str]) -> str:
    """``summary.md``: the pairs' rows (contenders by their labels, each with its budget, and ``verdicts``, the
    transfer table's by rival) and the count of rows each instrument separates."""
    columns = ["method", "rival", "scene", "budget", "n", "one-step gain (dB)", "per-state gain (dB)", "same pick"]
    columns += ["episodes: final PSNR diff (dB)", "duel cpu h", "episodes cpu h", "at the paper's scale"]
    cells = []
    for (_, s), (_, d) in zip(summary.iterrows(), details.iterrows(), strict=True):
        budget = s["budget"] if isinstance(s["budget"], str) else "-"
        cells.append(
            [contender_label(s["method"]), contender_label(s["rival"]), s["scene"], budget, str(int(s["n"]))]
            + [_interval(s["gain_mean"], s["ci_low"], s["ci_high"])]
            + [_interval(d["state_gain_mean"], d["state_ci_low"], d["state_ci_high"]), f"{s['same_pick']:.0%}"]
            + [_interval(s["episode_diff"], s["episode_ci_low"], s["episode_ci_high"]), f"{s['cpu_hours']:.2f}"]
            + ["-" if not math.isfinite(d["episode_cpu_hours"]) else f"{d['episode_cpu_hours']:.2f}"]
            + [paper_scale(s, verdicts)]
        )
    scenes = summary[(summary["scene"] != ALL) & summary["episode_diff"].notna()]
    duel = [separates(low, high) for low, high in zip(scenes["ci_low"], scenes["ci_high"], strict=True)]
    runs = [separates(low, high) for low, high in zip(scenes["episode_ci_low"], scenes["episode_ci_high"], strict=True)]
    both = [
        (gain, diff)
        for gain, diff, d, e in zip(scenes["gain_mean"], scenes["episode_diff"], duel, runs, strict=True)
        if d and e
    ]
    agree = sum(int(np.sign(gain) == np.sign(diff)) for gain, diff in both)
    ratios = _ratios(scenes, details.loc[scenes.index]) if len(scenes) else ""
    lines = [
        "# Duels: paired one-step decisions",
        "",
        "A's pick minus B's pick in held-out PSNR after one step, where they differ (mean [95% Student-t "
        "interval] over the n decisions; per state: over the states' mean gains), beside A's final PSNR minus "
        "B's in their episodes (paired by seed). Bold: the interval excludes zero. At the paper's scale: NVF's "
        "verdict against the rival at the same states trained at the paper's counts ([transfer.md]"
        '(../paper_states/transfer.md)); "not measured": not known to hold at the paper\'s model size.'
        + _pooled_sentence(summary),
        "",
        *markdown_table(columns, cells, left=4),
        "",
        EPISODES_MISSING,
        "",
        f"Of {len(scenes)} pair-scene rows with episodes of both, the duel separates {sum(duel)} and the "
        f"episodes {sum(runs)}; where both do ({len(both)}), their signs agree in {agree}.{ratios}",
    ]
    return "\n".join(lines) + "\n"


def write_summaries(root: Path, records: Path) -> list[Path]:
    """Write ``summary.csv``, ``details.csv`` and ``summary.md`` under ``root`` (atomically); their paths."""
    summary, details = tables(root, records)
    transfer = read_csv(root.parent.parent / TRANSFER_TABLE, TRANSFER_COLUMNS)  # root: <paths.results>/pilots/duel
    verdicts = {} if transfer is None else dict(zip(transfer["rival"], transfer["verdict"], strict=True))
    paths = [root / "summary.csv", root / "details.csv", root / "summary.md"]
    atomic_write_text(paths[0], as_csv(summary, TEXT, "%.4g"))
    atomic_write_text(paths[1], as_csv(details, TEXT, "%.4g"))
    atomic_write_text(paths[2], summary_markdown(summary, details, verdicts))
    return paths


def main(argv: list[str]) -> None:
    parser = ArgumentParser(prog="python -m pipeline.experiments.duel_summary", description=description(__doc__))
    parser.add_argument("overrides", nargs="*", help="config overrides, e.g. paths.results=results")
    parser.add_argument("--records", type=Path, default=RUNS, help=f"where the episodes' records are (default {RUNS})")
    args = parser.parse_intermixed_args(argv)
    results = Path(compose_run(args.overrides).paths.results)
    root = make_directory(results, results / "pilots" / DUEL)
    for path in write_summaries(root, args.records):
        print(f"wrote {path}")


if __name__ == "__main__":
    run_command(main, sys.argv[1:])
