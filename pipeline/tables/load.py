"""Run records -> data frames: every run directory under some roots read once (a run found twice counts
once), into a long frame (one row per run, step and metric) and a final frame (one row per run, its
last step's metrics). Step rows store NaN as ``null`` (pipeline.records); it is read back as NaN."""

import dataclasses
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from pipeline.config.named import GROUPS, NamedConfigs
from pipeline.records.store import (
    IDENTITY_KEYS,
    RUN_JSON,
    STEPS,
    check_key,
    read_steps,
    record_status,
    run_difference,
)
from pipeline.repo import CONF
from pipeline.tables.labels import LAST, MEAN_SCENE, METRIC_KEYS, OBJECT_MEAN, RowName, SceneName, row_name, scene_name


LONG_COLUMNS = (
    "scene", "scene_source", "method", "planner", "ablation", "budget", "seed", "step", "n_views", "metric", "value"
)
FINAL_COLUMNS = (
    *IDENTITY_KEYS, "scene_source", "status", "failure_reason", "lpips_missing_reason", "directory", "step", "n_views"
)
GROUP = ("budget", "scene", "method", "planner", "ablation")


@dataclass(frozen=True)
class Runs:
    """All run records: ``long`` (LONG_COLUMNS, finished runs), ``final`` (one row per run, last-step
    metrics); ``skipped`` (unreadable records) and ``conflicts`` (records left out because a kept record
    of the same run has other settings), one line each."""

    long: pd.DataFrame
    final: pd.DataFrame
    skipped: tuple[str, ...]
    conflicts: tuple[str, ...] = ()
    rows: Mapping[tuple[str, str, str], RowName] = dataclasses.field(default_factory=dict)  # (method, planner, ablation)
    scenes: Mapping[str, SceneName] = dataclasses.field(default_factory=dict)

    def row(self, method: str, planner: str, ablation: str) -> RowName:
        """How tables name and order a (method, planner, ablation); a row the records do not name gets its keys."""
        return self.rows.get((method, planner, ablation), RowName(f"{method} {planner} {ablation}", (True, method)))

    def scene(self, scene: str) -> SceneName:
        """How tables order a scene (the object-scene mean last)."""
        return MEAN_SCENE if scene == OBJECT_MEAN else self.scenes.get(scene, SceneName((LAST - 1, scene), None, False))


def effective_config(recorded: Any, named: Any) -> Any:
    """A record's config with every key it predates read from ``named`` (today's config of the same named
    groups): what the run's labels and scene data were."""
    if isinstance(recorded, Mapping) and isinstance(named, Mapping):
        return {key: effective_config(recorded.get(key), named.get(key)) for key in recorded.keys() | named.keys()}
    return named if recorded is None else recorded


def describe(info: Mapping[str, Any], named: NamedConfigs | None = None) -> tuple[RowName, SceneName]:
    """How tables name a record's row and scene, from its config (``effective_config``)."""
    named = NamedConfigs(CONF) if named is None else named
    config = effective_config(info.get("config") or {}, named.named(tuple(str(info[g]) for g in GROUPS)) or {})
    return row_name(config), scene_name(config)


def metric_value(value: object) -> float | None:
    """Float of a recorded metric (null -> NaN); None for non-numeric entries."""
    if value is None:
        return math.nan
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value)


def load_run(directory: Path) -> tuple[dict, list[dict]]:
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
                info, rows = load_run(directory)
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
    names: dict[tuple[str, str, str], RowName] = {}
    scenes: dict[str, SceneName] = {}
    named = NamedConfigs(CONF)
    for record in records.values():
        info, rows = record["info"], record["rows"]
        keys = {k: info[k] for k in IDENTITY_KEYS}
        row, scene = describe(info, named)
        names.setdefault((info["method"], info["planner"], info["ablation"]), row)
        scenes.setdefault(info["scene"], scene)
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
            value = metric_value(last["metrics"].get(metric))
            final[metric] = math.nan if value is None else value
        final_rows.append(final)
        if record["status"] != "done":
            continue
        for row in rows:
            for metric, raw in row["metrics"].items():
                value = metric_value(raw)
                if value is not None:
                    step = {"step": row["step"], "n_views": row.get("n_views")}
                    long_rows.append({**keys, "scene_source": source, **step, "metric": str(metric), "value": value})
    long = pd.DataFrame(long_rows, columns=list(LONG_COLUMNS))
    long = long.astype({"seed": "int64", "step": "int64", "n_views": "Int64", "value": "float64"})
    long = long.sort_values(list(LONG_COLUMNS[:8])).reset_index(drop=True)
    final_frame = pd.DataFrame(final_rows, columns=[*FINAL_COLUMNS, *METRIC_KEYS])
    return Runs(long, final_frame, tuple(skipped), tuple(conflicts), names, scenes)
