"""The results site, ``${paths.results}/site/``: static pages that open from ``file://`` with no server and no
network. ``index.html`` leads with who wins where: per scene and budget the best method by final PSNR, its paired
interval against the runner-up, a small picture of PSNR over the steps (``scenes/psnr_<scene>_<budget>.png``) and
a flag where no method reaches ``PSNR_FLOOR_DB``; then a methods x scenes table of the final PSNR. One page per
scene and budget holds
its table (paired intervals as in ``tables/all_runs``), its PSNR-over-steps curves per method (mean and 95%
Student-t band over seeds, the paper's final value marked where it has one) and every run's pictures;
``pilots.html`` shows the pilots under ``${paths.results}/pilots``: their Markdown notes as text (raw HTML in a
note is shown escaped, never passed through; links only to http(s), mailto and the files beside the note; a note
that is a symbolic link, or lies behind one leaving the pilots, is not read). The interactive plots are plotly's, its
JavaScript written once beside the pages (``plotly.min.js``); pictures are linked where they lie (beside the
run records, in ``pilots/``, or drawn into ``site/runs/`` for records that lack them, and carried from one build
of the site to the next), not copied, so the site works while it stays beside them.
"""

import html
import io
import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from urllib.parse import quote
from xml.etree import ElementTree

import markdown
import numpy as np
import pandas as pd
import plotly.graph_objects as go
from jinja2 import Environment
from markdown.extensions import Extension
from markdown.treeprocessors import Treeprocessor
from matplotlib.figure import Figure
from PIL import Image
from plotly.offline import get_plotlyjs

from pipeline.atomic_write import atomic_write_bytes, atomic_write_text
from pipeline.config.catalog import contender_label
from pipeline.records.checked_files import read_csv
from pipeline.records.experiment_columns import DUEL_SUMMARY_COLUMNS, EPISODES_MISSING, TRANSFER_COLUMNS
from pipeline.records.files import RecordError, escaping_link, is_plain_file, read_plain_file
from pipeline.tables.aggregate import SPECS, Table, build_table, mean_std_valid, seed_samples
from pipeline.tables.escape import plot_text
from pipeline.tables.figures import file_name, integer_steps, safe_name
from pipeline.tables.load import Runs
from pipeline.tables.paper import paper_numbers
from pipeline.tables.stats import LEVEL, Interval, paired
from pipeline.tables.table_formats import html_table

PLOTLY_JS = "plotly.min.js"
DUEL_SUMMARY = Path("pilots", "duel", "summary.csv")  # pipeline.experiments.duel_summary's table
TRANSFER = Path("pilots", "paper_states", "transfer.csv")  # pipeline.experiments.transfer's table
PAPER_STATES_NOTE = Path("pilots", "paper_states", "README.md")  # the duel page's closing note
DUEL_COLUMNS = DUEL_SUMMARY_COLUMNS  # the duel summary's columns as its writer declares them, read back checked

PSNR_FLOOR_DB = 15.0  # an RMS error of 18% of the intensity range: a blur of about the right colours, not a scene
PICTURE_SIZE = (3.8, 2.3)  # inches at PICTURE_DPI: the index's PSNR picture of a scene, shown 380 px wide
PICTURE_DPI = 150
PICTURE_COLORS = 64  # its palette (few colours: lines on white)
OTHER_ROWS = "#b0b0b0"  # the picture's rows other than the best and the runner-up
FLOOR_LABEL = f"floor, {PSNR_FLOOR_DB:g} dB"

