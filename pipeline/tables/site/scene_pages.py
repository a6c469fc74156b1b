"""One page per scene and budget: its table (paired intervals as in ``tables/all_runs``), its PSNR-over-steps curves
(mean and 95% Student-t band over seeds, the paper's final value where it has one) and every run's pictures."""

import html
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path

import pandas as pd
import plotly.graph_objects as go

from pipeline.tables.aggregate import SPECS, Table, build_table
from pipeline.tables.figures import file_name, safe_name
from pipeline.tables.load import Runs
from pipeline.tables.paper import paper_numbers
from pipeline.tables.site.page_frame import RunPictures, link, page_html
from pipeline.tables.stats import LEVEL, Interval
from pipeline.tables.table_formats import html_table


def scene_page_name(scene: str, budget: str) -> str:
    return f"scenes/{safe_name(scene)}_{safe_name(budget)}.html"


def scene_picture_name(scene: str, budget: str) -> str:
    """The index's PSNR picture of a scene at a budget, beside the scene's page."""
    return f"scenes/{file_name(['psnr', scene, budget], '_', '.png')}"


def psnr_bands(runs: Runs, scene: str, budget: str) -> list[tuple[str, pd.DataFrame]]:
    """Per method row (in the paper's order): step, mean, low, high and n of the PSNR over seeds, the band
    the two-sided ``LEVEL`` Student-t interval of the mean (``Interval``; none from one seed)."""
    long = runs.long[(runs.long["scene"] == scene) & (runs.long["budget"] == budget) & (runs.long["metric"] == "psnr")]
    out = []
    for key, group in sorted(long.groupby(["method", "planner", "ablation"]), key=lambda kv: runs.row(*kv[0]).order):
        rows = []
        for step, values in group.groupby("step")["value"]:
            band = Interval.of(values.to_numpy(float))
            rows.append({"step": int(step), "mean": band.mean, "low": band.low, "high": band.high, "n": band.n})
        out.append((runs.row(*key).label, pd.DataFrame(rows)))
    return out


def band_edge(frame: pd.DataFrame, column: str, label: str, fill: str | None = None) -> go.Scatter:
    """One edge of a PSNR band (``frame[column]`` over ``frame["step"]``), no line or hover, in ``label``'s
    legend group; ``fill``: the colour between it and the trace before it."""
    filled = {"fill": "tonexty", "fillcolor": fill} if fill is not None else {}
    return go.Scatter(
        x=frame["step"],
        y=frame[column],
        line={"width": 0},
        hoverinfo="skip",
        showlegend=False,
        legendgroup=label,
        **filled,
    )


def psnr_figure(runs: Runs, scene: str, budget: str) -> go.Figure:
    """PSNR over the steps per method: mean line and 95% band; the paper's final value as a marker at the last
    step where the paper reports this scene and method (Tables S3-S4)."""
    fig = go.Figure()
    paper = paper_numbers()
    paper_scene = runs.scene(scene).paper_scene
    last = 0
    for i, (label, frame) in enumerate(psnr_bands(runs, scene, budget)):
        color = COLORS[i % len(COLORS)]
        last = max(last, int(frame["step"].max()))
        if frame["n"].max() > 1:  # the band: its upper edge, then the lower one filled up to it
            fig.add_trace(band_edge(frame, "high", label))
            fig.add_trace(band_edge(frame, "low", label, fill=with_alpha(color, 0.12)))
        fig.add_trace(
            go.Scatter(
                x=frame["step"],
                y=frame["mean"],
                name=label,
                legendgroup=label,
                line={"color": color},
                customdata=frame[["low", "high", "n"]].to_numpy(),
                hovertemplate=f"{html.escape(label)} step %{{x}}: %{{y:.2f}} dB [%{{customdata[0]:.2f}}, "
                "%{customdata[1]:.2f}], n=%{customdata[2]}<extra></extra>",
            )
        )
        ref = paper[paper["table"].isin(["S3", "S4"]) & (paper["scene"] == paper_scene) & (paper["method"] == label)]
        if paper_scene is not None and not ref.empty:
            fig.add_trace(
                go.Scatter(
                    x=[int(frame["step"].max())],
                    y=[float(ref["psnr"].iloc[0])],
                    mode="markers",
                    legendgroup=label,
                    marker={"symbol": "star", "size": 12, "color": color, "line": {"width": 1, "color": "black"}},
                    name=f"{label}: paper (Table {ref['table'].iloc[0]})",
                    hovertemplate=f"paper, {html.escape(label)} on the {paper_scene} asset at the paper budget: "
                    "%{y:.2f} dB<extra></extra>",
                )
            )
    fig.update_layout(
        height=480,
        margin={"l": 60, "r": 20, "t": 40, "b": 50},
        template="plotly_white",
        title=f"{scene}, {budget} budget: PSNR over the steps (mean and {LEVEL:.0%} interval over seeds)",
        xaxis={"title": "step", "dtick": 1 if last <= 20 else None},
        yaxis={"title": "PSNR (dB)"},
        legend={"groupclick": "togglegroup"},
    )
    return fig


