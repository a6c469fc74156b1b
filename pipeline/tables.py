"""Run records -> long CSV -> paper-style tables (md, csv, tex), comparison with the paper, figures.

``python -m pipeline.tables [paths.outputs=DIR] [paths.results=DIR]`` reads every run under
``paths.outputs`` and ``${paths.results}/runs`` (committed records: run.json + steps.jsonl) and writes
``${paths.results}/runs.csv`` (long format; NaN as an empty field), ``tables/{main, table1_opt,
table2_ablation, table34_nerf_assets, all_runs, paper_comparison}.{md,csv,tex}`` and ``figures/``
(metric-vs-step curves, image grids). Only finished runs count; a cell is the mean ± population std
over seeds at each run's last step (PROTOCOL.md 3). Step rows store NaN as ``null``
(pipeline.records); it is read back as NaN and footnoted. A run whose recorded settings differ from what
its named groups give today (``pipeline.overrides``) has them appended to its budget, e.g.
``cpu+planner.num_candidates=512``, so it is never averaged or labelled with plain ``cpu`` runs.
"""

import json
import math
import re
import sys
from dataclasses import dataclass
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pandas as pd
from jaxtyping import Float
from matplotlib.figure import Figure

from pipeline.images import save_figure
from pipeline.metric_info import PAPER_METRICS
from pipeline.overrides import NamedConfigs
from pipeline.paper_numbers import paper_numbers
from pipeline.records import (
    IDENTITY_KEYS,
    RUN_JSON,
    STEPS,
    atomic_write_text,
    check_key,
    read_steps,
    record_status,
    run_difference,
)
from pipeline.repo import CONF

METRIC_KEYS = tuple(m.name for m in PAPER_METRICS)
METHOD_NAMES = (
    ("random", "Random"),
    ("wd", "WD"),
    ("activermap", "ActiveRMAP"),
    ("air", "AIR"),
    ("activenerf", "ActiveNeRF"),
    ("neurar", "NeurAR"),
    ("nvf", "NVF"),
)
ABLATION_NAMES = (
    ("wo_vis", "w/o Vis."),
    ("wo_var", "w/o Var."),
    ("ind_rays", "Ind. Rays"),
    ("loose", "Loose"),
    ("none", "NVF"),
)
PLANNERS = ("argmax", "opt")
OBJECT_SCENES = ("chair", "drums", "ficus", "hotdog", "lego", "materials", "mic", "ship")
ROOM_SCENES = ("hubble", "room")
OBJECT_MEAN = "object-scene mean"
LONG_COLUMNS = (
    "scene", "scene_source", "method", "planner", "ablation", "budget", "seed", "step", "n_views", "metric", "value"
)
FINAL_COLUMNS = (
    *IDENTITY_KEYS, "scene_source", "status", "failure_reason", "lpips_missing_reason", "directory", "step", "n_views"
)
GROUP = ("budget", "scene", "method", "planner", "ablation")
IMAGE_NAME = re.compile(r"step_(\d+)_(.+)\.png")
IMAGE_KINDS = (("gt", "GT"), ("pred", "prediction"), ("score", "score map"), ("entropy", "entropy"), ("depth", "depth"))


@dataclass(frozen=True)
class Runs:
    """All run records: ``long`` (LONG_COLUMNS, finished runs), ``final`` (one row per run, last-step
    metrics); ``skipped`` (unreadable records) and ``conflicts`` (records left out because a kept record
    of the same run has other settings), one line each."""

    long: pd.DataFrame
    final: pd.DataFrame
    skipped: tuple[str, ...]
    conflicts: tuple[str, ...] = ()


@dataclass(frozen=True)
class Table:
    """One rendered table: aggregated rows in display order, header lines and footnotes."""

    name: str
    title: str
    rows: pd.DataFrame
    header: tuple[str, ...]
    notes: tuple[str, ...]


def _rank(names: tuple[tuple[str, str], ...], key: str) -> int:
    keys = [k for k, _ in names]
    return keys.index(key) if key in keys else len(keys)


def method_label(method: str, planner: str, ablation: str) -> str:
    """Display name: Random ... NVF, ablations as w/o Vis. etc., '-OPT' for planner=opt."""
    label = dict(METHOD_NAMES).get(method, method)
    if ablation != "none":
        ablation_name = dict(ABLATION_NAMES).get(ablation, ablation)
        label = ablation_name if method == "nvf" else f"{label} {ablation_name}"
    if planner == "opt":
        return f"{label}-OPT"
    return label if planner == "argmax" else f"{label} ({planner})"


