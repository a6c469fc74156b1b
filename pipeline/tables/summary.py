"""One run's per-step metrics as Markdown (``<run_dir>/summary.md``), with the paper's row for its scene
and method where the paper has one, and its pictures (``run_pictures``: image grid, PSNR curve, cameras).
Record text is escaped (``pipeline.tables.escape``)."""

import math
from pathlib import Path

import pandas as pd

from pipeline.atomic_write import atomic_write_text
from pipeline.config.settings_beyond_groups import NamedConfigs
from pipeline.metrics.info import PAPER_METRICS
from pipeline.records.files import is_plain_file
from pipeline.records.store import record_status
from pipeline.repo import CONF
from pipeline.tables.escape import markdown
from pipeline.tables.figures import image_grid, step_curve, step_images
from pipeline.tables.labels import METRIC_KEYS
from pipeline.tables.load import describe, ground_truth_label, json_object, load_run, metric_value
from pipeline.tables.paper import paper_numbers
from pipeline.tables.trajectory import SceneOutline, outline_of_config, recorded_scene, trajectory_figure


def summarize_run(run_dir: Path) -> Path:
    """Per-step metrics of one run (and the paper's row for its scene and method, if any) as Markdown
    in ``<run_dir>/summary.md``; returns its path."""
    info, rows = load_run(Path(run_dir))
    row_name, scene_name = describe(info)
    label = row_name.label
    columns = ["Step", "Views"] + [f"{m.label}{m.arrow}" for m in PAPER_METRICS] + ["Seconds"]
    cells = []
    for row in rows:
        if row.get("status", "ok") != "ok" or not isinstance(row.get("metrics"), dict):
            continue
        values = [metric_value(row["metrics"].get(metric)) for metric in METRIC_KEYS]
        total = sum(v for v in json_object(row.get("seconds")).values() if isinstance(v, (int, float)))
        line = [str(row["step"]), str(row.get("n_views", ""))]
        line += [
            "-" if v is None or math.isnan(v) else f"{v:.{m.decimals}f}"
            for v, m in zip(values, PAPER_METRICS, strict=True)
        ]
        cells.append(line + [f"{total:.1f}"])
    paper = paper_numbers()
    match = paper[paper["table"].isin(["S3", "S4"]) & (paper["scene"] == scene_name.paper_scene)]
    for _, ref in match[match["method"] == label].iterrows():
        cells.append([f"paper ({ref['table']})", ""] + [f"{ref[m.name]:.{m.decimals}f}" for m in PAPER_METRICS] + [""])
    table = pd.DataFrame(cells, columns=columns).to_markdown(index=False, disable_numparse=True)
    source = info.get("scene_source", "unknown")
    asset, ground_truth = ground_truth_label(info)
    source = f"{source} ({asset})" if asset else source
    notes = [f"Status: {record_status(info, Path(run_dir))}. Scene source: {source}. Ground truth: {ground_truth}."]
    if info.get("lpips_missing_reason"):
        notes.append(f"LPIPS missing: {info['lpips_missing_reason']}.")
    title = f"# {markdown(info['scene'])} / {markdown(label)} / {markdown(info['budget'])} budget / seed {info['seed']}"
    path = Path(run_dir) / "summary.md"
    atomic_write_text(path, "\n".join([title, "", table, "", *(f"- {markdown(n)}" for n in notes)]) + "\n")
    return path


def run_title(info: dict) -> str:
    """``scene / method label / budget budget / seed n`` of a run record."""
    return f"{info['scene']} / {describe(info)[0].label} / {info['budget']} budget / seed {info['seed']}"


def run_pictures(run_dir: Path, outline: SceneOutline) -> list[Path]:
    """A finished run's labelled pictures beside its records: ``grid.png`` (steps x GT | prediction | score
    map | depth; only when the run saved its images), ``psnr.png`` (PSNR per step) and ``trajectory.png``
    (its cameras over ``outline``, the scene's)."""
    info, rows = load_run(Path(run_dir))
    title = run_title(info)
    grid = image_grid(Path(run_dir), Path(run_dir) / "grid.png", title)
    return [
        *([grid] if grid is not None else []),
        step_curve(rows, title, Path(run_dir) / "psnr.png"),
        trajectory_figure(outline, rows, title, Path(run_dir) / "trajectory.png"),
    ]


def finish_run(run_dir: Path, outline: SceneOutline) -> None:
    """What a run leaves beside its records once it is done: ``summary.md`` and its pictures (``run_pictures``)
    over ``outline``, its scene's (``outline_of_scene`` of the scene it observed, or ``recorded_outline``)."""
    summarize_run(run_dir)
    run_pictures(run_dir, outline)


def missing_pictures(run_dir: Path) -> bool:
    """Whether a finished run lacks what ``finish_run`` leaves: ``summary.md``, ``psnr.png``, ``trajectory.png``,
    and ``grid.png`` where it saved images (a run killed after its DONE marker and before its pictures)."""
    run_dir = Path(run_dir)
    needed = ["summary.md", "psnr.png", "trajectory.png", *(["grid.png"] if step_images(run_dir) else [])]
    return not all(is_plain_file(run_dir / name) for name in needed)


def recorded_outline(run_dir: Path, assets: Path) -> SceneOutline:
    """The outline of a finished run's scene as its record describes it (``outline_of_config``; its surface read
    from the asset under ``assets`` where it is there)."""
    info, _ = load_run(Path(run_dir))
    return outline_of_config(recorded_scene(info, NamedConfigs(CONF)), Path(assets))