STYLE = """
body { font-family: system-ui, sans-serif; margin: 1.5em auto; max-width: 1300px; padding: 0 1em; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; margin-top: 1.6em; } h3 { font-size: 1.05em; }
table { border-collapse: collapse; margin: 0.6em 0; font-size: 0.85em; }
th, td { border: 1px solid #ccc; padding: 0.2em 0.5em; text-align: right; white-space: nowrap; }
th:nth-child(-n+2), td:nth-child(-n+2), td.label { text-align: left; }
thead th { background: #f0f0f0; }
.note { color: #555; font-size: 0.85em; }
.runs { display: flex; flex-wrap: wrap; gap: 1em; }
.run { border: 1px solid #ddd; padding: 0.5em; }
.run img { display: block; max-width: 600px; margin: 0.3em 0; }
.pilot img { max-width: 800px; display: block; }
nav a { margin-right: 1em; }
.wide { overflow-x: auto; }
"""
LEAD_STYLE = """
.leads { display: flex; flex-wrap: wrap; gap: 1em; margin: 0.6em 0; }
.lead { border: 1px solid #ddd; padding: 0.5em 0.7em; width: 380px; }
.lead h3 { margin: 0 0 0.3em 0; }
.lead img { display: block; width: 100%; height: auto; }
.lead p { margin: 0.4em 0; font-size: 0.9em; }
.flag { border-left: 4px solid #b35900; background: #fff4e5; padding: 0.3em 0.5em; }
"""

PAGE = Environment(autoescape=True).from_string("""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{{ title }}</title>
<style>{{ style }}</style>{% if plotly %}<script src="{{ plotly }}"></script>{% endif %}</head>
<body><nav><a href="{{ home }}index.html">Overview</a><a href="{{ home }}pilots.html">Pilots</a></nav>
<h1>{{ title }}</h1>
{{ body | safe }}
</body></html>
""")


@dataclass(frozen=True)
class RunPictures:
    """One run's pictures: its grid and trajectory (beside its record, or drawn for the site) and its per-step
    table (None where it has none)."""

    grid: Path | None
    trajectory: Path | None
    summary: Path | None


def link(target: Path, page: Path) -> str:
    """``target`` relative to the folder of ``page``, as a URL path (characters a URL cannot hold quoted)."""
    return quote(Path(os.path.relpath(Path(target).resolve(), Path(page).resolve().parent)).as_posix())


def scene_page_name(scene: str, budget: str) -> str:
    return f"scenes/{safe_name(scene)}_{safe_name(budget)}.html"


def scene_picture_name(scene: str, budget: str) -> str:
    """The index's PSNR picture of a scene at a budget, beside the scene's page."""
    return f"scenes/{file_name(['psnr', scene, budget], '_', '.png')}"


def write_site(runs: Runs, pictures: Mapping[str, RunPictures], results: Path, site: Path) -> list[Path]:
    """Write the site of ``results`` into the folder ``site`` (beside ``results / "site"``, which it replaces:
    ``pipeline.tables.build``) from the runs and each run's pictures (by run directory); the pilots and the duel's
    summary are read from ``results``. Returns the files written."""
    done = runs.final[runs.final["status"] == "done"]
    pages_text: dict[Path, str] = {site / PLOTLY_JS: get_plotlyjs()}  # plotly.js, its MIT licence in its first lines
    pngs: dict[Path, bytes] = {}
    pages, curves = {}, {}
    for (budget, scene), frame in done.groupby(["budget", "scene"]):
        path = site / scene_page_name(scene, budget)
        pages[(budget, scene)] = path
        pages_text[path] = scene_page(runs, frame, pictures, scene, budget, path)
        lead = scene_lead(runs, frame)
        if lead is not None:
            curves[(budget, scene)] = site / scene_picture_name(scene, budget)
            pngs[curves[(budget, scene)]] = psnr_picture(runs, scene, budget, lead)
    duels = read_csv(Path(results) / DUEL_SUMMARY, DUEL_COLUMNS)
    transfer = read_csv(Path(results) / TRANSFER, TRANSFER_COLUMNS)
    if duels is not None:
        paper_note = Path(results) / PAPER_STATES_NOTE
        at_paper_scale = _note(paper_note, site / "duel.html") if os.path.lexists(paper_note) else None
        pages_text[site / "duel.html"] = duel_page(duels, at_paper_scale, transfer)
    index = site / "index.html"
    pages_text[index] = index_page(runs, done, pages, index, duels is not None, curves, transfer)
    pilots = site / "pilots.html"
    pages_text[pilots] = pilots_page(Path(results) / "pilots", pilots)
    for png_path, png in pngs.items():
        atomic_write_bytes(png_path, png)
    for path, text in pages_text.items():
        atomic_write_text(path, text)
    return [*pngs, *pages_text]