def base_scene(scene: str) -> str:
    """Paper scene a scene stands for: 'lego_proxy' -> 'lego'."""
    return scene.removesuffix("_proxy")


def _scene_rank(scene: str) -> tuple[int, str]:
    order = (*ROOM_SCENES, *OBJECT_SCENES)
    base = base_scene(scene)
    return (order.index(base) if base in order else len(order) + (scene == OBJECT_MEAN), scene)


def _metric_value(value: object) -> float | None:
    """Float of a recorded metric (null -> NaN); None for non-numeric entries."""
    if value is None:
        return math.nan
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value)


def _load_run(directory: Path) -> tuple[dict, list[dict]]:
    info = json.loads((directory / RUN_JSON).read_text(encoding="utf-8"))
    if not isinstance(info, dict):
        raise ValueError("run.json is not an object")
    missing = [key for key in IDENTITY_KEYS if key not in info]
    if missing:
        raise ValueError(f"run.json lacks {', '.join(missing)}")
    for key in IDENTITY_KEYS[:-1]:
        check_key(key, info[key])
    if not isinstance(info["seed"], int):
        raise ValueError(f"seed {info['seed']!r} is not an integer")
    rows, _ = read_steps(directory / STEPS)  # a truncated last line is ignored, never repaired here
    return info, rows


def collect_runs(roots: list[Path]) -> Runs:
    """Read every run directory (holding run.json) under ``roots``; a run found twice counts once
    (a finished copy wins, then the first root). A copy left out with other settings (config) than the
    kept one is listed in ``conflicts``: a table never mixes them silently."""
    records: dict[tuple, dict] = {}
    skipped: list[str] = []
    conflicts: list[str] = []
    for root in roots:
        for run_json in sorted(Path(root).rglob(RUN_JSON)) if Path(root).is_dir() else []:
            directory = run_json.parent
            try:
                info, rows = _load_run(directory)
            except (ValueError, OSError) as err:
                skipped.append(f"skipped unreadable run record {directory}: {str(err).splitlines()[0]}")
                continue
            key = tuple(info[k] for k in IDENTITY_KEYS)
            status = record_status(info, directory)
            ok = [r for r in rows if r.get("status", "ok") == "ok" and isinstance(r.get("metrics"), dict)]
            if status == "done" and not ok:
                status = "empty"
            record = {"info": info, "rows": ok, "status": status, "directory": directory}
            if key in records:
                keep_first = records[key]["status"] == "done" or status != "done"
                kept, left = (records[key], record) if keep_first else (record, records[key])
                changed = run_difference(left["info"], kept["info"], labels=("here", "there"))
                if changed is not None:
                    conflicts.append(
                        f"left out {left['directory']}: the same run as {kept['directory']} but a different {changed}"
                    )
                if keep_first:
                    continue
            records[key] = record
    long_rows, final_rows = [], []
    named = NamedConfigs(CONF)
    for record in records.values():
        info, rows = record["info"], record["rows"]
        keys = {k: info[k] for k in IDENTITY_KEYS}
        keys["budget"] = named.budget_label(info)
        source = str(info.get("scene_source", "unknown"))
        last = max(rows, key=lambda r: r["step"]) if rows else {"metrics": {}}
        final = {
            **keys,
            "scene_source": source,
            "status": record["status"],
            "failure_reason": info.get("failure_reason"),
            "lpips_missing_reason": info.get("lpips_missing_reason") or last.get("lpips_missing_reason"),
            "directory": str(record["directory"]),
            "step": last.get("step"),
            "n_views": last.get("n_views"),
        }
        for metric in METRIC_KEYS:
            value = _metric_value(last["metrics"].get(metric))
            final[metric] = math.nan if value is None else value
        final_rows.append(final)
        if record["status"] != "done":
            continue
        for row in rows:
            for metric, raw in row["metrics"].items():
                value = _metric_value(raw)
                if value is not None:
                    step = {"step": row["step"], "n_views": row.get("n_views")}
                    long_rows.append({**keys, "scene_source": source, **step, "metric": str(metric), "value": value})
    long = pd.DataFrame(long_rows, columns=list(LONG_COLUMNS))
    long = long.astype({"seed": "int64", "step": "int64", "n_views": "Int64", "value": "float64"})
    long = long.sort_values(list(LONG_COLUMNS[:8])).reset_index(drop=True)
    final_frame = pd.DataFrame(final_rows, columns=[*FINAL_COLUMNS, *METRIC_KEYS])
    return Runs(long=long, final=final_frame, skipped=tuple(skipped), conflicts=tuple(conflicts))


