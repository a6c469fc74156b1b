"""``python -m pipeline.bench visibility [--out PATH] [--sets N] [--sources head,labels,mesh] [--record DIR --step K]
[overrides]``:
how well each visibility source tells seen from unseen object pixels of candidate views (METHOD 9,
M17-M19), how much it changes NVF's ranking of the candidates against w/o Vis., and which term of the
reward decides each ranking (default ``budget=cpu scene=default``).

The diagnostic (``pipeline.diagnostics.visibility_report``, which says what each number is) trains one full NVF
model on the scene's initial views (with ``--record`` and ``--step K``: and the views a recorded episode selected
at steps ``0..K-1``, its state at step ``K``) and scores ``N`` of the planner's candidate sets with each source.

Writes ``results/bench/visibility.json`` (or ``--out``) and prints a table per source.
"""

import time
from pathlib import Path

import torch
from jaxtyping import Float
from torch import Tensor

from nvf.cameras import pose_to_matrix
from nvf.visibility_source import SOURCES
from pipeline.bench._report import report_path, write_report
from pipeline.cli import ArgumentParser, bounded, description, fail
from pipeline.config.validation import compose_run
from pipeline.diagnostics.visibility_report import visibility_report
from pipeline.tables.load import load_run

MAX_SETS = 64


def recorded_poses(record: Path, step: int) -> Float[Tensor, "k 4 4"]:
    """The poses a recorded episode selected before ``step`` (its state at ``step``, after the initial views)."""
    _, rows = load_run(record)
    if step > len(rows):
        raise ValueError(f"{record} has {len(rows)} steps; --step {step} needs that many")
    return pose_to_matrix(
        torch.tensor([row["selected_pose"] for row in rows[:step]], dtype=torch.float32).reshape(-1, 7)
    )


def _show(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def print_report(report: dict) -> None:
    """A table per source and candidate set (rho: NVF vs w/o Vis.; rho cov / new / nov: NVF vs object coverage,
    unseen coverage and novelty)."""
    columns = (
        ("source", 8),
        ("set", 4),
        ("pixels", 7),
        ("seen", 6),
        ("shell", 7),
        ("AUC", 7),
        ("rho", 7),
        ("same", 6),
        ("ties", 5),
        ("rho cov", 8),
        ("rho new", 8),
        ("rho nov", 8),
        ("decisive NVF", 22),
        ("w/o Vis.", 20),
    )
    print("".join(f"{name:>{width}}" for name, width in columns))
    for name in report["sources"]:
        for r in report["sets"]:
            x, blind = r["sources"][name], r["wo_vis"]
            share = x["terms"][x["decisive"]]["share"] if x["decisive"] else None
            blind_share = blind["terms"][blind["decisive"]]["share"] if blind["decisive"] else None
            cells = (
                name,
                r["set"],
                r["object_pixels"],
                _show(r["seen_fraction"], ".2f"),
                _show(r["shell_median"], ".3f"),
                _show(x["auc"], ".3f"),
                _show(x["spearman_nvf_wo_vis"], ".3f"),
                x["same_argmax"],
                x["ties_at_max"],
                _show(x["coverage_spearman"], ".3f"),
                _show(x["unseen_coverage_spearman"], ".3f"),
                _show(x["novelty_spearman"], ".3f"),
                f"{x['decisive']} ({_show(share, '.2f')})",
                f"{blind['decisive']} ({_show(blind_share, '.2f')})",
            )
            print("".join(f"{str(cell):>{width}}" for cell, (_, width) in zip(cells, columns, strict=True)))
    blind = report["sets"]
    print(
        "w/o Vis. rho cov "
        + ", ".join(_show(r["wo_vis"]["coverage_spearman"], ".3f") for r in blind)
        + "; rho new "
        + ", ".join(_show(r["wo_vis"]["unseen_coverage_spearman"], ".3f") for r in blind)
        + "; rho nov "
        + ", ".join(_show(r["wo_vis"]["novelty_spearman"], ".3f") for r in blind)
    )


def main(argv: list[str]) -> None:
    parser = ArgumentParser(prog="python -m pipeline.bench visibility", description=description(__doc__))
    parser.add_argument("overrides", nargs="*", help="Hydra overrides, e.g. train.label_margin=0.05")
    parser.add_argument(
        "--out", type=Path, default=None, help="JSON report path (default: ${paths.results}/bench/visibility.json)"
    )
    parser.add_argument("--sets", type=int, default=3, help="candidate sets (the planner's draws at steps 0..N-1)")
    parser.add_argument(
        "--sources", default=",".join(SOURCES), help=f"visibility sources, a subset of {','.join(SOURCES)}"
    )
    parser.add_argument("--record", type=Path, default=None, help="a recorded episode whose state at --step to measure")
    parser.add_argument(
        "--step", type=int, default=0, help="with --record: the state before this step (its views so far)"
    )
    args = parser.parse_intermixed_args(argv)
    sources = args.sources.split(",")
    bounded("--sets", args.sets, 1, MAX_SETS)
    if not sources or any(name not in SOURCES for name in sources):
        parser.error(f"--sources={args.sources!r}: use a comma-separated subset of {','.join(SOURCES)}")
    if args.step < 0 or (args.step > 0 and args.record is None):
        parser.error("--step takes a number >= 0 and needs --record")
    start = time.perf_counter()
    cfg = compose_run(["planner.num_candidates=64", *args.overrides])
    args.out = report_path(args.out, cfg.paths.results, "visibility")  # checked before any work
    try:
        extra = recorded_poses(args.record, args.step) if args.record is not None else None
    except (ValueError, OSError) as err:
        fail(str(err))
    report = visibility_report(cfg, args.sets, sources, extra)
    report["settings"]["overrides"] = args.overrides
    report["settings"]["state"] = None if args.record is None else {"record": str(args.record), "step": args.step}
    report["seconds"] = time.perf_counter() - start
    write_report(report, args.out)
    print_report(report)
    print(f"{report['seconds']:.0f} s; wrote {args.out}")