def _page(title: str, body: str, home: str = "", plotly: bool = False, style: str = STYLE) -> str:
    """A whole page; ``home``: the site's folder relative to the page's ("" or "../")."""
    return PAGE.render(title=title, body=body, style=style, home=home, plotly=f"{home}{PLOTLY_JS}" if plotly else None)


@dataclass(frozen=True)
class SceneLead:
    """Who wins a scene at one budget: its rows (methods, their -OPT variants, NVF's ablations) by mean final PSNR
    over seeds, best first, as (label, mean, seeds); ``versus``: the best's PSNR minus the runner-up's, paired by
    seed (``stats.paired``, as the tables' ΔPSNR vs NVF), with no mean when there is no runner-up."""

    ranked: tuple[tuple[str, float, int], ...]
    versus: Interval

    @property
    def below_floor(self) -> bool:
        """No row's mean final PSNR reaches ``PSNR_FLOOR_DB``."""
        return self.ranked[0][1] < PSNR_FLOOR_DB


def scene_lead(runs: Runs, frame: pd.DataFrame) -> SceneLead | None:
    """The ``SceneLead`` of one scene's finished runs at one budget (``frame``); None when no run has a final PSNR.
    Rows with the same mean keep the tables' order."""
    samples = seed_samples(frame)
    stats = {key: mean_std_valid(values["psnr"].to_numpy(float)) for key, values in samples.items()}
    keys = sorted(
        (key for key, (mean, _, _) in stats.items() if math.isfinite(mean)),
        key=lambda key: (-stats[key][0], runs.row(*key[2:]).order),
    )
    if not keys:
        return None
    ranked = tuple((runs.row(*key[2:]).label, stats[key][0], stats[key][2]) for key in keys)
    versus = paired(samples[keys[0]]["psnr"], samples[keys[1]]["psnr"]) if len(keys) > 1 else Interval.of(np.array([]))
    return SceneLead(ranked, versus)


def lead_text(lead: SceneLead) -> str:
    """The lead line of a scene (plain text): the best row and its paired difference to the runner-up, saying
    plainly whether the 95% interval separates them."""
    best, mean, seeds = lead.ranked[0]
    text = f"Best: {best}, {mean:.2f} dB (mean final PSNR over {seeds} seed{'' if seeds == 1 else 's'})."
    if len(lead.ranked) == 1:
        return f"{text} The only method run here."
    runner, runner_mean, _ = lead.ranked[1]
    versus, n = lead.versus, lead.versus.n
    text += f" Runner-up: {runner}, {runner_mean:.2f} dB."
    pairs = f"{n} seed{'' if n == 1 else 's'} both ran"
    if n < 2:
        return f"{text} Paired difference {versus.text()} dB over {pairs}: too few pairs for an interval."
    if versus.mean == versus.low == versus.high == 0.0:
        return (
            f"{text} Identical final PSNR on each of the {pairs}: not separated from {runner} (a difference of zero)."
        )
    verdict = (
        f"separated from {runner} (the interval excludes zero)"
        if versus.excludes_zero
        else f"not separated from {runner} (the interval includes zero)"
    )
    return f"{text} Paired difference {versus.text()} dB ({LEVEL:.0%} interval over the {pairs}): {verdict}."


def floor_text(lead: SceneLead) -> str:
    """The flag of a scene below ``PSNR_FLOOR_DB`` (plain text)."""
    return (
        f"Below the {PSNR_FLOOR_DB:g} dB floor: no method's mean final PSNR reaches it (the best: "
        f"{lead.ranked[0][1]:.2f} dB). The model barely learns this scene at this budget; read its ranking with care."
    )


