"""The results site, ``${paths.results}/site/``: static pages that open from ``file://`` with no server and no
network. ``index.html`` is a methods x scenes overview of the final PSNR; one page per scene and budget holds
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
from plotly.offline import get_plotlyjs

from pipeline.records.checked import Number, Text, read_csv
from pipeline.records.files import RecordError, escaping_link, is_plain_file, read_plain_file
from pipeline.records.store import atomic_write_text
from pipeline.tables.aggregate import SPECS, Table, build_table
from pipeline.tables.figures import safe_name
from pipeline.tables.load import Runs
from pipeline.tables.paper import paper_numbers
from pipeline.tables.render import html_table
from pipeline.tables.stats import LEVEL, Interval

PLOTLY_JS = "plotly.min.js"
DUEL_SUMMARY = Path("pilots", "duel", "summary.csv")  # pipeline.experiments.duel_summary's table
DB = Number(-100.0, 100.0, null=True)  # a PSNR difference, or none
# A 95% Student-t bound over differences in [-100, 100] dB: at two values t = 12.7 times their spread, so up to
# about +-1400 dB; the writer's intervals are read back as it wrote them.
INTERVAL_DB = Number(-2000.0, 2000.0, null=True)
DUEL_COLUMNS = {
    "method": Text(),
    "rival": Text(),
    "scene": Text(),
    "n": Number(0, 2**31, integer=True),
    "gain_mean": DB,
    "ci_low": INTERVAL_DB,
    "ci_high": INTERVAL_DB,
    "same_pick": Number(0.0, 1.0, null=True),
    "episode_diff": DB,
    "episode_ci_low": INTERVAL_DB,
    "episode_ci_high": INTERVAL_DB,
    "cpu_hours": Number(0.0, null=True),
}  # the duel summary's columns as the site reads them back (pipeline.records.checked)

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


def write_site(runs: Runs, pictures: Mapping[str, RunPictures], results: Path, site: Path) -> list[Path]:
    """Write the site of ``results`` into the folder ``site`` (beside ``results / "site"``, which it replaces:
    ``pipeline.tables.build``) from the runs and each run's pictures (by run directory); the pilots and the duel's
    summary are read from ``results``. Returns the files written."""
    done = runs.final[runs.final["status"] == "done"]
    pages_text: dict[Path, str] = {site / PLOTLY_JS: get_plotlyjs()}  # plotly.js, its MIT licence in its first lines
    pages = {}
    for (budget, scene), frame in done.groupby(["budget", "scene"]):
        path = site / scene_page_name(scene, budget)
        pages[(budget, scene)] = path
        pages_text[path] = scene_page(runs, frame, pictures, scene, budget, path)
    duels = read_csv(Path(results) / DUEL_SUMMARY, DUEL_COLUMNS)
    if duels is not None:
        pages_text[site / "duel.html"] = duel_page(duels)
    index = site / "index.html"
    pages_text[index] = index_page(runs, done, pages, index, duels is not None)
    pilots = site / "pilots.html"
    pages_text[pilots] = pilots_page(Path(results) / "pilots", pilots)
    for path, text in pages_text.items():
        atomic_write_text(path, text)
    return list(pages_text)


def _page(title: str, body: str, home: str = "", plotly: bool = False) -> str:
    """A whole page; ``home``: the site's folder relative to the page's ("" or "../")."""
    return PAGE.render(title=title, body=body, style=STYLE, home=home, plotly=f"{home}{PLOTLY_JS}" if plotly else None)


def index_page(
    runs: Runs, done: pd.DataFrame, pages: Mapping[tuple[str, str], Path], page: Path, duel: bool = False
) -> str:
    """Per budget, methods x scenes: final PSNR mean ± population std over seeds, each scene linking to its page;
    ``duel``: link the duel's page."""
    parts = []
    if done.empty:
        parts.append(
            "<p>No finished runs yet: run <code>python -m pipeline.run</code>, then "
            "<code>python -m pipeline.tables</code>.</p>"
        )
    for budget, frame in done.groupby("budget"):
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
                text = f"{psnr.mean():.2f} ± {psnr.std():.2f}" if len(psnr) else "-"
                cells.append(f'<td title="{len(psnr)} seeds">{text}</td>')
            lines.append(f'<tr><td class="label">{html.escape(runs.row(*key).label)}</td>{"".join(cells)}</tr>')
        parts.append(
            f'<h2>{html.escape(budget)} budget</h2><div class="wide"><table><thead><tr><th>method</th>{head}</tr>'
            f"</thead><tbody>{''.join(lines)}</tbody></table></div>"
        )
    parts.append(
        '<p class="note">Final PSNR (dB) on the evaluation views: mean ± population std over seeds (hover a cell for '
        "the number of seeds). A scene's page has every metric with paired 95% intervals, the curves over the steps "
        "and each run's pictures. Proxies and the procedural default scene are stand-ins, not the paper's assets.</p>"
    )
    if duel:
        parts.append(
            '<p><a href="duel.html">Duels</a>: which method\'s next view is better from the same state, paired '
            "one-step decisions beside the episodes' final PSNR.</p>"
        )
    return _page("nvf-bench results", "".join(parts))


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


