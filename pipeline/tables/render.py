"""A ``Table`` as Markdown, CSV and LaTeX texts (and an HTML table for the results site): cells 'mean ± std' (bold
for the best, † where some seeds lack the value), ‡ after the label of a row planned with the mesh's line of
sight, § after the label of a row whose method the paper does not have, header lines
and footnotes. Every cell, header line and footnote is escaped for its format (``pipeline.tables.escape``):
labels, sources and reasons come from run records."""

import html
import re

import pandas as pd

from pipeline.metrics.info import PAPER_METRICS
from pipeline.tables.aggregate import MESH_LOS_MARK, NOT_IN_PAPER_MARK, ORACLE_FLAGS, Table
from pipeline.tables.escape import markdown, plain, tex_escape

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
    low, high = row["psnr_vs_nvf_low"], row["psnr_vs_nvf_high"]
    text = f"{row['psnr_vs_nvf_mean']:+.2f}" + (f" [{low:+.2f}, {high:+.2f}]" if pd.notna(low) else "")
    return text + (f" (n={int(n)})" if n < row["n"] else "")


def _grid(table: Table, label_header: str) -> tuple[list[str], list[list[str]]]:
    """Column names and Markdown cell texts (csv drops the bold marks, tex converts them); the ΔPSNR column
    where some row has an NVF row to be compared with."""
    keys = (["section"] if "section" in table.rows else []) + (["budget"] if table.rows["budget"].nunique() > 1 else [])
    versus = "psnr_vs_nvf_n" in table.rows and (table.rows["psnr_vs_nvf_n"] > 0).any()
    columns = [key.capitalize() for key in keys] + ["Scene", label_header]
    columns += [f"{m.label}{m.arrow}" for m in PAPER_METRICS] + (["ΔPSNR vs NVF"] if versus else []) + ["n"]
    cells = []
    for _, row in table.rows.iterrows():
        label = row["label"] + (MESH_LOS_MARK if any(row.get(flag, False) for flag, _ in ORACLE_FLAGS) else "")
        label += "" if row.get("in_paper", True) else NOT_IN_PAPER_MARK
        line = [str(row[key]) for key in keys] + [row["scene"], label]
        line += [_cell(row, m.name, m.decimals) for m in PAPER_METRICS] + ([_versus_nvf(row)] if versus else [])
        cells.append(line + [str(int(row["n"]))])
    return columns, cells


def markdown_table(columns: list[str], cells: list[list[str]]) -> str:
    """A Markdown table of text cells, each escaped (``pipeline.tables.escape.markdown``; ``**bold**`` kept)."""
    grid = pd.DataFrame([[markdown(c) for c in line] for line in cells], columns=[markdown(c) for c in columns])
    return grid.to_markdown(index=False, disable_numparse=True)


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
    columns, cells = _grid(table, label_header)
    md = [
        f"# {table.title}",
        "",
        *map(markdown, table.header),
        "",
        markdown_table(columns, cells),
        "",
        *(f"- {markdown(n)}" for n in table.notes),
    ]
    bare = [[plain(c).replace("**", "") for c in line] for line in cells]
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
        *(" & ".join(map(tex_escape, line)) + r" \\" for line in cells),
        r"\bottomrule",
        r"\end{tabular}",
        *(r"\par{\footnotesize " + tex_escape(n) + "}" for n in table.notes),
    ]
    return {"md": "\n".join(md) + "\n", "csv": csv, "tex": "\n".join(tex) + "\n"}


BOLD = re.compile(r"\*\*(.+?)\*\*")


def _html_cell(text: str) -> str:
    return BOLD.sub(r"<strong>\1</strong>", html.escape(text))


def html_table(table: Table, label_header: str) -> str:
    """The table's rows as an HTML ``<table>`` (the Markdown cells; a best value in ``<strong>``)."""
    if table.rows.empty:
        return "<p>No finished runs.</p>"
    columns, cells = _grid(table, label_header)
    head = "".join(f"<th>{html.escape(c)}</th>" for c in columns)
    body = "".join("<tr>" + "".join(f"<td>{_html_cell(c)}</td>" for c in line) + "</tr>" for line in cells)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


LABEL_HEADERS = {"table2_ablation": "Variant"}