def psnr_picture(runs: Runs, scene: str, budget: str, lead: SceneLead) -> bytes:
    """A small PNG of a scene's PSNR over the steps, the mean over seeds per row (``psnr_bands``): the best and the
    runner-up in colour and named, the others grey; the floor dashed where it is in range or not reached."""
    best = lead.ranked[0][0]
    runner = lead.ranked[1][0] if len(lead.ranked) > 1 else None
    fig = Figure(figsize=PICTURE_SIZE, dpi=PICTURE_DPI, layout="constrained")
    ax = fig.subplots()
    drawn = []
    for label, frame in reversed(psnr_bands(runs, scene, budget)):  # the paper's first rows drawn last, on top
        if frame.empty or not frame["mean"].notna().any():
            continue
        steps, means = frame["step"].to_numpy(int), frame["mean"].to_numpy(float)
        drawn.append(means[np.isfinite(means)])
        if label == best:
            ax.plot(steps, means, color=COLORS[0], linewidth=2.2, zorder=4, label=plot_text(f"best: {label}"))
        elif label == runner:
            ax.plot(steps, means, color=COLORS[1], linewidth=1.6, zorder=3, label=plot_text(f"runner-up: {label}"))
        else:
            ax.plot(steps, means, color=OTHER_ROWS, linewidth=0.8, zorder=2)
    values = np.concatenate(drawn) if drawn else np.array([PSNR_FLOOR_DB])
    if lead.below_floor or values.min() <= PSNR_FLOOR_DB <= values.max():
        ax.axhline(PSNR_FLOOR_DB, color="#b35900", linestyle="--", linewidth=0.9, zorder=1, label=FLOOR_LABEL)
    handles, labels = ax.get_legend_handles_labels()
    order = sorted(range(len(labels)), key=lambda i: (labels[i] == FLOOR_LABEL, not labels[i].startswith("best")))
    if handles:
        ax.legend([handles[i] for i in order], [labels[i] for i in order], fontsize=6.5, frameon=False, loc="best")
    ax.set_xlabel("step", fontsize=7)
    ax.set_ylabel("PSNR (dB)", fontsize=7)
    ax.tick_params(labelsize=6.5)
    integer_steps(ax)
    ax.grid(alpha=0.3)
    png = io.BytesIO()
    fig.savefig(png, format="png")
    with Image.open(io.BytesIO(png.getvalue())) as image:
        png = io.BytesIO()
        image.convert("RGB").quantize(PICTURE_COLORS).save(png, format="PNG", optimize=True)
    return png.getvalue()


def picture_alt(scene: str, budget: str, lead: SceneLead) -> str:
    """The picture's text alternative (plain text)."""
    runner = f", the runner-up {lead.ranked[1][0]} in orange" if len(lead.ranked) > 1 else ""
    return (
        f"{scene}, {budget} budget: mean PSNR over the steps per method, the best {lead.ranked[0][0]} in blue"
        f"{runner}, the others grey"
    )


def leads_html(
    runs: Runs,
    frame: pd.DataFrame,
    budget: str,
    pages: Mapping[tuple[str, str], Path],
    curves: Mapping[tuple[str, str], Path],
    page: Path,
) -> str:
    """One budget's scenes, each a box: its name and picture linking its page, its lead line, its flag."""
    boxes = []
    for scene in sorted(set(frame["scene"]), key=lambda scene: runs.scene(scene).order):
        lead = scene_lead(runs, frame[frame["scene"] == scene])
        target = link(pages[(budget, scene)], page)
        box = [f'<div class="lead"><h3><a href="{target}">{html.escape(scene)}</a></h3>']
        if lead is None:
            boxes.append(f"{''.join(box)}<p>No run has a final PSNR.</p></div>")
            continue
        picture = curves.get((budget, scene))
        if picture is not None:
            alt = html.escape(picture_alt(scene, budget, lead))
            width, height = (round(inches * 100) for inches in PICTURE_SIZE)
            source = link(picture, page)
            box.append(f'<a href="{target}"><img src="{source}" alt="{alt}" width="{width}" height="{height}"></a>')
        box.append(f'<p class="best">{html.escape(lead_text(lead))}</p>')
        if lead.below_floor:
            box.append(f'<p class="flag" role="note">{html.escape(floor_text(lead))}</p>')
        boxes.append("".join(box) + "</div>")
    return f'<div class="leads">{"".join(boxes)}</div>'


