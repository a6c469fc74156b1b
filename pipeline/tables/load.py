"""Run records -> data frames: every run directory under some roots read once (identical copies of a run
count once; finished copies with the same settings that differ are named and none of them counts), into a
long frame (one row per run, step and metric) and a final frame (one row per run, its last step's metrics).
Step rows store NaN as ``null`` (pipeline.records); it is read back as NaN."""

import dataclasses
import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from pipeline.config.settings_beyond_groups import GROUPS, NamedConfigs
from pipeline.records.files import escaping_link
from pipeline.records.store import IDENTITY_KEYS, RECORD_FILES, RecordError, RunRecord, first_difference, run_difference
from pipeline.records.verify import verified_current
from pipeline.repo import CONF
from pipeline.tables.labels import LAST, MEAN_SCENE, METRIC_KEYS, OBJECT_MEAN, RowName, SceneName, row_name, scene_name

LONG_COLUMNS = (
    "scene",
    "scene_source",
    "method",
    "planner",
    "ablation",
    "budget",
    "seed",
    "step",
    "n_views",
    "metric",
    "value",
)
FINAL_COLUMNS = (
    *IDENTITY_KEYS,
    "scene_source",
    "asset",
    "ground_truth",
    "status",
    "failure_reason",
    "lpips_missing_reason",
    "mesh_los",
    "mesh_visibility",
    "dirty",
    "threads",
    "directory",
    "step",
    "n_views",
)
GROUP = ("budget", "scene", "method", "planner", "ablation")
# run.json keys besides the settings that reach a table (``collect_runs``'s final frame)
TABULATED = (
    "scene_source",
    "ground_truth",
    "failure_reason",
    "lpips_missing_reason",
    "collision_free",
    "candidate_filters",
)


def json_object(value: Any) -> dict:
    """``value`` when it is a JSON object (a dict), else an empty dict: a record's optional sections."""
    return value if isinstance(value, dict) else {}


def ground_truth_label(info: dict) -> tuple[str, str]:
    """The asset file (empty when the record does not say) and the ground-truth backend of a run record:
    ``pyrender`` or ``Blender Cycles <n> spp``. Records from before the Blender backend are pyrender's."""
    recorded = json_object(info.get("ground_truth"))
    render = json_object(json_object(info.get("config")).get("render"))
    backend = recorded.get("backend", render.get("backend", "pyrender"))
    if backend == "blender":
        backend = f"Blender Cycles {recorded.get('samples', render.get('samples'))} spp"
    return str(recorded.get("asset") or ""), str(backend)


@dataclass(frozen=True)
class Runs:
    """All run records: ``long`` (LONG_COLUMNS, finished runs), ``final`` (one row per run, last-step
    metrics); ``skipped`` (records that fail a check, with the reason) and ``conflicts`` (records left
    out because a kept record of the same run has other settings, and finished copies of one run that
    differ with the same settings, none of which is kept), one line each."""

    long: pd.DataFrame
    final: pd.DataFrame
    skipped: tuple[str, ...]
    conflicts: tuple[str, ...] = ()
    rows: Mapping[tuple[str, str, str], RowName] = dataclasses.field(
        default_factory=dict
    )  # (method, planner, ablation)
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
    """How tables name a record's row and scene, from its config (``effective_config``); the experiments a
    method or scene joins are read from today's ``conf/`` where it still has the group (a declaration is
    the benchmark's current choice, not a setting of the run)."""
    named = NamedConfigs(CONF) if named is None else named
    today = named.named(tuple(str(info[g]) for g in GROUPS)) or {}
    config = effective_config(info.get("config") or {}, today)
    names = {group: {"name": info[group]} for group in ("scene", "method", "ablation", "planner")}
    config = effective_config(config, names)  # groups conf/ no longer has and the record lacks: their names
    for group in ("scene", "method"):  # which experiments a method or scene joins is today's declaration
        declared = (today.get(group) or {}).get("experiments")
        config[group] = {**config[group], **({"experiments": declared} if declared is not None else {})}
    return row_name(config), scene_name(config)


def metric_value(value: object) -> float | None:
    """Float of a recorded metric (null -> NaN); None for non-numeric entries."""
    if value is None:
        return math.nan
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value)


def load_run(directory: Path) -> tuple[dict, list[dict]]:
    """run.json and the step rows of a record that passes ``pipeline.records.verify``, read as the current record
    version (``pipeline.records.upgrade``; read-only); RecordError (one line naming the file and the problem)
    otherwise."""
    info, rows = verified_current(RunRecord(directory))
    if not info:
        raise RecordError(f"{directory}: no run.json")
    return info, rows


def used_mesh_line_of_sight(info: dict) -> bool:
    """Whether the run's candidates were filtered by the scene mesh's exact line of sight (M29 with
    ``planner.los_source=mesh`` and the collision-free sampler): an oracle, marked in the tables."""
    planner = json_object(json_object(info.get("config")).get("planner"))
    filtered = info.get("candidate_filters") is True and info.get("collision_free") is True
    return planner.get("los_source") == "mesh" and filtered


def used_mesh_visibility(info: dict) -> bool:
    """Whether NVF's scores read the visibility from the scene mesh (``nvf.entropy.visibility_source=mesh``
    with the visibility in use): an oracle, marked in the tables."""
    config = json_object(info.get("config"))
    entropy = json_object(json_object(config.get("nvf")).get("entropy"))
    return (
        json_object(config.get("method")).get("name") == "nvf"
        and entropy.get("visibility_source") == "mesh"
        and entropy.get("use_visibility") is True
    )


