"""Every table and figure from the run records: long CSV, the paper's tables (md, csv, tex), the comparison
with the paper, curves and image grids."""

from pathlib import Path

from pipeline.records.files import check_directory, make_directory
from pipeline.records.store import atomic_write_text
from pipeline.tables.aggregate import GROUP, SPECS, build_table
from pipeline.tables.compare import paper_comparison
from pipeline.tables.figures import curves, file_name, image_grid
from pipeline.tables.load import collect_runs
from pipeline.tables.render import LABEL_HEADERS, render

OUTPUT_DIRECTORIES = ("tables", "figures", "figures/grids")  # under paths.results


def prepare_outputs(results: Path) -> None:
    """Create ``results``; ``RecordError`` (nothing written) when one of its ``OUTPUT_DIRECTORIES`` lies behind a
    symbolic link leaving ``results`` or is a file."""
    make_directory(Path(results), Path(results))
    for name in OUTPUT_DIRECTORIES:
        check_directory(Path(results), Path(results) / name)


def build_tables(
    outputs: Path, runs_dirs: list[Path], results: Path, figures: bool = True
) -> tuple[list[Path], tuple[str, ...]]:
    """Collect runs, write runs.csv, the tables (md/csv/tex), the paper comparison and (unless
    ``figures`` is False) the curves and image grids.

    Returns the files written and one line per run record skipped (unreadable) or left out (settings
    that conflict with a kept record of the same run, differing finished copies). Nothing is written
    before the output directories are checked (``prepare_outputs``) and every file name is known.
    """
    results = Path(results)
    prepare_outputs(results)
    runs = collect_runs([Path(outputs), *map(Path, runs_dirs)])
    done = runs.final[runs.final["status"] == "done"].sort_values("seed")
    grids = [  # one grid per method and scene: lowest seed
        (Path(run["directory"]), results / "figures" / "grids" / file_name(
            ["grid", run["scene"], "-".join((run["method"], run["planner"], run["ablation"])), run["budget"],
             f"seed{int(run['seed'])}"], "_", ".png"))
        for _, run in done.drop_duplicates(list(GROUP)).iterrows()
    ]  # fmt: skip
    written = [results / "runs.csv"]
    atomic_write_text(written[0], runs.long.to_csv(index=False))
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
    for run_directory, path in grids:
        grid = image_grid(run_directory, path)
        written += [grid] if grid is not None else []
    return written, (*runs.skipped, *runs.conflicts)