def index_page(
    runs: Runs,
    done: pd.DataFrame,
    pages: Mapping[tuple[str, str], Path],
    page: Path,
    duel: bool = False,
    curves: Mapping[tuple[str, str], Path] | None = None,
    transfer: pd.DataFrame | None = None,
) -> str:
    """Per budget, who wins where (``leads_html``: per scene the best row and its paired interval against the
    runner-up, the PSNR picture of ``curves`` by (budget, scene), the floor's flag), then methods x scenes: final
    PSNR mean ± population std over seeds, each scene linking to its page; ``duel``: link the duel's page;
    ``transfer``: which of the duel's cpu verdicts hold at the paper's scale (``transfer_html``)."""
    parts = []
    if done.empty:
        parts.append(
            "<p>No finished runs yet: run <code>python -m pipeline.run</code>, then "
            "<code>python -m pipeline.tables</code>.</p>"
        )
    else:
        parts.append(
            "<p>Who wins where: per scene and budget, the best method by mean final PSNR over seeds (every row of "
            "the tables: the methods, their -OPT variants and NVF's ablations) and its paired difference to the "
            "runner-up, the best's final PSNR minus the runner-up's on the seeds both ran: mean "
            f"[{LEVEL:.0%} Student-t interval], as the tables' ΔPSNR vs NVF. Where that interval includes zero, "
            "the best is not separated from the runner-up. The picture: mean PSNR over the steps per method, the "
            "best in blue, the runner-up in orange, the others grey; it opens the scene's page.</p>"
            f'<p class="note">Floor: a scene is flagged where no method\'s mean final PSNR reaches '
            f"{PSNR_FLOOR_DB:g} dB. That is a root-mean-square error of {10 ** (-PSNR_FLOOR_DB / 20):.0%} of the "
            "intensity range, a blur of about the right colours: the model barely learns the scene at this budget, "
            "and its ranking says more about the seeds than about the chosen views.</p>"
        )
    for budget, frame in done.groupby("budget"):
        parts.append(f"<h2>{html.escape(budget)} budget</h2>")
        parts.append(leads_html(runs, frame, budget, pages, curves or {}, page))
        frame = frame.assign(row=list(zip(frame["method"], frame["planner"], frame["ablation"], strict=True)))
        groups = sorted(set(frame["row"]), key=lambda key: runs.row(*key).order)
        scenes = sorted(set(frame["scene"]), key=lambda scene: runs.scene(scene).order)
        head = "".join(f'<th><a href="{link(pages[(budget, s)], page)}">{html.escape(s)}</a></th>' for s in scenes)
        lines = []
        for key in groups:
            cells = []
            for scene in scenes:
                psnr = frame.loc[(frame["scene"] == scene) & (frame["row"] == key), "psnr"].to_numpy(float)
                psnr = psnr[np.isfinite(psnr)]
                spread = f" ± {psnr.std():.2f}" if len(psnr) > 1 else ""  # one seed: the mean alone, as the tables
                text = f"{psnr.mean():.2f}{spread}" if len(psnr) else "-"
                cells.append(f'<td title="{len(psnr)} seeds">{text}</td>')
            lines.append(f'<tr><td class="label">{html.escape(runs.row(*key).label)}</td>{"".join(cells)}</tr>')
        parts.append(
            f'<h3>Every method, {html.escape(budget)} budget</h3><div class="wide"><table><thead><tr><th>method</th>'
            f"{head}</tr></thead><tbody>{''.join(lines)}</tbody></table></div>"
        )
    parts.append(
        '<p class="note">Tables: final PSNR (dB) on the evaluation views, mean ± population std over seeds (hover a '
        "cell for the number of seeds). A scene's page has every metric with paired 95% intervals, the curves over "
        "the steps and each run's pictures. Proxies and the procedural default scene are stand-ins, not the paper's "
        "assets.</p>"
    )
    if duel:
        parts.append(
            '<p><a href="duel.html">Duels</a>: which method\'s next view is better from the same state, paired '
            "one-step decisions beside the episodes' final PSNR.</p>"
        )
    if transfer is not None:
        parts.append(transfer_html(transfer))
    return _page("nvf-bench results", "".join(parts), style=STYLE + LEAD_STYLE)


