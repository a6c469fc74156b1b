"""The duel's page, ``duel.html``: per scene one row per pair of the duel's summary, in its order, with whether NVF's
verdict against each rival holds at the paper's scale."""

import html
import math
from collections.abc import Mapping

import pandas as pd

from pipeline.config.catalog import contender_label
from pipeline.records.experiment_columns import EPISODES_MISSING
from pipeline.tables.site.index_page import transfer_html
from pipeline.tables.site.page_frame import bold_interval, page_html
from pipeline.tables.stats import Interval


def duel_row(row: pd.Series, verdicts: Mapping[str, str]) -> str:
    """One pair's row, in summary.md's order: the method and the rival (their labels), the budget, the decisions
    whose picks differ, the one-step gain with its interval (bold where it excludes zero), the share of identical
    picks, the episodes' final-PSNR difference (bold likewise), the cpu hours and, for NVF's rivals, whether NVF's
    verdict against the rival holds at the paper's scale (``verdicts``: the transfer table's, by rival)."""
    gain = Interval(row["gain_mean"], row["ci_low"], row["ci_high"], int(row["n"]))
    episode = Interval(row["episode_diff"], row["episode_ci_low"], row["episode_ci_high"], 0)
    same = f"{row['same_pick']:.0%}" if math.isfinite(row["same_pick"]) else "-"
    hours = f"{row['cpu_hours']:.2f}" if math.isfinite(row["cpu_hours"]) else "-"
    budget = row["budget"] if isinstance(row.get("budget"), str) else "-"
    names = (contender_label(str(row["method"])), contender_label(str(row["rival"])), budget)
    paper = verdicts.get(str(row["rival"]), "not measured") if row["method"] == "nvf" else "-"
    return (
        "<tr>"
        + "".join(f'<td class="label">{html.escape(name)}</td>' for name in names)
        + f"<td>{int(row['n'])}</td><td>{bold_interval(gain)}</td><td>{same}</td><td>{bold_interval(episode)}</td>"
        f"<td>{hours}</td><td>{html.escape(paper)}</td></tr>"
    )


DUEL_HEAD = (
    "method",
    "rival",
    "budget",
    "differing",
    "one-step gain (dB)",
    "same pick",
    "episodes' final PSNR (dB)",
    "cpu h",
    "paper's scale",
)


def duel_page(summary: pd.DataFrame, at_paper_scale: str | None = None, transfer: pd.DataFrame | None = None) -> str:
    """Per scene (and over scenes), one row per rival (and method) of the duel's one-step gains (``summary.csv`` of
    ``pipeline.experiments.duel_summary``): a long table, as narrow however many rivals and methods it holds; then,
    where given, the note on the same decisions at paper-trained states (``PAPER_STATES_NOTE``, as HTML)."""
    parts = [
        "<p>A duel scores the same candidate views with two methods on the same states (half from each method's "
        "recorded episodes); where their picks differ, the plain backbone is trained one step with each pick and "
        "measured on the evaluation views. A row: the method's pick minus the rival's in held-out PSNR (dB, mean "
        "[95% Student-t interval] over the decisions whose picks differ), how many decisions differ, the share of "
        "states where both picked the same view, the method's final PSNR minus the rival's in their episodes "
        "(paired by seed), the duel's cpu hours and, for NVF's rivals, whether NVF's verdict holds at the paper's "
        "scale (the table above). Bold: the interval excludes zero. The table <i>all</i> pools the "
        "scenes every pair holds, so that its rows compare; a scene only some pairs hold has its own table only. "
        f"{html.escape(EPISODES_MISSING)}</p>"
    ]
    head = "".join(f"<th>{html.escape(name)}</th>" for name in DUEL_HEAD)
    verdicts = {} if transfer is None else dict(zip(transfer["rival"], transfer["verdict"], strict=True))
    if transfer is not None:
        parts.append(transfer_html(transfer))
    for scene, block in summary.groupby("scene", sort=False):
        rivals = list(dict.fromkeys(block["rival"]))
        ordered = block.assign(_rival=block["rival"].map(rivals.index)).sort_values("_rival", kind="stable")
        lines = "".join(duel_row(row, verdicts) for _, row in ordered.iterrows())
        parts.append(
            f'<h2>{html.escape(str(scene))}</h2><div class="wide"><table><thead><tr>{head}</tr></thead><tbody>'
            f"{lines}</tbody></table></div>"
        )
    if at_paper_scale is not None:
        parts.append(f'<h2>At the paper\'s scale</h2><div class="pilot">{at_paper_scale}</div>')
    return page_html("Duels: paired one-step decisions", "".join(parts))
