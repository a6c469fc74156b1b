"""The visibility study's table: one row per setting and scene (and per setting over all its scenes) from
the folders ``python -m pipeline.experiments.visibility_study`` writes under
``${paths.results}/pilots/visibility_study/``.

Columns: ``setting, scene, visibility_source, label_auc, head_auc`` (the initial views' separation of seen
from unseen object pixels, ``pipeline.bench visibility``), ``spearman_nvf_wo_vis`` (mean over the studied
candidate sets), ``onestep_gain_mean, onestep_ci_low, onestep_ci_high, n`` (NVF's pick minus w/o Vis.'s
in held-out PSNR, dB, where they differ, with the 95% Student-t interval over the ``n`` disagreements),
``minutes_per_episode`` (NVF's and w/o Vis.'s mean in the setting's discrimination experiment when it has
one, ``episode_minutes``, else empty), then
``decisions`` (candidate sets studied), ``same_argmax_fraction``, ``nvf_decisive_term`` (the reward term
deciding NVF's ranking most often), ``nvf_unknown_share`` (the unknown component's mean share of NVF's
reward variance) and ``nvf_tied_fraction``, ``wo_vis_tied_fraction`` (the candidate sets whose maximum
several candidates share: a pick by draw order).

``surface.csv``: how fast NVF, w/o Vis. and Random uncover a scene's surface in the finished records
(``vis_area``: the area-weighted share of the surface the training views see, PROTOCOL's Vis. by area), per
scene and step the mean over seeds and NVF minus w/o Vis. paired over seeds with its 95% interval.

``python -m pipeline.experiments.visibility_summary [paths.results=DIR] [--records DIR]`` rewrites both. The
study's files are read back checked (``pipeline.records.checked_files``: ``SETTING``, ``DECISION``, ``DIAGNOSTIC``, and
the discrimination experiment's ``PER_SEED`` columns): one that fails is one ``error:`` line naming the file, the
line and the key, and nothing is written.
"""

import collections
import math
import os
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.atomic_write import atomic_write_text
from pipeline.cli import ArgumentParser, description, run_command
from pipeline.config.settings_beyond_groups import config_label
from pipeline.config.validation import compose_run
from pipeline.records.checked_files import Each, Entries, Number, Optional, Text, read_csv, read_json, read_json_lines
from pipeline.records.experiment_columns import (
    DISCRIMINATE_PER_SEED_COLUMNS,
    STUDY_SUMMARY_COLUMNS,
    STUDY_SURFACE_COLUMNS,
    only,
)
from pipeline.records.files import escaping_link, make_directory
from pipeline.records.schema import MAX_HORIZON
from pipeline.records.store import MAX_SEED
from pipeline.repo import RUNS
from pipeline.tables.escape import as_csv
from pipeline.tables.load import collect_runs
from pipeline.tables.stats import Interval, paired

STUDY = "visibility_study"
TEXT = ("setting", "scene", "visibility_source", "nvf_decisive_term")  # csv columns of names (escaped)
COLUMNS = tuple(STUDY_SUMMARY_COLUMNS)  # summary.csv's, declared with their shapes in pipeline.records
ALL_SCENES = "all"
SURFACE_ENTRIES = {"nvf": ("nvf", "none"), "wo_vis": ("nvf", "wo_vis"), "random": ("random", "none")}
SURFACE_COLUMNS = tuple(STUDY_SURFACE_COLUMNS)  # surface.csv's


# what the summary and the study read of the study's files (the other keys are kept, not read)
SETTING = {
    "name": Text(),
    "overrides": Optional(Each(Text())),
    "visibility_source": Optional(Text()),
    "budget": Optional(Text()),
    "state_budget": Optional(Text()),
    "threads": Optional(Number(1, 4096, integer=True)),  # missing: made with one (before it was recorded)
}
COUNT = Number(0, 2**31, integer=True)
DECISION = {
    "scene": Text(),
    "seed": Number(0, MAX_SEED, integer=True),
    "step": Number(0, MAX_HORIZON, integer=True),
    "set": COUNT,
    "spearman": Number(-1.0, 1.0, null=True),
    "same_argmax": bool,
    "ties_at_max": {"nvf": COUNT, "wo_vis": COUNT},
    "terms": {"nvf": {"decisive": Text(null=True), "terms": {"unknown": {"share": Number(null=True)}}}},
    "gain": Optional(Number(-100.0, 100.0)),  # dB
}
DIAGNOSTIC = {"sources": Optional(Entries({"auc_mean": Optional(Number(0.0, 1.0, null=True))}))}
PER_SEED = only(DISCRIMINATE_PER_SEED_COLUMNS, "scene", "method", "ablation", "minutes")


def _rows(folder: Path) -> list[dict]:
    return read_json_lines(folder / "decisions.jsonl", DECISION)[0]


def _diagnostic(folder: Path, scene: str) -> dict:
    return read_json(folder / f"{scene}_diagnostic.json", DIAGNOSTIC) or {}


def _mean(values: list) -> float:
    kept = [v for v in values if v is not None]
    return float(np.mean(kept)) if kept else math.nan