def transfer_html(transfer: pd.DataFrame) -> str:
    """Per rival of NVF, its one-step verdict at the cpu budget beside the same states trained at the paper's scale
    (``pilots/paper_states/transfer.csv``) and whether it holds at both, flips or is unknown at one."""
    head = "".join(
        f"<th>{html.escape(name)}</th>"
        for name in ("rival", "states", "NVF's gain, cpu (dB)", "NVF's gain, paper (dB)", "verdict at both scales")
    )
    rows = "".join(
        f'<tr><td class="label">{html.escape(str(r["label"]))}</td><td>{int(r["states"])}</td>'
        f"<td>{bold_interval(Interval(r['cpu_gain'], r['cpu_low'], r['cpu_high'], int(r['states'])))}</td>"
        f"<td>{bold_interval(Interval(r['paper_gain'], r['paper_low'], r['paper_high'], int(r['states'])))}</td>"
        f"<td>{html.escape(str(r['verdict']))}</td></tr>"
        for _, r in transfer.iterrows()
    )
    return (
        "<h2>Do the verdicts hold at the paper's scale?</h2><p>The same states trained at the cpu budget and at the "
        "paper's (its 512-px images, iterations and table size): NVF's pick's one-step held-out PSNR minus the "
        "rival's, 0 where both pick one view, mean [95% interval] over the states "
        '(<a href="../pilots/paper_states/transfer.md">transfer.md</a>).</p>'
        f'<div class="wide"><table><thead><tr>{head}</tr></thead><tbody>{rows}</tbody></table></div>'
    )


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


def _band_edge(frame: pd.DataFrame, column: str, label: str, fill: str | None = None) -> go.Scatter:
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
            fig.add_trace(_band_edge(frame, "high", label))
            fig.add_trace(_band_edge(frame, "low", label, fill=_alpha(color, 0.12)))
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


def _alpha(color: str, alpha: float) -> str:
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
            parts.append(_run_card(run, found, page))
        parts.append("</div>")
    return _page(f"{scene}, {budget} budget", "".join(parts), "../", plotly=True)


def _run_card(run: pd.Series, found: RunPictures, page: Path) -> str:
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


MAX_NOTE_BYTES = 1 << 20  # a pilot's Markdown note
SAFE_SCHEMES = ("http", "https", "mailto")
SPACE_OR_CONTROL = re.compile(r"[\x00-\x20\x7f]")


def safe_url(url: str) -> bool:
    """Whether a note may link to ``url``: an http(s) or mailto address, or a relative one (no scheme, not from
    the root); ``javascript:``, ``data:``, ``file:`` and absolute paths are not, nor anything with a space or a
    control character (which browsers drop, so ``java\tscript:`` would run)."""
    if SPACE_OR_CONTROL.search(url) or url.startswith(("/", "\\")):
        return False
    scheme, colon, _ = url.partition(":")
    return not colon or any(ch in scheme for ch in "/?#") or scheme.lower() in SAFE_SCHEMES


