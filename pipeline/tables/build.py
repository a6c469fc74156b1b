"""Every table and figure from the run records: long CSV, the paper's tables (md, csv, tex), the comparison
with the paper, curves and image grids, and the results site (with the pictures older records lack).

All or nothing: ``tables/``, ``figures/`` and ``site/`` are each built whole into a new folder beside the one
they replace (``pipeline.atomic_write.temp_folder``), and only once every output is made are they renamed into
place and ``runs.csv`` replaced (``replace_folder``), so a failure leaves the previous outputs as they were and
no page, table or figure of a run no longer tabulated remains. In ``figures/`` the build owns its curves and ``grids/``
(a grid of a tabulated run whose images are no longer beside its record is carried from the old folder); what
other commands put there (``pipeline.scenes``' ``figures/scenes/``) is carried into the new folder too.
"""

import shutil
from collections.abc import Callable
from pathlib import Path

from pipeline.atomic_write import atomic_write_text, replace_folder, temp_folder
from pipeline.config.paths import configured_paths
from pipeline.config.settings_beyond_groups import NamedConfigs
from pipeline.records.files import check_directory, escaping_link, is_plain_file, make_directory
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
BUILT = ("tables", "figures", "site")  # the folders a build replaces whole (figures=False: tables alone)
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
    outputs: Path,
    runs_dirs: list[Path],
    results: Path,
    figures: bool = True,
    assets: Path | None = None,
    stage: Callable[[str], None] = lambda _: None,
) -> tuple[list[Path], tuple[str, ...]]:
    """Collect runs, write runs.csv, the tables (md/csv/tex), the paper comparison and (unless
    ``figures`` is False) the curves, image grids and the site, with the ``grid.png`` and
    ``trajectory.png`` of each finished run that lacks them (``run_pictures_of``; scene outlines read from
    ``assets``). Every file is written under ``results``, all or nothing (the module doc).

    Returns the files written (where they lie once in place) and one line per run record skipped (unreadable)
    or left out (settings that conflict with a kept record of the same run, differing finished copies), or whose
    pictures could not be written. Nothing is written before the output directories are checked
    (``prepare_outputs``). ``stage`` hears what each stage is about to do (the command shows it on a terminal).
    """
    results = Path(results)
    prepare_outputs(results)
    stage("reading and verifying the run records")
    runs = collect_runs([Path(outputs), *map(Path, runs_dirs)])
    built = {name: temp_folder(results / name) for name in BUILT[: 3 if figures else 1]}
    try:
        written, problems = _build(runs, results, built, assets, stage)
        if "figures" in built:
            _carry_figures(results, built["figures"])
        text_columns = {column: runs.long[column].map(csv_cell) for column in TEXT_COLUMNS}
        runs_csv = runs.long.assign(**text_columns).to_csv(index=False)
    except BaseException:
        for folder in built.values():
            shutil.rmtree(folder, ignore_errors=True)
        raise
    for name, folder in built.items():
        replace_folder(folder, results / name)
    atomic_write_text(results / "runs.csv", runs_csv)
    moved = {folder: results / name for name, folder in built.items()}
    in_place = [next((moved[f] / p.relative_to(f) for f in moved if f in p.parents), p) for p in written]
    return [results / "runs.csv", *in_place], (*runs.skipped, *runs.conflicts, *problems)


def _build(
    runs: Runs, results: Path, built: dict[str, Path], assets: Path | None, stage: Callable[[str], None]
) -> tuple[list[Path], list[str]]:
    """Write the tables, and with ``built["figures"]`` the figures and the site, into the new folders ``built``;
    the files written and the lines of runs whose pictures could not be drawn."""
    written = []
    stage(f"the tables of {len(runs.final)} runs")
    tables = {spec.name: build_table(runs, spec) for spec in SPECS}
    texts = {s.name: render(tables[s.name], LABEL_HEADERS.get(s.name, "Method"), s.experiment) for s in SPECS}
    texts["paper_comparison"] = render(paper_comparison(tables, runs), "Method", "table34_nerf_assets")
    for name, flavors in texts.items():
        for flavor, text in flavors.items():
            path = built["tables"] / f"{name}.{flavor}"
            atomic_write_text(path, text)
            written.append(path)
    if "figures" not in built:
        return written, []
    stage("the curves")
    written += curves(runs, built["figures"])
    done = runs.final[runs.final["status"] == "done"].sort_values("seed")
    stage(f"the image grids of {done.drop_duplicates(list(GROUP)).shape[0]} methods and scenes")
    for _, run in done.drop_duplicates(list(GROUP)).iterrows():  # one grid per method and scene: lowest seed
        group = "-".join((run["method"], run["planner"], run["ablation"]))
        name = file_name(["grid", run["scene"], group, run["budget"], f"seed{int(run['seed'])}"], "_", ".png")
        label = runs.row(run["method"], run["planner"], run["ablation"]).label
        title = f"{run['scene']} / {label} / {run['budget']} budget / seed {int(run['seed'])}"
        grid = image_grid(Path(run["directory"]), built["figures"] / "grids" / name, title)
        if grid is not None:
            written.append(grid)
        else:  # drawn by an earlier build while the run's images were beside its record (committed ones lack them)
            _carry(results / "figures" / "grids" / name, built["figures"] / "grids" / name, results)
    stage("each run's pictures")
    pictures, problems = run_pictures_of(runs, built["site"], assets, results / "site")
    written += [
        p
        for found in pictures.values()
        for p in (found.grid, found.trajectory)
        if p is not None and built["site"] in p.parents
    ]
    stage("the results site")
    written += write_site(runs, pictures, results, built["site"])
    return written, problems


