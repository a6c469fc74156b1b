"""Every table and figure from the run records: long CSV, the paper's tables (md, csv, tex), the comparison
with the paper, curves and image grids, and the results site (with the pictures older records lack)."""

from pathlib import Path

from pipeline.atomic_write import atomic_write_text
from pipeline.config.paths import configured_paths
from pipeline.config.settings_beyond_groups import NamedConfigs
from pipeline.records.files import check_directory, make_directory
from pipeline.repo import CONF
from pipeline.tables.aggregate import GROUP, SPECS, build_table
from pipeline.tables.compare import paper_comparison
from pipeline.tables.escape import csv_cell
from pipeline.tables.figures import curves, file_name, image_grid, safe_name
from pipeline.tables.load import Runs, collect_runs, load_run
from pipeline.tables.site import RunPictures, write_site
from pipeline.tables.summary import run_title
from pipeline.tables.table_formats import LABEL_HEADERS, render
from pipeline.tables.trajectory import outline_of_config, recorded_scene, trajectory_figure

OUTPUT_DIRECTORIES = ("tables", "figures", "figures/grids", "site", "site/runs")  # under paths.results
TEXT_COLUMNS = (
    "scene",
    "scene_source",
    "method",
    "planner",
    "ablation",
    "budget",
    "metric",
)  # runs.csv's, from records


def prepare_outputs(results: Path) -> None:
    """Create ``results``; ``RecordError`` (nothing written) when one of its ``OUTPUT_DIRECTORIES`` lies behind a
    symbolic link leaving ``results`` or is a file."""
    make_directory(Path(results), Path(results))
    for name in OUTPUT_DIRECTORIES:
        check_directory(Path(results), Path(results) / name)


def build_tables(
    outputs: Path, runs_dirs: list[Path], results: Path, figures: bool = True, assets: Path | None = None
) -> tuple[list[Path], tuple[str, ...]]:
    """Collect runs, write runs.csv, the tables (md/csv/tex), the paper comparison and (unless
    ``figures`` is False) the curves, image grids and the site, with the ``grid.png`` and
    ``trajectory.png`` of each finished run that lacks them (``run_pictures_of``; scene outlines read from
    ``assets``). Every file is written under ``results``.

    Returns the files written and one line per run record skipped (unreadable) or left out (settings
    that conflict with a kept record of the same run, differing finished copies), or whose pictures could not
    be written. Nothing is written before the output directories are checked (``prepare_outputs``) and
    every figure's file name is known.
    """
    results = Path(results)
    prepare_outputs(results)
    runs = collect_runs([Path(outputs), *map(Path, runs_dirs)])
    done = runs.final[runs.final["status"] == "done"].sort_values("seed")
    grids = [  # one grid per method and scene: lowest seed
        (
            Path(run["directory"]),
            results
            / "figures"
            / "grids"
            / file_name(
                [
                    "grid",
                    run["scene"],
                    "-".join((run["method"], run["planner"], run["ablation"])),
                    run["budget"],
                    f"seed{int(run['seed'])}",
                ],
                "_",
                ".png",
            ),
            f"{run['scene']} / {runs.row(run['method'], run['planner'], run['ablation']).label} / {run['budget']} "
            "budget "
            f"/ seed {int(run['seed'])}",
        )
        for _, run in done.drop_duplicates(list(GROUP)).iterrows()
    ]
    written = [results / "runs.csv"]
    text_columns = {column: runs.long[column].map(csv_cell) for column in TEXT_COLUMNS}
    atomic_write_text(written[0], runs.long.assign(**text_columns).to_csv(index=False))
    tables = {spec.name: build_table(runs, spec) for spec in SPECS}
    texts = {s.name: render(tables[s.name], LABEL_HEADERS.get(s.name, "Method"), s.experiment) for s in SPECS}
    texts["paper_comparison"] = render(paper_comparison(tables, runs), "Method", "table34_nerf_assets")
    for name, flavors in texts.items():
        for flavor, text in flavors.items():
            path = results / "tables" / f"{name}.{flavor}"
            atomic_write_text(path, text)
            written.append(path)
    if not figures:
        return written, (*runs.skipped, *runs.conflicts)
    written += curves(runs, results / "figures")
    for run_directory, path, title in grids:
        grid = image_grid(run_directory, path, title)
        written += [grid] if grid is not None else []
    pictures, problems = run_pictures_of(runs, results / "site", assets)
    written += [
        p
        for found in pictures.values()
        for p in (found.grid, found.trajectory)
        if p is not None and results in p.parents
    ]
    written += write_site(runs, pictures, results)
    return written, (*runs.skipped, *runs.conflicts, *problems)


def run_pictures_of(runs: Runs, site: Path, assets: Path | None) -> tuple[dict[str, RunPictures], list[str]]:
    """Each finished run's pictures (by directory): its own ``grid.png`` and ``trajectory.png`` beside its
    record where it has them; else those drawn for a site beside its records' folder (the committed
    ``results/site/runs/`` for ``results/runs``) or for this ``site``, under ``runs/<scene>/<method>-<planner>-
    <ablation>/<budget>/seed_<n>/``; else they are drawn there for this site (records made before runs drew
    them; records are never written to), again when the record is newer. One line per run whose pictures
    could not be drawn."""
    named, outlines = NamedConfigs(CONF), {}
    assets = configured_paths({})["assets"] if assets is None else assets
    pictures, problems = {}, []
    for _, run in runs.final[runs.final["status"] == "done"].iterrows():
        run_dir = Path(run["directory"])
        group = "-".join(safe_name(run[key]) for key in ("method", "planner", "ablation"))
        key = Path(safe_name(run["scene"]), group, safe_name(run["budget"]), f"seed_{int(run['seed'])}")
        beside = [run_dir.parents[3].parent / "site" / "runs" / key] if len(run_dir.parents) >= 4 else []
        places = [run_dir, *beside, site / "runs" / key]
        found_grid, trajectory = (_found(name, places, run_dir) for name in ("grid.png", "trajectory.png"))
        grid: Path | None = found_grid  # None once drawn for a run without images
        try:
            if _stale(found_grid, run_dir) or _stale(trajectory, run_dir):
                info, rows = load_run(run_dir)
                if _stale(found_grid, run_dir):
                    grid = image_grid(run_dir, found_grid, run_title(info))
                if _stale(trajectory, run_dir):
                    scene = recorded_scene(info, named)
                    scene_key = str(sorted(scene.items()))
                    if scene_key not in outlines:
                        outlines[scene_key] = outline_of_config(scene, assets)
                    trajectory_figure(outlines[scene_key], rows, run_title(info), trajectory)
        except (OSError, ValueError, KeyError) as err:
            problems.append(f"pictures of {run_dir} not drawn: {' '.join(str(err).split())}")
        summary = run_dir / "summary.md"
        pictures[str(run["directory"])] = RunPictures(
            *(path if path is not None and path.is_file() else None for path in (grid, trajectory, summary))
        )
    return pictures, problems


def _found(name: str, places: list[Path], run_dir: Path) -> Path:
    """The first up-to-date ``name`` in ``places``; else where this site draws it (the last place)."""
    return next((place / name for place in places if not _stale(place / name, run_dir)), places[-1] / name)


def _stale(picture: Path | None, run_dir: Path) -> bool:
    """A picture not there, or drawn for a site before its record's last step was written (a run's own
    pictures are never stale; None: the grid of a run without images)."""
    if picture is None:
        return False
    if not picture.is_file():
        return True
    return picture.parent != run_dir and picture.stat().st_mtime < (run_dir / "steps.jsonl").stat().st_mtime