def record_directories(root: Path) -> tuple[list[Path], list[str]]:
    """Every directory under ``root`` holding an entry named as a file of a run record (run.json, steps.jsonl,
    DONE, FAILED), whatever it is (a link there fails verification, in one line), and one skip line for each
    directory link leaving ``root`` (never followed)."""
    if not Path(root).is_dir():
        return [], []
    found, links = set(), []
    for folder, subfolders, files in os.walk(root):  # links to folders are listed, never entered
        if any(name in RECORD_FILES for name in (*files, *subfolders)):
            found.add(Path(folder))
        for name in subfolders:
            link = escaping_link(Path(root), Path(folder) / name)
            if link is not None:
                links.append(f"skipped run records under {link[0]}: a symbolic link to {link[1]}, outside {root}")
    return sorted(found), sorted(links)


def _short(value: Any) -> str:
    text = json.dumps(value)
    return text if len(text) <= 40 else f"{text[:37]}..."


def copy_difference(one: dict, other: dict) -> str | None:
    """How two copies of a run with the same settings differ in what the tables read: the first row and key,
    else the first of run.json's ``TABULATED`` keys; None when the tables would show either alike (times and
    provenance may differ: two copies written at other moments)."""
    pairs = [
        (f"step {index} ", mine, theirs)
        for index, (mine, theirs) in enumerate(zip(one["rows"], other["rows"], strict=False))  # the steps both hold
    ]
    tabulated = [{key: copy["info"].get(key) for key in TABULATED} for copy in (one, other)]
    for prefix, mine, theirs in [*pairs, ("run.json ", tabulated[0], tabulated[1])]:
        found = first_difference(mine, theirs, prefix)
        if found is not None:
            key, was, now = found
            return f"{key} ({_short(was)} in the first, {_short(now)} in the second)"
    if len(one["rows"]) != len(other["rows"]):
        return f"{len(one['rows'])} rows in the first, {len(other['rows'])} in the second"
    return None


def _choose(copies: list[dict], conflicts: list[str]) -> dict | None:
    """The copy of one run that counts (a finished copy, then the first root's), appending a line to
    ``conflicts`` for each copy left out: a copy with other settings than the kept one is named; finished
    copies with the kept one's settings count once where identical, and where they differ (their rows, what the
    tables show) all of them are named in one line and none counts."""
    finished = [copy for copy in copies if copy["status"] == "done"]
    kept = finished[0] if finished else copies[0]
    for copy in copies:
        changed = None if copy is kept else run_difference(copy["info"], kept["info"], labels=("here", "there"))
        if changed is not None:
            conflicts.append(
                f"left out {copy['directory']}: the same run as {kept['directory']} but a different {changed}"
            )
    same = [copy for copy in finished if run_difference(copy["info"], kept["info"]) is None]
    distinct = [copy for i, copy in enumerate(same) if all(copy_difference(copy, other) for other in same[:i])]
    if len(distinct) < 2:
        return kept
    named = " and ".join(str(copy["directory"]) for copy in distinct)
    conflicts.append(
        f"left out every copy of one run: {named} are finished copies that differ "
        f"({copy_difference(distinct[0], distinct[1])}); remove the ones that are wrong"
    )
    return None


def collect_runs(roots: list[Path]) -> Runs:
    """Read every run record under ``roots`` (``record_directories``); one that fails a check
    (``pipeline.records.verify``) is listed in ``skipped`` with the reason, and so is every link to a folder
    outside its root (never followed). Copies of one run (same identity keys) are resolved by ``_choose``, every
    copy left out listed in ``conflicts``: a table never mixes runs, or picks between differing copies, silently."""
    copies: dict[tuple, list[dict]] = {}
    seen: set[Path] = set()
    skipped: list[str] = []
    conflicts: list[str] = []
    for root in roots:
        directories, links = record_directories(root)
        skipped += links
        for directory in directories:
            if directory.resolve() in seen:  # the same directory reached from two roots
                continue
            seen.add(directory.resolve())
            try:
                info, rows = load_run(directory)
            except (ValueError, OSError) as err:
                skipped.append(f"skipped run record: {str(err).splitlines()[0]}")
                continue
            record: dict[str, Any] = {
                "info": info,
                "rows": rows,
                "status": RunRecord(directory).status(),
                "directory": directory,
            }
            copies.setdefault(tuple(info[k] for k in IDENTITY_KEYS), []).append(record)
    records = [kept for group in copies.values() if (kept := _choose(group, conflicts)) is not None]
    long_rows, final_rows = [], []
    names: dict[tuple[str, str, str], RowName] = {}
    scenes: dict[str, SceneName] = {}
    named = NamedConfigs(CONF)
    for record in records:
        info, rows = record["info"], record["rows"]
        keys = {k: info[k] for k in IDENTITY_KEYS}
        row_label, scene_label = describe(info, named)
        names.setdefault((info["method"], info["planner"], info["ablation"]), row_label)
        scenes.setdefault(info["scene"], scene_label)
        keys["budget"] = named.budget_label(info)
        source = str(info.get("scene_source", "unknown"))
        asset, ground_truth = ground_truth_label(info)
        last = max(rows, key=lambda r: r["step"]) if rows else {"metrics": {}}
        final = {
            **keys,
            "scene_source": source,
            "asset": asset,
            "ground_truth": ground_truth,
            "status": record["status"],
            "failure_reason": info.get("failure_reason"),
            "lpips_missing_reason": info.get("lpips_missing_reason") or last.get("lpips_missing_reason"),
            "mesh_los": used_mesh_line_of_sight(info),
            "mesh_visibility": used_mesh_visibility(info),
            "dirty": bool((info.get("git") or {}).get("dirty")),
            "threads": int(info.get("torch_threads") or 0),
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