def _carry_figures(results: Path, figures: Path) -> None:
    """Copy into the new ``figures`` folder what the old ``results/figures`` holds besides the build's own curves
    and grids (``pipeline.scenes``' outlines, a user's files), never through a symbolic link."""
    old = results / "figures"
    if not old.is_dir() or old.is_symlink():
        return
    for entry in sorted(old.iterdir()):
        name = entry.name
        if name.startswith(".") or name == "grids" or (name.startswith("curves_") and name.endswith(".png")):
            continue
        if entry.is_symlink():
            continue
        if entry.is_dir():
            shutil.copytree(entry, figures / name, symlinks=True)
        elif is_plain_file(entry):
            shutil.copy2(entry, figures / name)


def run_pictures_of(
    runs: Runs, site: Path, assets: Path | None, previous: Path
) -> tuple[dict[str, RunPictures], list[str]]:
    """Each finished run's pictures (by directory): its own ``grid.png`` and ``trajectory.png`` beside its
    record where it has them; else those drawn for a site beside its records' folder (the committed
    ``results/site/runs/`` for ``results/runs``) or for the ``previous`` site (the one ``site`` replaces), under
    ``runs/<scene>/<method>-<planner>-<ablation>/<budget>/seed_<n>/``, those of ``previous`` copied into
    ``site``; else they are drawn there for this site (records made before runs drew them; records are never
    written to), again when the record is newer. One line per run whose pictures could not be drawn."""
    named, outlines = NamedConfigs(CONF), {}
    assets = configured_paths({})["assets"] if assets is None else assets
    pictures, problems = {}, []
    for _, run in runs.final[runs.final["status"] == "done"].iterrows():
        run_dir = Path(run["directory"])
        group = "-".join(safe_name(run[key]) for key in ("method", "planner", "ablation"))
        key = Path(safe_name(run["scene"]), group, safe_name(run["budget"]), f"seed_{int(run['seed'])}")
        beside = [run_dir.parents[3].parent / "site" / "runs" / key] if len(run_dir.parents) >= 4 else []
        places = [run_dir, *beside, previous / "runs" / key]
        found_grid, trajectory = (
            _carried(_found(name, places, run_dir), previous, site) for name in ("grid.png", "trajectory.png")
        )
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
    """The first up-to-date ``name`` in ``places``; else the last place's."""
    return next((place / name for place in places if not _stale(place / name, run_dir)), places[-1] / name)


def _carried(picture: Path, previous: Path, site: Path) -> Path:
    """``picture``, or for one of the ``previous`` site its place in the new ``site``: copied there (with its time)
    where it is a plain file reached through no link, else left to be drawn there."""
    if previous not in picture.parents:
        return picture
    target = site / picture.relative_to(previous)
    _carry(picture, target, previous)
    return target


def _carry(old: Path, new: Path, root: Path) -> None:
    """Copy ``old`` to ``new`` with its time where it is a plain file reached through no link leaving ``root``."""
    if is_plain_file(old) and escaping_link(root, old) is None:
        new.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(old, new)


def _stale(picture: Path | None, run_dir: Path) -> bool:
    """A picture not there, or drawn for a site before its record's last step was written (a run's own
    pictures are never stale; None: the grid of a run without images)."""
    if picture is None:
        return False
    if not picture.is_file():
        return True
    return picture.parent != run_dir and picture.stat().st_mtime < (run_dir / "steps.jsonl").stat().st_mtime