def episode_minutes(study: Path, setting: dict) -> dict[str, float]:
    """Mean minutes per episode of NVF and w/o Vis., per scene and over all (``ALL_SCENES``), in the setting's
    discrimination experiment (``pilots/discriminate/<its budget label>/per_seed.csv``,
    ``pipeline.experiments.discriminate``), or {} where it has none."""
    overrides = [o for o in setting.get("overrides", []) if not o.startswith("paths.")]
    label = config_label(compose_run([f"budget={setting.get('budget', 'cpu')}", *overrides]).composed)
    runs = read_csv(study.parent / "discriminate" / label / "per_seed.csv", PER_SEED)
    if runs is None:
        return {}
    runs = runs[(runs["method"] == "nvf") & runs["ablation"].isin(["none", "wo_vis"])]
    minutes = {str(scene): float(m) for scene, m in runs.groupby("scene")["minutes"].mean().items()}
    return minutes | ({ALL_SCENES: float(runs["minutes"].mean())} if len(runs) else {})


def setting_row(setting: dict, scene: str, rows: list[dict], diagnostics: list[dict]) -> dict:
    """The summary row of one setting over ``rows`` (one scene's, or all of them)."""
    gains = np.array([r["gain"] for r in rows if "gain" in r], dtype=float)
    interval = Interval.of(gains)
    decisive = collections.Counter(r["terms"]["nvf"]["decisive"] for r in rows)
    sources = [d.get("sources", {}) for d in diagnostics]
    return {
        "setting": setting["name"],
        "scene": scene,
        "visibility_source": setting.get("visibility_source", "head"),
        "label_auc": _mean([s.get("labels", {}).get("auc_mean") for s in sources]),
        "head_auc": _mean([s.get("head", {}).get("auc_mean") for s in sources]),
        "spearman_nvf_wo_vis": _mean([r["spearman"] for r in rows]),
        "onestep_gain_mean": interval.mean,
        "onestep_ci_low": interval.low,
        "onestep_ci_high": interval.high,
        "n": interval.n,
        "minutes_per_episode": setting.get("minutes_per_episode", {}).get(scene, math.nan),
        "decisions": len(rows),
        "same_argmax_fraction": _mean([float(r["same_argmax"]) for r in rows]),
        "nvf_decisive_term": decisive.most_common(1)[0][0] if decisive else None,
        "nvf_unknown_share": _mean([r["terms"]["nvf"]["terms"]["unknown"]["share"] for r in rows]),
        "nvf_tied_fraction": _mean([float(r["ties_at_max"]["nvf"] > 1) for r in rows]),
        "wo_vis_tied_fraction": _mean([float(r["ties_at_max"]["wo_vis"] > 1) for r in rows]),
    }


def summary_frame(study: Path) -> pd.DataFrame:
    """Every setting folder under ``study``: a row per scene and one over all its scenes."""
    out = []
    folders = [p for p in study.iterdir() if p.is_dir() and escaping_link(study, p) is None]
    for folder in sorted(p for p in folders if os.path.lexists(p / "setting.json")):
        setting = read_json(folder / "setting.json", SETTING)
        setting["minutes_per_episode"] = episode_minutes(study, setting)
        rows = _rows(folder)
        scenes = list(dict.fromkeys(r["scene"] for r in rows))
        for scene in scenes:
            out.append(
                setting_row(setting, scene, [r for r in rows if r["scene"] == scene], [_diagnostic(folder, scene)])
            )
        if len(scenes) > 1:
            out.append(setting_row(setting, ALL_SCENES, rows, [_diagnostic(folder, scene) for scene in scenes]))
    return pd.DataFrame(out, columns=list(COLUMNS))


def write_summary(study: Path) -> Path:
    """Write ``<study>/summary.csv`` (atomically) and return its path."""
    path = study / "summary.csv"
    atomic_write_text(path, as_csv(summary_frame(study), TEXT, "%.4g"))
    return path


def surface_frame(records: Path, budget: str = "cpu") -> pd.DataFrame:
    """``surface.csv``'s rows from the finished argmax-planner records of ``budget`` under ``records``: the
    scenes where both NVF and w/o Vis. have records, every step."""
    long = collect_runs([records]).long
    long = long[(long["metric"] == "vis_area") & (long["budget"] == budget) & (long["planner"] == "argmax")]
    out = []
    for (scene, step), group in long.groupby(["scene", "step"], sort=True):
        series = {
            name: group[(group["method"] == method) & (group["ablation"] == ablation)].set_index("seed")["value"]
            for name, (method, ablation) in SURFACE_ENTRIES.items()
        }
        if series["nvf"].empty or series["wo_vis"].empty:
            continue
        interval = paired(series["nvf"], series["wo_vis"])
        means = {f"{name}_vis_area": values.mean() if len(values) else math.nan for name, values in series.items()}
        out.append(
            {"scene": scene, "step": int(step), **means, "nvf_minus_wo_vis": interval.mean, "ci_low": interval.low,
             "ci_high": interval.high, "n": interval.n}
        )  # fmt: skip
    return pd.DataFrame(out, columns=list(SURFACE_COLUMNS))


def write_surface(study: Path, records: Path) -> Path:
    """Write ``<study>/surface.csv`` (atomically) from the records under ``records`` and return its path."""
    path = study / "surface.csv"
    atomic_write_text(path, as_csv(surface_frame(records), TEXT, "%.4g"))
    return path


def main(argv: list[str]) -> None:
    parser = ArgumentParser(prog="python -m pipeline.experiments.visibility_summary", description=description(__doc__))
    parser.add_argument("overrides", nargs="*", help="config overrides, e.g. paths.results=results")
    parser.add_argument("--records", type=Path, default=RUNS, help=f"where the finished records are (default {RUNS})")
    args = parser.parse_intermixed_args(argv)
    results = Path(compose_run(args.overrides).paths.results)
    study = make_directory(results, results / "pilots" / STUDY)
    for path in (write_summary(study), write_surface(study, args.records)):
        print(f"wrote {path}")


if __name__ == "__main__":
    run_command(main, sys.argv[1:])