def mean_std_valid(values: Float[np.ndarray, " n"]) -> tuple[float, float, int]:
    """Mean, population std and count of the finite ``values`` over seeds (NaN, NaN, 0 if none)."""
    valid = values[np.isfinite(values)]
    if not valid.size:
        return math.nan, math.nan, 0
    return float(valid.mean()), float(valid.std()), int(valid.size)  # population std (ddof 0)


def aggregate(final: pd.DataFrame) -> pd.DataFrame:
    """Mean, population std and count of valid values per metric over the seeds of each GROUP."""
    rows = []
    for key, group in final.groupby(list(GROUP), sort=False):
        row = {**dict(zip(GROUP, key)), "scene_source": ", ".join(sorted(set(group["scene_source"]))), "n": len(group)}
        for metric in METRIC_KEYS:
            stats = mean_std_valid(group[metric].to_numpy(float))
            row[f"{metric}_mean"], row[f"{metric}_std"], row[f"{metric}_valid"] = stats
        rows.append(row)
    return pd.DataFrame(rows)


def object_mean(final: pd.DataFrame) -> tuple[pd.DataFrame, tuple[str, ...]]:
    """Per seed, the mean over the object scenes of each method (a NaN stays NaN); then over seeds.

    Seeds lacking one of the method's scenes are left out. Returns the aggregated rows (scene =
    OBJECT_MEAN, ``scene_count`` = scenes averaged) and notes naming the scenes averaged and the seeds left out.
    """
    objects = final[final["scene"].map(base_scene).isin(OBJECT_SCENES)]
    per_seed, coverage, counts = [], {}, {}
    for key, group in objects.groupby(["budget", "method", "planner", "ablation"], sort=False):
        scenes = sorted(set(group["scene"]), key=_scene_rank)
        counts[key] = len(scenes)
        complete = group.groupby("seed").filter(lambda s: set(s["scene"]) == set(scenes))
        text = f"mean over {len(scenes)} scene{'' if len(scenes) == 1 else 's'} ({', '.join(scenes)})"
        dropped = sorted(set(group["seed"]) - set(complete["seed"]))
        if dropped:
            text += f", seeds {', '.join(map(str, dropped))} left out (missing scenes)"
        coverage.setdefault(text, []).append(f"{method_label(*key[1:])} ({key[0]})")
        for seed, seed_rows in complete.groupby("seed"):
            sources = ", ".join(sorted(set(seed_rows["scene_source"])))
            means = {m: float(seed_rows[m].to_numpy(float).mean()) for m in METRIC_KEYS}
            keys = dict(zip(("budget", "method", "planner", "ablation"), key))
            per_seed.append({**keys, "scene": OBJECT_MEAN, "seed": seed, "scene_source": sources, **means})
    if not per_seed:
        return pd.DataFrame(), ()
    rows = aggregate(pd.DataFrame(per_seed))
    keys = zip(rows["budget"], rows["method"], rows["planner"], rows["ablation"])
    rows["scene_count"] = [counts[key] for key in keys]
    if len(coverage) == 1:
        return rows, (f"{next(iter(coverage))} for every row",)
    return rows, tuple(f"{text}: {', '.join(labels)}" for text, labels in coverage.items())


def _mixed_seed_counts(rows: pd.DataFrame) -> pd.Series:
    """Per row: True if its (budget, scene) block has rows over different numbers of seeds ``n``."""
    return rows["n"].groupby([rows["budget"], rows["scene"]]).transform("nunique") > 1


def _mark_best(rows: pd.DataFrame) -> pd.DataFrame:
    """Add ``<metric>_best``: the direction-aware best mean of each (budget, scene) block; none when all tie,
    or when the block's rows average different numbers of seeds (a 3-seed mean is not comparable with one seed)."""
    rows = rows.copy()
    comparable = ~_mixed_seed_counts(rows)
    for m in PAPER_METRICS:
        means = rows[f"{m.name}_mean"]
        block = means.groupby([rows["budget"], rows["scene"]])
        best = block.transform("max" if m.higher_is_better else "min")
        spread = block.transform("max") > block.transform("min")  # no bold when every row ties
        rows[f"{m.name}_best"] = (means == best) & spread & comparable
    return rows


def _label_rank(method: str, planner: str, ablation: str) -> tuple:
    """Paper row order: plain before -OPT, ablations as in Table S2, methods as in Tables S3-S4."""
    return (planner == "opt", _rank(ABLATION_NAMES, ablation), _rank(METHOD_NAMES, method), method, planner)


