"""Final-step rows -> the paper's tables: mean ± population std over seeds per (budget, scene, method,
planner, ablation), the object-scene mean, best values marked, rows in the paper's order, and each
table's header and footnotes (``SPECS`` says which runs a table takes)."""

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import pandas as pd
from jaxtyping import Float

from pipeline.metrics.info import PAPER_METRICS
from pipeline.tables.labels import (
    ABLATION_NAMES,
    METHOD_NAMES,
    METRIC_KEYS,
    OBJECT_MEAN,
    OBJECT_SCENES,
    PLANNERS,
    ROOM_SCENES,
    base_scene,
    label_rank,
    method_label,
    scene_rank,
)
from pipeline.tables.load import GROUP, Runs


MESH_LOS_MARK = "‡"
MESH_LOS_NOTE = (
    f"{MESH_LOS_MARK} Planned with an oracle: M29's line-of-sight filter used the scene mesh's exact segment test "
    "(`planner.los_source=mesh`, the cpu budget's setting, acting on Room's collision-free sampler), not the "
    "model's transmittance, so the planner knew the true free space (docs/DEVIATIONS.md)."
)


@dataclass(frozen=True)
class Table:
    """One rendered table: aggregated rows in display order, header lines and footnotes."""

    name: str
    title: str
    rows: pd.DataFrame
    header: tuple[str, ...]
    notes: tuple[str, ...]


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
        row["mesh_los"] = bool(group["mesh_los"].any())
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
        scenes = sorted(set(group["scene"]), key=scene_rank)
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
            oracle = bool(seed_rows["mesh_los"].any())
            per_seed.append({**keys, "scene": OBJECT_MEAN, "seed": seed, "scene_source": sources, "mesh_los": oracle, **means})
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


def order_rows(rows: pd.DataFrame) -> pd.DataFrame:
    keys = [
        (budget, scene_rank(scene), label_rank(method, planner, ablation))
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
    if "mesh_los" in rows and rows["mesh_los"].any():
        notes.append(MESH_LOS_NOTE)
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
        notes.append(
            f"{len(runs.skipped)} run record(s) skipped: they fail a check (listed with the reason in all_runs and by "
            "`python -m pipeline.tables`)."
        )
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
    scenes = "; ".join(f"{scene} ({sources[scene]})" for scene in sorted(sources.index, key=scene_rank))
    return (
        f"Budget: {budgets}. Cells: mean ± population std over seeds at the last step (step {steps}), the mean alone "
        "from one seed; n = seeds.",
        f"Scenes: {scenes}. Proxies and procedural scenes are stand-ins, not the paper's assets.",
    )


def build_table(runs: Runs, spec: Spec) -> Table:
    """Aggregate the finished runs a spec selects into one Table (rows empty when there are none);
    ``all_runs`` also lists every skipped record with its reason."""
    table = _build_table(runs, spec)
    if spec.name != "all_runs" or not runs.skipped:
        return table
    return dataclasses.replace(table, notes=(*table.notes, *(f"{line[0].upper()}{line[1:]}." for line in runs.skipped)))


def _build_table(runs: Runs, spec: Spec) -> Table:
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
    rows = order_rows(_mark_best(pd.concat(parts, ignore_index=True)))
    rows["label"] = [method_label(m, p, a) for m, p, a in zip(rows["method"], rows["planner"], rows["ablation"])]
    notes = _notes(selected, done, rows, runs) + [f"{OBJECT_MEAN}: {n}." for n in mean_notes]
    return Table(spec.name, spec.title, rows, _header(done), tuple(notes))
