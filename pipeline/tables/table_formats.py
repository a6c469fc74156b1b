"""A ``Table`` as Markdown, CSV and LaTeX texts (and an HTML table for the results site): cells 'mean ± std' (bold
for the best, † where some seeds lack the value), ‡ after the label of a row planned with the mesh's line of
sight, § after the label of a row whose method the paper does not have, ° after the label of a row whose seeds
were not made alike (a dirty checkout, another thread count), header lines and footnotes. The text cells (budget,
scene, label), header lines and footnotes are escaped for their format (``pipeline.tables.escape``): labels,
sources and reasons come from run records. Only the value cells, which this module writes from numbers, carry
markup (a best value's bold)."""

import html
import re

import pandas as pd

from pipeline.metrics.info import PAPER_METRICS
from pipeline.tables.aggregate import IRREGULAR_MARK, MESH_LOS_MARK, NOT_IN_PAPER_MARK, ORACLE_FLAGS, Table
from pipeline.tables.escape import csv_cell, markdown, plain, tex_escape
from pipeline.tables.stats import Interval

TIE_MARK = "≈"


def _cell(row: pd.Series, metric: str, decimals: int) -> str:
    """'mean ± std' ('mean' alone from one seed; bold if the significant best, ≈ if tied best, † if some
    seeds lack it, '-' if none has it), then ' / paper' if any."""
    mean, std, valid = row[f"{metric}_mean"], row[f"{metric}_std"], row[f"{metric}_valid"]
    text = "-"
    if valid > 0:
        text = f"{mean:.{decimals}f}" + (f" ± {std:.{decimals}f}" if valid > 1 else "")
        if row.get(f"{metric}_best", False):
            text = f"**{text}**"
        text += TIE_MARK if row.get(f"{metric}_tie", False) else ""
        text += "†" if valid < row["n"] else ""
    if f"{metric}_paper" in row:
        text += f" / {row[f'{metric}_paper']:.{decimals}f}"
    return text


def _versus_nvf(row: pd.Series) -> str:
    """'+0.52 [-0.31, +1.35]' (n pairs added where fewer than the row's seeds); '-' for NVF itself or none."""
    n = row.get("psnr_vs_nvf_n")
    if n is None or not n > 0:
        return "-"
    interval = Interval(row["psnr_vs_nvf_mean"], row["psnr_vs_nvf_low"], row["psnr_vs_nvf_high"], int(n))
    return interval.text() + (f" (n={int(n)})" if n < row["n"] else "")


def _grid(table: Table, label_header: str) -> tuple[list[str], list[list[str]], int]:
    """Column names, cell texts and how many of each row's first cells are text from the records (the others
    are values: numbers with ``**`` around a best one, which each format converts); the ΔPSNR column where some
    row has an NVF row to be compared with."""
    keys = (["section"] if "section" in table.rows else []) + (["budget"] if table.rows["budget"].nunique() > 1 else [])
    versus = "psnr_vs_nvf_n" in table.rows and (table.rows["psnr_vs_nvf_n"] > 0).any()
    columns = [key.capitalize() for key in keys] + ["Scene", label_header]
    columns += [f"{m.label}{m.arrow}" for m in PAPER_METRICS] + (["ΔPSNR vs NVF"] if versus else []) + ["n"]
    cells = []
    for _, row in table.rows.iterrows():
        label = row["label"] + (MESH_LOS_MARK if any(row.get(flag, False) for flag, _ in ORACLE_FLAGS) else "")
        label += "" if row.get("in_paper", True) else NOT_IN_PAPER_MARK
        label += IRREGULAR_MARK if row.get("irregular", False) else ""
        line = [str(row[key]) for key in keys] + [row["scene"], label]
        line += [_cell(row, m.name, m.decimals) for m in PAPER_METRICS] + ([_versus_nvf(row)] if versus else [])
        cells.append(line + [str(int(row["n"]))])
    return columns, cells, len(keys) + 2