def _order(rows: pd.DataFrame) -> pd.DataFrame:
    keys = [
        (budget, _scene_rank(scene), _label_rank(method, planner, ablation))
        for budget, scene, method, planner, ablation in rows[list(GROUP)].itertuples(index=False)
    ]
    return rows.iloc[sorted(range(len(keys)), key=keys.__getitem__)].reset_index(drop=True)


@dataclass(frozen=True)
class Spec:
    """Which runs a table takes, and how it is laid out."""

    name: str
    title: str
    methods: tuple[str, ...] | None  # None: any
    planners: tuple[str, ...] | None
    ablations: tuple[str, ...] | None
    scenes: str  # all | objects | main
    object_mean: bool
    experiment: str | None  # the Hydra experiment that fills it


SPECS = (
    Spec("main", "Main table: Hubble, Room, NeRF-asset mean", None, ("argmax",), ("none",), "main", True, "main"),
    Spec(
        "table1_opt",
        "Table S1: gradient-based view refinement (-OPT)",
        ("air", "neurar", "nvf"),
        PLANNERS,
        ("none",),
        "all",
        True,
        "table1_opt",
    ),
    Spec("table2_ablation", "Table S2: ablations", ("nvf",), ("argmax",), None, "all", True, "table2_ablation"),
    Spec(
        "table34_nerf_assets",
        "Tables S3-S4: NeRF assets",
        None,
        ("argmax",),
        ("none",),
        "objects",
        True,
        "table34_nerf_assets",
    ),
    Spec("methods", "Every method per scene (argmax planner, no ablation)", None, ("argmax",), ("none",), "all", False,
         "methods"),  # fmt: skip
    Spec("all_runs", "All runs: every scene and method, per scene", None, None, None, "all", False, None),
)


def _select(final: pd.DataFrame, spec: Spec) -> pd.DataFrame:
    keep = pd.Series(True, index=final.index)
    for column, allowed in (("method", spec.methods), ("planner", spec.planners), ("ablation", spec.ablations)):
        if allowed is not None:
            keep &= final[column].isin(allowed)
    bases = final["scene"].map(base_scene)
    if spec.scenes == "objects":
        keep &= bases.isin(OBJECT_SCENES)
    elif spec.scenes == "main":
        keep &= bases.isin((*ROOM_SCENES, *OBJECT_SCENES))
    return final[keep]


def _notes(selected: pd.DataFrame, done: pd.DataFrame, rows: pd.DataFrame, runs: Runs) -> list[str]:
    notes = []
    valid = rows[[f"{m}_valid" for m in METRIC_KEYS]].to_numpy() if not rows.empty else np.zeros((0, 1))
    if ((valid > 0) & (valid < rows[["n"]].to_numpy())).any():
        notes.append("† some seeds lack this value: the cell averages the others.")
    if (valid == 0).any():
        notes.append("'-': no run has this value.")
    if not rows.empty:
        mixed = rows[_mixed_seed_counts(rows)].drop_duplicates(["budget", "scene"])
        blocks = ", ".join(f"{scene} ({budget})" for budget, scene in zip(mixed["budget"], mixed["scene"]))
        if blocks:
            notes.append(f"No best is marked for {blocks}: its rows average different numbers of seeds (n).")
    for m in PAPER_METRICS:
        missing = done[done[m.name].isna()]
        if missing.empty:
            continue
        if m.name == "lpips":
            reasons = {r for r in missing["lpips_missing_reason"] if isinstance(r, str) and r}
            reasons = sorted(reasons or {"reason not recorded"})
            notes.append(f"{m.label} missing in {len(missing)} of {len(done)} runs: {'; '.join(reasons)}.")
        else:
            hint = " (an empty reconstruction gives Acc = Comp = NaN)" if m.name in ("acc", "comp") else ""
            notes.append(f"{m.label} is NaN/null in {len(missing)} of {len(done)} runs{hint}.")
    unfinished = selected[selected["status"] != "done"]
    if not unfinished.empty:
        counts = unfinished["status"].value_counts()
        parts = [f"{count} {status}" for status, count in counts.items()]
        notes.append(f"Excluded: {', '.join(parts)} run(s) (only runs marked done count).")
        for _, run in unfinished[unfinished["status"] == "failed"].iterrows():
            label = method_label(run["method"], run["planner"], run["ablation"])
            reason = run["failure_reason"] or "no reason recorded"
            notes.append(f"Failed: {run['scene']} {label} seed {run['seed']} ({run['budget']}): {reason}.")
    if runs.skipped:
        notes.append(f"{len(runs.skipped)} unreadable run record(s) skipped (listed by `python -m pipeline.tables`).")
    if runs.conflicts:
        notes.append(
            f"{len(runs.conflicts)} run record(s) left out: the same run as a kept record with other settings "
            "(listed by `python -m pipeline.tables`)."
        )
    return notes