COLORS = (
    "#1f77b4",
    "#ff7f0e",
    "#2ca02c",
    "#d62728",
    "#9467bd",
    "#8c564b",
    "#e377c2",
    "#7f7f7f",
    "#bcbd22",
    "#17becf",
)  # matplotlib's, as the PNG curves


def with_alpha(color: str, alpha: float) -> str:
    r, g, b = (int(color[i : i + 2], 16) for i in (1, 3, 5))
    return f"rgba({r},{g},{b},{alpha})"


def scene_table(runs: Runs, scene: str, budget: str) -> Table:
    """The ``all_runs`` table of one scene at one budget, with its own header and notes."""
    final = runs.final[(runs.final["scene"] == scene) & (runs.final["budget"] == budget)]
    long = runs.long[(runs.long["scene"] == scene) & (runs.long["budget"] == budget)]
    spec = next(spec for spec in SPECS if spec.name == "all_runs")
    return build_table(replace(runs, final=final, long=long, skipped=(), conflicts=()), spec)


def scene_page(
    runs: Runs, frame: pd.DataFrame, pictures: Mapping[str, RunPictures], scene: str, budget: str, page: Path
) -> str:
    """One scene at one budget: table, curves, each run's pictures."""
    table = scene_table(runs, scene, budget)
    parts = [f'<h2>Final step, every metric</h2><div class="wide">{html_table(table, "Method")}</div>']
    parts.append(f'<p class="note">{html.escape(" ".join(table.header))}</p>')
    parts.append('<p class="note">' + "<br>".join(html.escape(n) for n in table.notes) + "</p>")
    chart = psnr_figure(runs, scene, budget).to_html(full_html=False, include_plotlyjs=False, div_id="psnr-curves")
    parts.append(f"<h2>PSNR over the steps</h2>{chart}")
    parts.append(
        '<p class="note">Band: two-sided 95% Student-t interval of the mean over seeds; stars: the paper\'s final '
        "PSNR for the real asset at the paper budget (Tables S3-S4), where it reports this scene and method. "
        "Click a legend entry to hide a method.</p><h2>Runs</h2>"
    )
    for key, group in sorted(frame.groupby(["method", "planner", "ablation"]), key=lambda kv: runs.row(*kv[0]).order):
        parts.append(f'<h3>{html.escape(runs.row(*key).label)}</h3><div class="runs">')
        for _, run in group.sort_values("seed").iterrows():
            found = pictures.get(str(run["directory"]), RunPictures(None, None, None))
            parts.append(run_card(run, found, page))
        parts.append("</div>")
    return page_html(f"{scene}, {budget} budget", "".join(parts), "../", plotly=True)


def run_card(run: pd.Series, found: RunPictures, page: Path) -> str:
    lines = [f'<div class="run"><strong>seed {int(run["seed"])}</strong>: final PSNR {run["psnr"]:.2f} dB']
    if found.summary is not None:
        lines.append(f' (<a href="{link(found.summary, page)}">per-step table</a>)')
    for picture, what in ((found.trajectory, "cameras"), (found.grid, "images")):
        if picture is not None:
            target = link(picture, page)
            lines.append(f'<a href="{target}"><img src="{target}" alt="{what}, seed {int(run["seed"])}"></a>')
    if found.grid is None:
        lines.append(
            '<span class="note">no images: the record keeps its steps only (save_images off, or a '
            "committed record)</span>"
        )
    return "".join(lines) + "</div>"
