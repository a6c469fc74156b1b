"""Final-step rows -> the paper's tables: mean ± population std over seeds per (budget, scene, method,
planner, ablation), the object-scene mean, best values marked, rows in the paper's order, and each
table's header and footnotes (``SPECS`` says which runs a table takes)."""

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from jaxtyping import Float
from omegaconf import OmegaConf

from pipeline.config.plain_containers import as_dict, as_list
from pipeline.metrics.info import PAPER_METRICS
from pipeline.repo import CONF
from pipeline.tables.labels import METRIC_KEYS, OBJECT_MEAN
from pipeline.tables.load import GROUP, Runs
from pipeline.tables.stats import paired

MESH_LOS_MARK = "‡"
MESH_LOS_NOTE = (
    f"{MESH_LOS_MARK} Planned with an oracle: M29's line-of-sight filter used the scene mesh's exact segment test "
    "(`planner.los_source=mesh`, the cpu budget's setting, acting on Room's collision-free sampler), not the "
    "model's transmittance, so the planner knew the true free space (docs/DEVIATIONS.md)."
)
MESH_VISIBILITY_NOTE = (
    f"{MESH_LOS_MARK} Scored with an oracle: NVF's visibility came from the scene mesh's line of sight to the "
    "training cameras (`nvf.entropy.visibility_source=mesh`), not from its visibility head (docs/METHOD.md 9.3)."
)
ORACLE_FLAGS = (("mesh_los", MESH_LOS_NOTE), ("mesh_visibility", MESH_VISIBILITY_NOTE))
NOT_IN_PAPER_MARK = "§"
IRREGULAR_MARK = "°"
IRREGULAR_NOTE = (
    f"{IRREGULAR_MARK} Not made as its siblings: a seed of this row ran from a checkout with uncommitted changes, "
    "or with another torch thread count than its other seeds (run.json's `git.dirty` and `torch_threads`; a "
    "record's numbers depend on its thread count)."
)


def irregular(group: pd.DataFrame) -> bool:
    """Whether a row's runs differ from each other in how they were made: a dirty checkout, or two thread counts."""
    return bool(group["dirty"].any() or group["threads"].nunique() > 1)