def _header(done: pd.DataFrame) -> tuple[str, ...]:
    budgets = ", ".join(sorted(set(done["budget"])))
    steps = ", ".join(str(s) for s in sorted(set(done["step"].astype(int))))
    sources = done.groupby("scene")["scene_source"].agg(lambda s: "/".join(sorted(set(s))))
    scenes = "; ".join(f"{scene} ({sources[scene]})" for scene in sorted(sources.index, key=_scene_rank))
    return (
        f"Budget: {budgets}. Cells: mean ± population std over seeds at the last step (step {steps}), the mean alone "
        "from one seed; n = seeds.",
        f"Scenes: {scenes}. Proxies and procedural scenes are stand-ins, not the paper's assets.",
    )


def build_table(runs: Runs, spec: Spec) -> Table:
    """Aggregate the finished runs a spec selects into one Table (rows empty when there are none)."""
    selected = _select(runs.final, spec)
    done = selected[selected["status"] == "done"]
    if spec.scenes == "main":
        per_scene = done[done["scene"].map(base_scene).isin(ROOM_SCENES)]
    else:
        per_scene = done
    parts = [aggregate(per_scene)] if not per_scene.empty else []
    mean_notes: tuple[str, ...] = ()
    object_scenes = done.loc[done["scene"].map(base_scene).isin(OBJECT_SCENES), "scene"].nunique()
    if spec.object_mean and (object_scenes > 1 or (spec.scenes == "main" and object_scenes)):
        mean_rows, mean_notes = object_mean(done)
        parts.append(mean_rows)
    if not parts:
        notes = _notes(selected, done, pd.DataFrame(columns=["n"]), runs)
        return Table(spec.name, spec.title, pd.DataFrame(), (), tuple(notes))
    rows = _order(_mark_best(pd.concat(parts, ignore_index=True)))
    rows["label"] = [method_label(m, p, a) for m, p, a in zip(rows["method"], rows["planner"], rows["ablation"])]
    notes = _notes(selected, done, rows, runs) + [f"{OBJECT_MEAN}: {n}." for n in mean_notes]
    return Table(spec.name, spec.title, rows, _header(done), tuple(notes))


def _cell(row: pd.Series, metric: str, decimals: int) -> str:
    """'mean ± std' ('mean' alone from one seed; bold if best, † if some seeds lack it, '-' if none has
    it), then ' / paper' if any."""
    mean, std, valid = row[f"{metric}_mean"], row[f"{metric}_std"], row[f"{metric}_valid"]
    text = "-"
    if valid > 0:
        text = f"{mean:.{decimals}f}" + (f" ± {std:.{decimals}f}" if valid > 1 else "")
        if row.get(f"{metric}_best", False):
            text = f"**{text}**"
        text += "†" if valid < row["n"] else ""
    if f"{metric}_paper" in row:
        text += f" / {row[f'{metric}_paper']:.{decimals}f}"
    return text


def _grid(table: Table, label_header: str) -> tuple[list[str], list[list[str]]]:
    """Column names and Markdown cell texts (csv drops the bold marks, tex converts them)."""
    keys = (["section"] if "section" in table.rows else []) + (["budget"] if table.rows["budget"].nunique() > 1 else [])
    columns = [key.capitalize() for key in keys] + ["Scene", label_header]
    columns += [f"{m.label}{m.arrow}" for m in PAPER_METRICS] + ["n"]
    cells = []
    for _, row in table.rows.iterrows():
        line = [str(row[key]) for key in keys] + [row["scene"], row["label"]]
        line += [_cell(row, m.name, m.decimals) for m in PAPER_METRICS]
        cells.append(line + [str(int(row["n"]))])
    return columns, cells


TEX_SPECIALS = (
    ("\\", r"\textbackslash{}"), ("&", r"\&"), ("%", r"\%"), ("$", r"\$"), ("#", r"\#"), ("_", r"\_"),
    ("{", r"\{"), ("}", r"\}"), ("~", r"\textasciitilde{}"), ("^", r"\textasciicircum{}"),
    ("±", r"$\pm$"), ("↑", r"$\uparrow$"), ("↓", r"$\downarrow$"), ("†", r"$^\dagger$"),
)


