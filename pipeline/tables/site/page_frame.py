"""What every page of the results site shares: its HTML frame and style, plotly's script's name, links between
files, a run's pictures, an interval's bold."""

import html
import os
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import quote

from jinja2 import Environment

from pipeline.tables.stats import Interval

PLOTLY_JS = "plotly.min.js"


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


def page_html(title: str, body: str, home: str = "", plotly: bool = False, style: str = STYLE) -> str:
    """A whole page; ``home``: the site's folder relative to the page's ("" or "../")."""
    return PAGE.render(title=title, body=body, style=style, home=home, plotly=f"{home}{PLOTLY_JS}" if plotly else None)


def bold_interval(interval: Interval) -> str:
    """An interval's text, escaped, in bold where it excludes zero."""
    text = html.escape(interval.text())
    return f"<strong>{text}</strong>" if interval.excludes_zero else text