def duel_cell(row: pd.Series) -> str:
    """One pair's cell: the one-step gain with its interval (bold where it excludes zero), its decisions, and the
    episodes' final-PSNR difference beneath (bold likewise)."""
    gain = Interval(row["gain_mean"], row["ci_low"], row["ci_high"], int(row["n"]))
    episode = Interval(row["episode_diff"], row["episode_ci_low"], row["episode_ci_high"], 0)
    gain_html, episode_html = (
        f"<strong>{html.escape(i.text())}</strong>" if i.excludes_zero else html.escape(i.text())
        for i in (gain, episode)
    )
    title = f"{int(row['n'])} differing decisions, same pick {row['same_pick']:.0%}, {row['cpu_hours']:.2f} cpu h"
    return (
        f'<td title="{html.escape(title)}">{gain_html} <span class="note">n={int(row["n"])}</span><br>'
        f'<span class="note">episodes {episode_html}</span></td>'
    )


def duel_page(summary: pd.DataFrame) -> str:
    """Per scene (and over scenes), a method x rival matrix of the duel's one-step gains (``summary.csv`` of
    ``pipeline.experiments.duel_summary``)."""
    parts = [
        "<p>A duel scores the same candidate views with two methods on the same states (half from each method's "
        "recorded episodes); where their picks differ, the plain backbone is trained one step with each pick and "
        "measured on the evaluation views. A cell: the row method's pick minus the column rival's in held-out "
        "PSNR (dB, mean [95% Student-t interval] over the n decisions whose picks differ) and, beneath, the row "
        "method's final PSNR minus the rival's in their episodes (paired by seed). Bold: the interval excludes "
        "zero. Hover a cell for the share of identical picks and the duel's cpu hours.</p>"
    ]
    for scene, block in summary.groupby("scene", sort=False):
        methods, rivals = list(dict.fromkeys(block["method"])), list(dict.fromkeys(block["rival"]))
        head = "".join(f"<th>{html.escape(str(r))}</th>" for r in rivals)
        lines = []
        for method in methods:
            cells = []
            for rival in rivals:
                found = block[(block["method"] == method) & (block["rival"] == rival)]
                cells.append(duel_cell(found.iloc[0]) if len(found) else "<td>-</td>")
            lines.append(f'<tr><td class="label">{html.escape(str(method))}</td>{"".join(cells)}</tr>')
        parts.append(
            f'<h2>{html.escape(str(scene))}</h2><div class="wide"><table><thead><tr><th>method \\ rival</th>'
            f"{head}</tr></thead><tbody>{''.join(lines)}</tbody></table></div>"
        )
    return _page("Duels: paired one-step decisions", "".join(parts))