def tex_escape(text: str) -> str:
    """LaTeX for plain text (specials escaped, ± ↑ ↓ † as math); '**x**' (a best cell) becomes bold."""
    specials = dict(TEX_SPECIALS)
    bold = text.startswith("**") and "**" in text[2:]
    if bold:
        inner, rest = text[2:].split("**", 1)
        return r"\textbf{" + tex_escape(inner) + "}" + tex_escape(rest)
    return "".join(specials.get(ch, ch) for ch in text)


def render(table: Table, label_header: str, experiment: str | None) -> dict[str, str]:
    """The table as {'md', 'csv', 'tex'} texts ('no runs yet' texts when it has no rows)."""
    if table.rows.empty:
        command = f"python -m pipeline.run -m experiment={experiment}" if experiment else "python -m pipeline.run"
        message = f"No runs yet for {table.name}: run `{command}`, then `python -m pipeline.tables`."
        return {
            "md": "\n".join([f"# {table.title}", "", message, "", *(f"- {n}" for n in table.notes)]).rstrip() + "\n",
            "csv": pd.DataFrame({"note": [message, *table.notes]}).to_csv(index=False),
            "tex": "\n".join([f"% {table.title}", tex_escape(message), *(tex_escape(n) for n in table.notes)]) + "\n",
        }
    columns, cells = _grid(table, label_header)
    markdown = pd.DataFrame(cells, columns=columns).to_markdown(index=False, disable_numparse=True)
    md = [f"# {table.title}", "", *table.header, "", markdown, "", *(f"- {n}" for n in table.notes)]
    plain = [[c.replace("**", "") for c in line] for line in cells]
    csv = "".join(f"# {line}\n" for line in (table.title, *table.header))
    csv += pd.DataFrame(plain, columns=columns).to_csv(index=False) + "".join(f"# {n}\n" for n in table.notes)
    tex = [
        f"% {table.title}",
        *(f"% {line}" for line in table.header),
        r"\begin{tabular}{" + "l" * (len(columns) - 9) + "c" * 8 + "r}",
        r"\toprule",
        " & ".join(map(tex_escape, columns)) + r" \\",
        r"\midrule",
        *(" & ".join(map(tex_escape, line)) + r" \\" for line in cells),
        r"\bottomrule",
        r"\end{tabular}",
        *(r"\par{\footnotesize " + tex_escape(n) + "}" for n in table.notes),
    ]
    return {"md": "\n".join(md) + "\n", "csv": csv, "tex": "\n".join(tex) + "\n"}


COMPARISONS = (  # (our table, section, paper tables, our object-scene-mean rows only)
    ("table34_nerf_assets", "S3/S4", ("S3", "S4"), False),
    ("table34_nerf_assets", "8-scene mean", ("mean8",), True),
    ("table1_opt", "S1 (scene not stated)", ("S1",), True),
    ("table2_ablation", "S2 (scene not stated)", ("S2",), True),
)


def paper_comparison(tables: dict[str, Table]) -> Table:
    """Our rows next to the paper's (S3/S4 per scene, 8-scene mean, S1, S2): cells 'ours / paper'."""
    paper = paper_numbers()
    rows, coverage = [], []
    for name, section, sources, mean_only in COMPARISONS:
        ours = tables[name].rows
        coverage += [n for n in tables[name].notes if n.startswith(OBJECT_MEAN)] if mean_only else []
        reference = paper[paper["table"].isin(sources)]
        for _, row in ours.iterrows():
            if (row["scene"] == OBJECT_MEAN) != mean_only:
                continue
            same_scene = reference["scene"] == base_scene(row["scene"])
            match = reference[(reference["method"] == row["label"]) & (mean_only | same_scene)]
            if not match.empty:
                values = {f"{m}_paper": float(match.iloc[0][m]) for m in METRIC_KEYS}
                ours_row = row.drop([f"{m}_best" for m in METRIC_KEYS]).to_dict()
                if mean_only:  # how much of the paper's 8-scene mean ours covers, in the row itself
                    ours_row["scene"] = f"{OBJECT_MEAN} ({int(row['scene_count'])} of {len(OBJECT_SCENES)})"
                rows.append({**ours_row, "section": section, **values})
    notes = (
        "Cells: ours (mean ± population std over seeds; the mean alone from one seed) / the paper's (supplement, "
        "mean of 3 runs).",
        "The paper ran the `paper` budget on the original assets: proxies and smaller budgets need not match.",
        *dict.fromkeys(coverage),
    )
    header = (f"Budget: {', '.join(sorted({r['budget'] for r in rows}))}.",) if rows else ()
    return Table("paper_comparison", "Ours vs the paper", pd.DataFrame(rows), header, notes)


