"""``python -m pipeline.tables [paths.outputs=DIR] [paths.results=DIR] [paths.assets=DIR] [--with-committed]``:
every table and figure, and the results site, from the run records.

What it reads: the runs under ``paths.outputs`` (default ``outputs``) and under ``${paths.results}/runs``
(default ``outputs/results/runs``), that is, your own runs. ``--with-committed`` adds the repository's
committed records (``results/runs``), so your runs are tabulated beside them; identical copies of a run
count once; finished copies with the same settings that differ are named in one line and none is tabulated
until the wrong ones are removed; a copy left out because its settings differ from the kept one's (a
finished copy wins, then yours) is listed.
``paths.results=results paths.outputs=results/runs`` regenerates the repository's published tables and
site from the committed records alone.

What it writes, under ``paths.results`` (default ``${paths.outputs}/results``, your own folder):

- ``runs.csv``: every step's metrics, one row per run, step and metric (NaN as an empty field);
- ``tables/{main, table1_opt, table2_ablation, table34_nerf_assets, methods, all_runs,
  paper_comparison}.{md,csv,tex}``: mean ± population std over seeds at each run's last step, the best
  value bold only where its paired 95% interval to every other row excludes zero, each row's paired PSNR
  difference to NVF;
- ``figures/``: metric-over-steps curves per scene and budget, and one image grid per method and scene;
- ``site/``: the results site (open ``site/index.html`` in a browser; it needs no network or server):
  per scene the best method with its paired interval against the runner-up, a PSNR picture and a flag below
  the floor, then methods x scenes; per scene its table, interactive PSNR curves with 95% bands and each run's pictures;
  the pilots under ``${paths.results}/pilots``. A run's pictures are linked where they lie, beside its
  record; those an older record lacks are taken from the site beside its records' folder where that drew
  them (the committed ``results/site/runs/``), else drawn into ``site/runs/``: ``trajectory.png`` (where it put its
  cameras, over the scene's outline read from ``paths.assets``; the tight box where the asset is not there)
  and ``grid.png`` (when it saved its images). Records themselves are never written to.

Only finished runs count. A run whose recorded settings differ from what its named groups give today has
them appended to its budget, e.g. ``cpu+planner.num_candidates=512``, so it is never averaged with plain
``cpu`` runs. Records are untrusted input: one that fails a check (``pipeline.records.verify``) or lies
behind a symbolic link leaving its root is skipped and listed with the reason; record text is escaped in
every table (``pipeline.tables.escape``) and reduced to a safe, bounded file name where it names a figure.
Rows planned with the scene mesh's line of sight (``planner.los_source=mesh`` on Room) are marked ‡.
Exit status 2: a bad argument or an unusable ``paths.results``, e.g. a ``tables/`` that is a symbolic link out
of it (nothing written); 1: writing failed (the previous outputs left as they were: each is built into a new
folder and swapped in once all are made, ``pipeline.tables.build``). Errors are one ``error: ...`` line.
"""

import sys
from pathlib import Path

from pipeline.cli import ArgumentParser, help_page, run_command
from pipeline.config.paths import paths_from_args, unwritable
from pipeline.records.store import RecordError
from pipeline.repo import RESULTS
from pipeline.tables.build import build_tables, prepare_outputs

PATH_KEYS = ("paths.outputs", "paths.results", "paths.assets")


def parse(argv: list[str]) -> tuple[dict[str, Path], bool]:
    """The paths (``conf/paths`` with the ``paths.<key>=DIR`` arguments) and whether to add the committed
    records; a ValueError naming the arguments the command takes otherwise."""
    parser = ArgumentParser(prog="python -m pipeline.tables", add_help=False)
    parser.add_argument("--with-committed", action="store_true")
    known, rest = parser.parse_known_args(argv)
    return paths_from_args(rest, PATH_KEYS), known.with_committed


def stage_line(what: str) -> None:
    """On a terminal, a line per stage (the whole build takes minutes on the committed records); quiet elsewhere."""
    if sys.stderr.isatty():
        print(f"pipeline.tables: {what} ...", file=sys.stderr, flush=True)


def main(argv: list[str]) -> int:
    """Command-line entry point; returns the exit code."""
    if any(arg in ("-h", "--help") for arg in argv):
        print(help_page(__doc__))
        return 0
    try:
        paths, with_committed = parse(argv)
    except ValueError as err:
        print(f"error: {err} [--with-committed] (see --help)", file=sys.stderr)
        return 2
    outputs, results = paths["outputs"], paths["results"]
    problem = unwritable("paths.results", results)
    if problem is not None:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    try:
        prepare_outputs(results)
    except RecordError as err:
        print(f"error: paths.results: {err}", file=sys.stderr)
        return 2
    roots = [results / "runs", *([RESULTS / "runs"] if with_committed else [])]
    roots = list({root.resolve(): root for root in roots if root.resolve() != outputs.resolve()}.values())  # each once
    try:
        written, skipped = build_tables(outputs, roots, results, assets=paths["assets"], stage=stage_line)
    except (ValueError, OSError) as err:
        print(f"error: {str(err).splitlines()[0]}", file=sys.stderr)
        return 1
    for line in skipped:
        print(f"pipeline.tables: {' '.join(line.split())}", file=sys.stderr)
    if not outputs.is_dir():
        read = " and ".join(str(root) for root in roots)
        print(
            f"pipeline.tables: note: paths.outputs={outputs} is not a directory; only {read} was read", file=sys.stderr
        )
    print(
        f"pipeline.tables: wrote {len(written)} files under {results} (runs.csv, tables/, figures/, site/); "
        f"open {results / 'site' / 'index.html'}"
    )
    return 0


if __name__ == "__main__":
    run_command(main, sys.argv[1:])