def markdown_table(columns: list[str], rows: list[list[object]], left: int = 1) -> list[str]:
    """A Markdown table's lines: the first ``left`` columns hold text (names, labels: escaped, ``escape.markdown``)
    and are aligned left; the others hold values the code formatted (numbers, intervals: one line, no cell
    break) and are aligned right."""
    align = ["|", *(":--|" if i < left else "--:|" for i in range(len(columns)))]

    def cell(i: int, value: object) -> str:
        return markdown(value) if i < left else plain(value).replace("|", "\\|")

    return [
        "| " + " | ".join(map(markdown, columns)) + " |",
        "".join(align),
        *("| " + " | ".join(cell(i, value) for i, value in enumerate(row)) + " |" for row in rows),
    ]


def render(table: Table, label_header: str, experiment: str | None) -> dict[str, str]:
    """The table as {'md', 'csv', 'tex'} texts ('no runs yet' texts when it has no rows)."""
    if table.rows.empty:
        command = f"python -m pipeline.run -m experiment={experiment}" if experiment else "python -m pipeline.run"
        message = f"No runs yet for {table.name}: run `{command}`, then `python -m pipeline.tables`."
        return {
            "md": "\n".join([f"# {table.title}", "", message, "", *(f"- {markdown(n)}" for n in table.notes)]).rstrip()
            + "\n",
            "csv": pd.DataFrame({"note": [message, *map(plain, table.notes)]}).to_csv(index=False),
            "tex": "\n".join([f"% {table.title}", tex_escape(message), *(tex_escape(n) for n in table.notes)]) + "\n",
        }
    columns, cells, texts = _grid(table, label_header)
    grid = pd.DataFrame([[*map(markdown, line[:texts]), *line[texts:]] for line in cells], columns=columns)
    md = [
        f"# {table.title}",
        "",
        *map(markdown, table.header),
        "",
        grid.to_markdown(index=False, disable_numparse=True),
        "",
        *(f"- {markdown(n)}" for n in table.notes),
    ]
    bare = [[csv_cell(plain(c)) for c in line[:texts]] + [c.replace("**", "") for c in line[texts:]] for line in cells]
    csv = "".join(f"# {plain(line)}\n" for line in (table.title, *table.header))
    csv += pd.DataFrame(bare, columns=columns).to_csv(index=False) + "".join(f"# {plain(n)}\n" for n in table.notes)
    tex = [
        f"% {table.title}",
        *(f"% {plain(line)}" for line in table.header),
        r"\begin{tabular}{"
        + "l" * (columns.index("Scene") + 2)
        + "c" * (len(columns) - columns.index("Scene") - 3)
        + "r}",
        r"\toprule",
        " & ".join(map(tex_escape, columns)) + r" \\",
        r"\midrule",
        *(" & ".join([*map(tex_escape, line[:texts]), *map(_tex_value, line[texts:])]) + r" \\" for line in cells),
        r"\bottomrule",
        r"\end{tabular}",
        *(r"\par{\footnotesize " + tex_escape(n) + "}" for n in table.notes),
    ]
    return {"md": "\n".join(md) + "\n", "csv": csv, "tex": "\n".join(tex) + "\n"}


BOLD = re.compile(r"\*\*(.+?)\*\*")


def _tex_value(cell: str) -> str:
    """A value cell in LaTeX: its ``**best**`` bold."""
    return "".join(
        r"\textbf{" + tex_escape(part) + "}" if i % 2 else tex_escape(part) for i, part in enumerate(BOLD.split(cell))
    )


def _html_value(cell: str) -> str:
    """A value cell in HTML: its ``**best**`` in ``<strong>``."""
    return BOLD.sub(r"<strong>\1</strong>", html.escape(cell))


def html_table(table: Table, label_header: str) -> str:
    """The table's rows as an HTML ``<table>`` (the Markdown cells; a best value in ``<strong>``)."""
    if table.rows.empty:
        return "<p>No finished runs.</p>"
    columns, cells, texts = _grid(table, label_header)
    head = "".join(f"<th>{html.escape(c)}</th>" for c in columns)
    body = "".join(
        "<tr>"
        + "".join(f"<td>{html.escape(c)}</td>" for c in line[:texts])
        + "".join(f"<td>{_html_value(c)}</td>" for c in line[texts:])
        + "</tr>"
        for line in cells
    )
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


LABEL_HEADERS = {"table2_ablation": "Variant"}