def curves(long: pd.DataFrame, figures: Path) -> list[Path]:
    """Metric-vs-step curves per (scene, budget): mean ± population-std band over seeds, one line per
    method (colour by position, dashed for ablations)."""
    written = []
    for (scene, budget), frame in long.groupby(["scene", "budget"]):
        fig = Figure(figsize=(16, 7), dpi=80)
        fig.subplots_adjust(left=0.04, right=0.85, bottom=0.08, top=0.9, wspace=0.3, hspace=0.35)
        axes = fig.subplots(2, 4).ravel()
        groups = sorted(frame.groupby(["method", "planner", "ablation"]), key=lambda kv: _label_rank(*kv[0]))
        for ax, m in zip(axes, PAPER_METRICS):
            for i, ((method, planner, ablation), group) in enumerate(groups):
                series = group[group["metric"] == m.name].groupby("step")["value"]
                mean, std = series.mean(), series.std(ddof=0).fillna(0.0)
                if mean.notna().any():
                    color = f"C{i % 10}"  # the 10-colour cycle; ablations dashed, so no two lines look alike
                    style = "-" if ablation == "none" else "--"
                    label = method_label(method, planner, ablation)
                    ax.plot(mean.index, mean.to_numpy(), color=color, linestyle=style, label=label)
                    low, high = (mean - std).to_numpy(), (mean + std).to_numpy()
                    ax.fill_between(mean.index, low, high, alpha=0.2, color=color)
            ax.set_title(f"{m.label} {m.arrow}")
            ax.set_xlabel("step")
        handles, labels = axes[0].get_legend_handles_labels()
        if handles:
            fig.legend(handles, labels, loc="upper right")
        fig.suptitle(f"{scene} ({budget} budget)")
        path = figures / f"curves_{scene}_{budget}.png"
        save_figure(fig, path)
        written.append(path)
    return written


def image_grid(run_dir: Path, out_path: Path, max_rows: int = 5) -> Path | None:
    """Assemble ``images/step_XX_<kind>.png`` of a run into one grid: rows = up to ``max_rows`` evenly
    spaced steps (first and last included), columns = GT, prediction, score/entropy map, depth, others.
    None when the run saved no images."""
    found: dict[int, dict[str, Path]] = {}
    for path in sorted((Path(run_dir) / "images").glob("step_*.png")):
        match = IMAGE_NAME.fullmatch(path.name)
        if match:
            found.setdefault(int(match.group(1)), {})[match.group(2)] = path
    if not found:
        return None
    kinds = sorted(
        {kind for images in found.values() for kind in images},
        key=lambda kind: (_rank(IMAGE_KINDS, kind), kind),
    )
    steps = sorted(found)
    steps = [steps[round(i)] for i in np.linspace(0, len(steps) - 1, min(max_rows, len(steps)))]
    fig = Figure(figsize=(2.5 * len(kinds), 2.5 * len(steps)), layout="constrained")
    axes = np.asarray(fig.subplots(len(steps), len(kinds), squeeze=False))
    for i, step in enumerate(steps):
        for j, kind in enumerate(kinds):
            ax = axes[i, j]
            ax.set_axis_off()
            if kind in found[step]:
                image = iio.imread(found[step][kind])
                ax.imshow(image[..., :3] if image.ndim == 3 else image, cmap=None if image.ndim == 3 else "viridis")
            if i == 0:
                ax.set_title(dict(IMAGE_KINDS).get(kind, kind))
            if j == 0:
                ax.text(-0.05, 0.5, f"step {step}", transform=ax.transAxes, rotation=90, ha="right", va="center")
    save_figure(fig, Path(out_path))
    return Path(out_path)


LABEL_HEADERS = {"table2_ablation": "Variant"}