def not_in_paper_note(labels: list[str], own: list[str]) -> str:
    """The footnote for rows whose method the paper does not have: ``labels`` this benchmark adds, ``own`` a user's
    (declared outside the repository)."""
    parts = [f"{', '.join(labels)}, this benchmark's"] if labels else []
    parts += [f"{', '.join(own)}, a method of your own (declared outside this repository)"] if own else []
    return (
        f"{NOT_IN_PAPER_MARK} Not in the paper: {'; '.join(parts)}; the paper has no reference numbers for them, nor "
        "for an -OPT variant of them (n/a)."
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


Samples = dict[tuple, pd.DataFrame]  # a row's GROUP key -> its metric values, one row per seed (or seed and scene)


def aggregate(final: pd.DataFrame) -> pd.DataFrame:
    """Mean, population std and count of valid values per metric over the seeds of each GROUP."""
    rows = []
    for key, group in final.groupby(list(GROUP), sort=False):
        row = {
            **dict(zip(GROUP, key, strict=True)),
            "scene_source": ", ".join(sorted(set(group["scene_source"]))),
            "n": len(group),
        }
        for flag, _ in ORACLE_FLAGS:
            row[flag] = bool(group[flag].any())
        row["irregular"] = irregular(group) or bool(group.get("irregular", pd.Series(dtype=bool)).any())
        for metric in METRIC_KEYS:
            stats = mean_std_valid(group[metric].to_numpy(float))
            row[f"{metric}_mean"], row[f"{metric}_std"], row[f"{metric}_valid"] = stats
        rows.append(row)
    return pd.DataFrame(rows)


def seed_samples(final: pd.DataFrame) -> Samples:
    """Each GROUP's metric values indexed by seed: what a paired comparison pairs."""
    return {key: group.set_index("seed")[list(METRIC_KEYS)] for key, group in final.groupby(list(GROUP), sort=False)}


def object_mean(final: pd.DataFrame, runs: Runs) -> tuple[pd.DataFrame, tuple[str, ...], Samples]:
    """Per seed, the mean over the object scenes of each method (a NaN stays NaN); then over seeds.

    Seeds lacking one of the method's scenes are left out. Returns the aggregated rows (scene =
    OBJECT_MEAN, ``scene_count`` = scenes averaged), notes naming the scenes averaged and the seeds left
    out, and each row's samples indexed by (seed, scene): a mean over scenes is compared over those pairs.
    """
    objects = final[np.array([runs.scene(scene).nerf_asset for scene in final["scene"]], dtype=bool)]
    per_seed: list[dict[str, object]] = []
    coverage: dict[str, list[str]] = {}
    counts: dict[tuple, int] = {}
    samples: Samples = {}
    for key, group in objects.groupby(["budget", "method", "planner", "ablation"], sort=False):
        scenes = sorted(set(group["scene"]), key=lambda scene: runs.scene(scene).order)
        counts[key] = len(scenes)
        complete = group.groupby("seed").filter(lambda s: set(s["scene"]) == set(scenes))  # noqa: B023 - called at once
        text = f"mean over {len(scenes)} scene{'' if len(scenes) == 1 else 's'} ({', '.join(scenes)})"
        dropped = sorted(set(group["seed"]) - set(complete["seed"]))
        if dropped:
            text += f", seeds {', '.join(map(str, dropped))} left out (missing scenes)"
        coverage.setdefault(text, []).append(f"{runs.row(*key[1:]).label} ({key[0]})")
        samples[(key[0], OBJECT_MEAN, *key[1:])] = complete.set_index(["seed", "scene"])[list(METRIC_KEYS)]
        for seed, seed_rows in complete.groupby("seed"):
            sources = ", ".join(sorted(set(seed_rows["scene_source"])))
            means = {m: float(seed_rows[m].to_numpy(float).mean()) for m in METRIC_KEYS}
            keys = dict(zip(("budget", "method", "planner", "ablation"), key, strict=True))
            oracles = {flag: bool(seed_rows[flag].any()) for flag, _ in ORACLE_FLAGS}
            made = {"dirty": False, "threads": int(seed_rows["threads"].iloc[0]), "irregular": irregular(seed_rows)}
            per_seed.append(
                {**keys, "scene": OBJECT_MEAN, "seed": seed, "scene_source": sources, **oracles, **made, **means}
            )
    if not per_seed:
        return pd.DataFrame(), (), {}
    rows = aggregate(pd.DataFrame(per_seed))
    row_keys = zip(rows["budget"], rows["method"], rows["planner"], rows["ablation"], strict=True)
    rows["scene_count"] = [counts[key] for key in row_keys]
    if len(coverage) == 1:
        return rows, (f"{next(iter(coverage))} for every row",), samples
    return rows, tuple(f"{text}: {', '.join(labels)}" for text, labels in coverage.items()), samples


REFERENCE = ("nvf", "argmax", "none")  # the row every other row of its scene is compared with: NVF
SIGNIFICANCE_NOTE = (
    "Bold: a scene's best mean whose paired difference to every other row (same seeds; for the object-scene "
    "mean, same seeds and scenes) has a 95% Student-t interval excluding zero; ≈: tied best, the best mean and "
    "the rows whose interval to it includes zero (one seed in common establishes nothing). ΔPSNR vs NVF: the "
    "row's paired PSNR difference to NVF in the same scene, mean [95% interval], over the n pairs shown where "
    "they are fewer than the row's seeds."
)


def _mark_best(rows: pd.DataFrame, samples: Samples) -> pd.DataFrame:
    """Add ``<metric>_best`` and ``<metric>_tie`` per (budget, scene) block (``SIGNIFICANCE_NOTE``), and the
    paired PSNR difference of each row to the block's NVF row (``psnr_vs_nvf_{mean,low,high,n}``)."""
    rows = rows.copy()
    for m in PAPER_METRICS:
        rows[f"{m.name}_best"] = False
        rows[f"{m.name}_tie"] = False
    for name in ("mean", "low", "high", "n"):
        rows[f"psnr_vs_nvf_{name}"] = math.nan
    keys = [tuple(key) for key in rows[list(GROUP)].itertuples(index=False)]
    for _, block in rows.groupby(["budget", "scene"], sort=False):
        index = list(block.index)
        if len(index) < 2:
            continue
        for m in PAPER_METRICS:
            means = rows.loc[index, f"{m.name}_mean"]
            if means.notna().sum() < 2 or means.max() == means.min():
                continue  # nothing to compare, or every row ties exactly
            best = means.idxmax() if m.higher_is_better else means.idxmin()
            sign = 1.0 if m.higher_is_better else -1.0
            tied = [
                i
                for i in index
                if i != best
                and pd.notna(means[i])
                and not paired(sign * samples[keys[best]][m.name], sign * samples[keys[i]][m.name]).above_zero
            ]
            column = f"{m.name}_tie" if tied else f"{m.name}_best"
            rows.loc[[best, *tied], column] = True
        reference = [i for i in index if (keys[i][2], keys[i][3], keys[i][4]) == REFERENCE]
        for i in index if reference else ():
            if i != reference[0]:
                interval = paired(samples[keys[i]]["psnr"], samples[keys[reference[0]]]["psnr"])
                rows.loc[i, ["psnr_vs_nvf_mean", "psnr_vs_nvf_low", "psnr_vs_nvf_high", "psnr_vs_nvf_n"]] = (
                    interval.mean,
                    interval.low,
                    interval.high,
                    interval.n,
                )
    return rows


def order_rows(rows: pd.DataFrame, runs: Runs) -> pd.DataFrame:
    """Rows by budget, scene (``scene.rank``) and the paper's row order (``RowName.order``)."""
    keys = [
        (budget, runs.scene(scene).order, runs.row(method, planner, ablation).order)
        for budget, scene, method, planner, ablation in rows[list(GROUP)].itertuples(index=False)
    ]
    return rows.iloc[sorted(range(len(keys)), key=keys.__getitem__)].reset_index(drop=True)


@dataclass(frozen=True)
class Spec:
    """A table: the Hydra experiment whose sweep fills it (``conf/experiment/<name>.yaml``; the methods,
    planners, ablations and scenes it sweeps are the ones the table takes, read as ``experiment_selection``
    reads them; None: every run), whether the NeRF-asset scenes add their mean row (``object_mean``) and
    whether they show through that mean only (``assets_as_mean``: the main table) and whether it takes
    every scene whatever its sweep runs (``every_scene``: the methods table, whose sweep runs the embedded
    scene and whose methods run on other scenes with ``experiment=methods scene=hotdog``)."""

    name: str
    title: str
    experiment: str | None
    object_mean: bool
    assets_as_mean: bool = False
    every_scene: bool = False


SPECS = (
    Spec("main", "Main table: Hubble, Room, NeRF-asset mean", "main", True, assets_as_mean=True),
    Spec("table1_opt", "Table S1: gradient-based view refinement (-OPT)", "table1_opt", True),
    Spec("table2_ablation", "Table S2: ablations", "table2_ablation", True),
    Spec("table34_nerf_assets", "Tables S3-S4: NeRF assets", "table34_nerf_assets", True),
    Spec("methods", "Every method per scene (argmax planner, no ablation)", "methods", False, every_scene=True),
    Spec("all_runs", "All runs: every scene and method, per scene", None, False),
)
SWEPT = ("method", "planner", "ablation", "scene")
DECLARED = "declared"  # a sweep over the options that declare the experiment (``${declared:GROUP,EXPERIMENT}``)


def experiment_selection(experiment: str | None, conf_dir: Path = CONF) -> dict[str, tuple[str, ...] | str | None]:
    """The options of each of ``SWEPT`` an experiment runs: the values its sweep lists, None (any) for
    ``glob(*)``, ``DECLARED`` for ``${declared:GROUP,EXPERIMENT}`` (the options whose own config declares
    the experiment) and the default choice (``conf/config.yaml``) for a group it does not sweep."""
    if experiment is None:
        return dict.fromkeys(SWEPT)
    listed = as_list(OmegaConf.load(Path(conf_dir) / "config.yaml").defaults, resolve=False)
    defaults = {k: v for d in listed if isinstance(d, dict) for k, v in d.items()}
    node = OmegaConf.select(
        OmegaConf.load(Path(conf_dir) / "experiment" / f"{experiment}.yaml"), "hydra.sweeper.params"
    )
    params = as_dict(node, resolve=False) if node is not None else {}
    selection: dict[str, tuple[str, ...] | str | None] = {}
    for key in SWEPT:
        value = str(params.get(key, defaults[key]))
        if value.startswith("glob("):
            selection[key] = None
        elif value.replace(" ", "") == f"${{declared:{key},{experiment}}}":
            selection[key] = DECLARED
        else:
            selection[key] = tuple(v.strip() for v in value.split(","))
    return selection


def _select(final: pd.DataFrame, spec: Spec, runs: Runs) -> pd.DataFrame:
    keep = pd.Series(True, index=final.index)
    for column, allowed in experiment_selection(spec.experiment).items():
        if column == "scene" and spec.every_scene:
            continue
        if allowed == DECLARED and column == "scene":
            keep &= np.array([spec.experiment in runs.scene(scene).experiments for scene in final["scene"]], dtype=bool)
        elif allowed == DECLARED:
            rows = zip(final["method"], final["planner"], final["ablation"], strict=True)
            keep &= np.array([spec.experiment in runs.row(*row).experiments for row in rows], dtype=bool)
        elif allowed is not None:
            keep &= final[column].isin(allowed)
    return final[keep]


def _notes(selected: pd.DataFrame, done: pd.DataFrame, rows: pd.DataFrame, runs: Runs) -> list[str]:
    notes = []
    notes += [note for flag, note in ORACLE_FLAGS if flag in rows and rows[flag].any()]
    if "irregular" in rows and rows["irregular"].any():
        notes.append(IRREGULAR_NOTE)
    if "in_paper" in rows and not rows["in_paper"].all():
        added = rows[~rows["in_paper"]]
        ours = list(dict.fromkeys(added.loc[added["in_repository"], "label"]))
        notes.append(not_in_paper_note(ours, list(dict.fromkeys(added.loc[~added["in_repository"], "label"]))))
    valid = rows[[f"{m}_valid" for m in METRIC_KEYS]].to_numpy() if not rows.empty else np.zeros((0, 1))
    if ((valid > 0) & (valid < rows[["n"]].to_numpy())).any():
        notes.append("† some seeds lack this value: the cell averages the others.")
    if (valid == 0).any():
        notes.append("'-': no run has this value.")
    if not rows.empty and (rows["n"].groupby([rows["budget"], rows["scene"]]).size() > 1).any():
        notes.append(SIGNIFICANCE_NOTE)
    for m in PAPER_METRICS:
        missing = done[done[m.name].isna()]
        if missing.empty:
            continue
        if m.name == "lpips":
            recorded = {r for r in missing["lpips_missing_reason"] if isinstance(r, str) and r}
            reasons = sorted(recorded or {"reason not recorded"})
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
            label = runs.row(run["method"], run["planner"], run["ablation"]).label
            reason = run["failure_reason"] or "no reason recorded"
            notes.append(f"Failed: {run['scene']} {label} seed {run['seed']} ({run['budget']}): {reason}.")
    if runs.skipped:
        notes.append(
            f"{len(runs.skipped)} run record(s) skipped: they fail a check (listed with the reason in all_runs and by "
            "`python -m pipeline.tables`)."
        )
    if runs.conflicts:
        notes.append(
            f"{len(runs.conflicts)} conflict(s) between copies of a run left records out: a copy with other settings "
            "than "
            "the kept one, or finished copies that differ, none of which counts (listed by `python -m "
            "pipeline.tables`)."
        )
    return notes


def _header(done: pd.DataFrame, runs: Runs) -> tuple[str, ...]:
    budgets = ", ".join(sorted(set(done["budget"])))
    steps = ", ".join(str(s) for s in sorted(set(done["step"].astype(int))))
    by_scene = done.groupby("scene")
    sources = {
        column: by_scene[column].agg(lambda s: "/".join(sorted(set(s) - {""})))
        for column in ("scene_source", "asset", "ground_truth")
    }
    scenes = "; ".join(
        f"{scene} ({' '.join(filter(None, (sources['scene_source'][scene], sources['asset'][scene])))}, "
        f"ground truth {sources['ground_truth'][scene]})"
        for scene in sorted(by_scene.groups, key=lambda scene: runs.scene(scene).order)
    )
    return (
        f"Budget: {budgets}. Cells: mean ± population std over seeds at the last step (step {steps}), the mean alone "
        "from one seed; n = seeds.",
        f"Scenes: {scenes}. Proxies and procedural scenes are stand-ins, not the paper's assets; pyrender's ground "
        "truth is flat (unlit), Blender Cycles' lit (docs/DEVIATIONS.md).",
    )


def build_table(runs: Runs, spec: Spec) -> Table:
    """Aggregate the finished runs a spec selects into one Table (rows empty when there are none);
    ``all_runs`` also lists every skipped record with its reason."""
    table = _build_table(runs, spec)
    if spec.name != "all_runs" or not runs.skipped:
        return table
    return dataclasses.replace(table, notes=(*table.notes, *(f"{line[0].upper()}{line[1:]}." for line in runs.skipped)))


def _build_table(runs: Runs, spec: Spec) -> Table:
    selected = _select(runs.final, spec, runs)
    done = selected[selected["status"] == "done"]
    nerf_asset = pd.Series([runs.scene(scene).nerf_asset for scene in done["scene"]], index=done.index, dtype=bool)
    per_scene = done[~nerf_asset] if spec.assets_as_mean else done
    parts = [aggregate(per_scene)] if not per_scene.empty else []
    samples = seed_samples(per_scene)
    mean_notes: tuple[str, ...] = ()
    object_scenes = done.loc[nerf_asset, "scene"].nunique()
    if spec.object_mean and (object_scenes > 1 or (spec.assets_as_mean and object_scenes)):
        mean_rows, mean_notes, mean_samples = object_mean(done, runs)
        parts.append(mean_rows)
        samples |= mean_samples
    if not parts:
        notes = _notes(selected, done, pd.DataFrame(columns=["n"]), runs)
        return Table(spec.name, spec.title, pd.DataFrame(), (), tuple(notes))
    rows = order_rows(_mark_best(pd.concat(parts, ignore_index=True), samples), runs)
    keys = zip(rows["method"], rows["planner"], rows["ablation"], strict=True)
    names = [runs.row(m, p, a) for m, p, a in keys]
    rows["label"] = [name.label for name in names]
    rows["in_paper"] = [name.in_paper for name in names]
    rows["in_repository"] = [name.in_repository for name in names]
    notes = _notes(selected, done, rows, runs) + [f"{OBJECT_MEAN}: {n}." for n in mean_notes]
    return Table(spec.name, spec.title, rows, _header(done, runs), tuple(notes))
