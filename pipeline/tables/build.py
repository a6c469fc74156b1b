"""Every table and figure from the run records: long CSV, the paper's tables (md, csv, tex), the comparison
with the paper, curves and image grids."""

from pathlib import Path

from pipeline.records.store import atomic_write_text
from pipeline.tables.aggregate import GROUP, SPECS, build_table
from pipeline.tables.compare import paper_comparison
from pipeline.tables.figures import curves, image_grid, safe_name
from pipeline.tables.load import collect_runs
from pipeline.tables.render import LABEL_HEADERS, render


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
    texts["paper_comparison"] = render(paper_comparison(tables, runs), "Method", "table34_nerf_assets")
    for name, flavors in texts.items():
        for flavor, text in flavors.items():
            path = results / "tables" / f"{name}.{flavor}"
            atomic_write_text(path, text)
            written.append(path)
    if not figures:
        return written, (*runs.skipped, *runs.conflicts)
    written += curves(runs, results / "figures")
    done = runs.final[runs.final["status"] == "done"].sort_values("seed")
    for _, run in done.drop_duplicates(list(GROUP)).iterrows():  # one grid per method and scene: lowest seed
        group = "-".join(safe_name(run[key]) for key in ("method", "planner", "ablation"))
        name = f"grid_{safe_name(run['scene'])}_{group}_{safe_name(run['budget'])}_seed{int(run['seed'])}.png"
        grid = image_grid(Path(run["directory"]), results / "figures" / "grids" / name)
        written += [grid] if grid is not None else []
    return written, (*runs.skipped, *runs.conflicts)
