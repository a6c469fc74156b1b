"""Run records -> long CSV -> paper-style tables (md, csv, tex), comparison with the paper, figures.

``python -m pipeline.tables [paths.outputs=DIR] [paths.results=DIR]`` reads every run under
``paths.outputs`` (default ``outputs``) and ``${paths.results}/runs`` (committed records: run.json +
steps.jsonl) and writes into ``paths.results`` (default ``${paths.outputs}/results``, the user's own folder;
``paths.results=results paths.outputs=results/runs`` regenerates the repository's published tables)
``${paths.results}/runs.csv`` (long format; NaN as an empty field), ``tables/{main, table1_opt,
table2_ablation, table34_nerf_assets, all_runs, paper_comparison}.{md,csv,tex}`` and ``figures/``
(metric-vs-step curves, image grids). Only finished runs count; a cell is the mean ± population std
over seeds at each run's last step (PROTOCOL.md 3). Step rows store NaN as ``null``
(``pipeline.records``); it is read back as NaN and footnoted. A run whose recorded settings differ from what
its named groups give today (``pipeline.config.named``) has them appended to its budget, e.g.
``cpu+planner.num_candidates=512``, so it is never averaged or labelled with plain ``cpu`` runs.
Records are untrusted input: one that fails a check (``pipeline.records.verify``) or lies behind a symbolic
link leaving its root is skipped and listed with the reason; finished copies of one run that differ are
named in one line and none is tabulated until the wrong ones are removed; record text is escaped in every
table (``pipeline.tables.escape``) and reduced to a safe, bounded file name where it names a figure.
Rows planned with the scene mesh's line of sight (``planner.los_source=mesh`` on Room) are marked ‡.
Exit status 2: a bad argument or an unusable ``paths.results``, e.g. a ``tables/`` that is a symbolic link out
of it (nothing written); 1: writing failed. Errors are one ``error: ...`` line.
"""

import sys
from pathlib import Path

from pipeline.config.paths import paths_from_args, unwritable
from pipeline.records.store import RecordError
from pipeline.tables.build import build_tables, prepare_outputs


def parse_overrides(argv: list[str]) -> tuple[Path, Path]:
    """(outputs, results) from ``paths.outputs=...`` / ``paths.results=...`` (defaults: conf/paths)."""
    paths = paths_from_args(argv, ("paths.outputs", "paths.results"))
    return paths["outputs"], paths["results"]


def main(argv: list[str]) -> int:
    """Command-line entry point; returns the exit code."""
    if any(arg in ("-h", "--help") for arg in argv):
        print(__doc__.strip())
        return 0
    try:
        outputs, results = parse_overrides(argv)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    problem = unwritable("paths.results", results)
    if problem is not None:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    try:
        prepare_outputs(results)
    except RecordError as err:
        print(f"error: paths.results: {err}", file=sys.stderr)
        return 2
    try:
        written, skipped = build_tables(outputs, [results / "runs"], results)
    except (ValueError, OSError) as err:
        print(f"error: {str(err).splitlines()[0]}", file=sys.stderr)
        return 1
    for line in skipped:
        print(f"pipeline.tables: {' '.join(line.split())}", file=sys.stderr)
    if not outputs.is_dir():
        note = f"paths.outputs={outputs} is not a directory; only {results / 'runs'} was read"
        print(f"pipeline.tables: note: {note}", file=sys.stderr)
    print(f"pipeline.tables: wrote {len(written)} files under {results} (runs.csv, tables/, figures/)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