class _NoteLinks(Treeprocessor):
    """Each link and image of a note kept only where ``safe_url`` allows it, a relative one pointing at the
    note's folder (``base``: relative to the page), and the note's headings three levels down."""

    def __init__(self, md: markdown.Markdown, base: str):
        super().__init__(md)
        self.base = base

    def run(self, root: ElementTree.Element) -> None:
        for element in root.iter():
            if re.fullmatch(r"h[1-6]", element.tag):
                element.tag = f"h{min(6, int(element.tag[1]) + 3)}"
            for attribute in ("href", "src"):
                url = element.get(attribute)
                if url is None or url.startswith("#"):
                    continue
                if not safe_url(url):
                    del element.attrib[attribute]
                elif ":" not in url.split("/")[0]:
                    element.set(attribute, f"{self.base}/{url}")


class _TextNote(Extension):
    """A note rendered as text: raw HTML (blocks and inline) is not recognised, so it is escaped like any text."""

    def __init__(self, base: str):
        super().__init__()
        self.base = base

    def extendMarkdown(self, md: markdown.Markdown) -> None:
        md.preprocessors.deregister("html_block")
        md.inlinePatterns.deregister("html")
        md.treeprocessors.register(_NoteLinks(md, self.base), "note_links", 0)


def _note(path: Path, page: Path) -> str:
    """A Markdown note as HTML under the page's own headings (``_TextNote``); read only from a regular file (never
    through a symbolic link, at most ``MAX_NOTE_BYTES``), else one line saying why it is not shown."""
    try:
        data = read_plain_file(path, MAX_NOTE_BYTES) or b""
    except RecordError as err:
        return f'<p class="note">not shown: {html.escape(str(err))}</p>'
    text = data.decode("utf-8", "replace")
    return markdown.markdown(text, extensions=["tables", "fenced_code", _TextNote(link(path.parent, page))])


def pilots_page(pilots: Path, page: Path) -> str:
    """Each pilot under ``pilots``: its Markdown notes (README.md, summaries) and pictures, two folders deep
    (the records under them are not listed); links in the notes point at the files beside them."""
    folders = sorted(p for p in pilots.iterdir() if p.is_dir()) if pilots.is_dir() else []
    folders = [folder for folder in folders if escaping_link(pilots, folder) is None]
    parts = [f"<p>No pilots under {html.escape(str(pilots))}.</p>"] if not folders else []
    if folders:
        items = "".join(f'<li><a href="#{html.escape(f.name)}">{html.escape(f.name)}</a></li>' for f in folders)
        parts.append(f"<p>Settings tried beside the budgets, each with its notes and pictures:</p><ul>{items}</ul>")
    for folder in folders:
        parts.append(f'<div class="pilot"><h2 id="{html.escape(folder.name)}">{html.escape(folder.name)}</h2>')
        files = sorted(
            (
                path
                for path in {
                    *folder.glob("*.md"),
                    *folder.glob("*/*.md"),
                    *folder.glob("*.png"),
                    *folder.glob("*/*.png"),
                }
                if escaping_link(pilots, path.parent) is None
            ),
            key=lambda p: (p.parent != folder, p.parent.name, p.name != "README.md", p.name),
        )
        for path in files:
            where = path.relative_to(folder).as_posix()
            if path.suffix == ".png":
                if not is_plain_file(path):
                    continue
                parts.append(f'<h3>{html.escape(where)}</h3><img src="{link(path, page)}" alt="{html.escape(where)}">')
                continue
            parts.append(f"<h3>{html.escape(where)}</h3>{_note(path, page)}")
        parts.append("</div>")
    return _page("Pilots", "".join(parts))


def bold_interval(interval: Interval) -> str:
    """An interval's text, escaped, in bold where it excludes zero."""
    text = html.escape(interval.text())
    return f"<strong>{text}</strong>" if interval.excludes_zero else text


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
    return _page("Duels: paired one-step decisions", "".join(parts))