def summarize_run(run_dir: Path) -> Path:
    """Per-step metrics of one run (and the paper's row for its scene and method, if any) as Markdown
    in ``<run_dir>/summary.md``; returns its path."""
    info, rows = _load_run(Path(run_dir))
    label = method_label(info["method"], info["planner"], info["ablation"])
    columns = ["Step", "Views"] + [f"{m.label}{m.arrow}" for m in PAPER_METRICS] + ["Seconds"]
    cells = []
    for row in rows:
        if row.get("status", "ok") != "ok" or not isinstance(row.get("metrics"), dict):
            continue
        values = [_metric_value(row["metrics"].get(metric)) for metric in METRIC_KEYS]
        seconds = row.get("seconds") if isinstance(row.get("seconds"), dict) else {}
        total = sum(v for v in seconds.values() if isinstance(v, (int, float)))
        line = [str(row["step"]), str(row.get("n_views", ""))]
        line += ["-" if v is None or math.isnan(v) else f"{v:.{m.decimals}f}" for v, m in zip(values, PAPER_METRICS)]
        cells.append(line + [f"{total:.1f}"])
    paper = paper_numbers()
    match = paper[paper["table"].isin(["S3", "S4"]) & (paper["scene"] == base_scene(info["scene"]))]
    for _, ref in match[match["method"] == label].iterrows():
        cells.append([f"paper ({ref['table']})", ""] + [f"{ref[m.name]:.{m.decimals}f}" for m in PAPER_METRICS] + [""])
    table = pd.DataFrame(cells, columns=columns).to_markdown(index=False, disable_numparse=True)
    source = info.get("scene_source", "unknown")
    notes = [f"Status: {record_status(info, Path(run_dir))}. Scene source: {source}."]
    if info.get("lpips_missing_reason"):
        notes.append(f"LPIPS missing: {info['lpips_missing_reason']}.")
    title = f"# {info['scene']} / {label} / {info['budget']} budget / seed {info['seed']}"
    path = Path(run_dir) / "summary.md"
    atomic_write_text(path, "\n".join([title, "", table, "", *(f"- {n}" for n in notes)]) + "\n")
    return path


def build_tables(
    outputs: Path, runs_dirs: list[Path], results: Path, figures: bool = True
) -> tuple[list[Path], tuple[str, ...]]:
    """Collect runs, write runs.csv, the tables (md/csv/tex), the paper comparison and (unless
    ``figures`` is False) the curves and image grids.

    Returns the files written and one line per run record skipped (unreadable) or left out (settings
    that conflict with a kept record of the same run).
    """
    runs = collect_runs([Path(outputs), *map(Path, runs_dirs)])
    results = Path(results)
    written = [results / "runs.csv"]
    atomic_write_text(written[0], runs.long.to_csv(index=False))
    tables = {spec.name: build_table(runs, spec) for spec in SPECS}
    texts = {s.name: render(tables[s.name], LABEL_HEADERS.get(s.name, "Method"), s.experiment) for s in SPECS}
    texts["paper_comparison"] = render(paper_comparison(tables), "Method", "table34_nerf_assets")
    for name, flavors in texts.items():
        for flavor, text in flavors.items():
            path = results / "tables" / f"{name}.{flavor}"
            atomic_write_text(path, text)
            written.append(path)
    if not figures:
        return written, (*runs.skipped, *runs.conflicts)
    written += curves(runs.long, results / "figures")
    done = runs.final[runs.final["status"] == "done"].sort_values("seed")
    for _, run in done.drop_duplicates(list(GROUP)).iterrows():  # one grid per method and scene: lowest seed
        group = f"{run['method']}-{run['planner']}-{run['ablation']}"
        name = f"grid_{run['scene']}_{group}_{run['budget']}_seed{run['seed']}.png"
        grid = image_grid(Path(run["directory"]), results / "figures" / "grids" / name)
        written += [grid] if grid is not None else []
    return written, (*runs.skipped, *runs.conflicts)


def parse_overrides(argv: list[str]) -> tuple[Path, Path]:
    """(outputs, results) from ``paths.outputs=...`` / ``paths.results=...`` (defaults as conf/paths)."""
    paths = {"paths.outputs": Path("outputs"), "paths.results": Path("results")}
    for arg in argv:
        key, sep, value = arg.partition("=")
        if not sep or key not in paths or not value:
            raise ValueError(f"unknown argument {arg!r}: use paths.outputs=DIR and/or paths.results=DIR")
        paths[key] = Path(value)
    return paths["paths.outputs"], paths["paths.results"]


def main(argv: list[str]) -> int:
    """Command-line entry point; returns the exit code."""
    if any(arg in ("-h", "--help") for arg in argv):
        print(__doc__.strip())
        return 0
    try:
        outputs, results = parse_overrides(argv)
        written, skipped = build_tables(outputs, [results / "runs"], results)
    except (ValueError, OSError) as err:
        print(f"pipeline.tables: error: {str(err).splitlines()[0]}", file=sys.stderr)
        return 1
    for line in skipped:
        print(f"pipeline.tables: {line}", file=sys.stderr)
    if not outputs.is_dir():
        note = f"paths.outputs={outputs} is not a directory; only {results / 'runs'} was read"
        print(f"pipeline.tables: note: {note}", file=sys.stderr)
    print(f"pipeline.tables: wrote {len(written)} files under {results} (runs.csv, tables/, figures/)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
