"""Record text made safe for the files it goes into. Labels, budget labels, sources and reasons come from run
records (untrusted input): in a table they are plain text, never markup, and never more than one line.

- ``plain``: one line (control characters and line breaks become spaces); comment lines.
- ``markdown``: ``plain`` with every character that Markdown (CommonMark, GitHub's tables, Python-Markdown)
  reads as markup escaped: emphasis, code, links and images, cell breaks, HTML, entities, strikethrough, and a
  block marker (``#``, ``>``, ``-``, ``+``, ``1.``) at its start.
- ``tex_escape``: LaTeX for plain text (TeX's specials escaped); comment lines take ``plain``.
- ``csv_cell``: a CSV cell a spreadsheet shows as text: one starting with ``=``, ``+``, ``-``, ``@``, a tab or a
  carriage return (a formula) gets a leading ``'``, unless it is a number (``-0.5`` stays a number);
  ``as_csv``: a data frame as CSV with the text cells of its named columns ``csv_cell`` (the experiments' csv files).
- ``plot_text``: ``plain`` with ``$`` escaped (no matplotlib mathtext).
"""

import re
from collections.abc import Sequence

import pandas as pd

CONTROL = re.compile(r"[\x00-\x1f\x7f]")
MARKDOWN_SPECIALS = {
    "\\": "\\\\",
    "`": "\\`",
    "*": "\\*",
    "[": "\\[",
    "]": "\\]",
    "|": "\\|",
    "<": "&lt;",
    "&": "&amp;",
    "~": "&#126;",
}
WORD_EDGE_UNDERSCORE = re.compile(r"(?<![A-Za-z0-9])_|_(?![A-Za-z0-9])")  # within a word (lego_proxy) it is text
MARKDOWN_BLOCK_START = re.compile(r"^(\d*)([#>+-]|(?<=\d)[.)])")  # a heading, quote, list item or rule
FORMULA_START = ("=", "+", "-", "@", "\t", "\r")
NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")
TEX_SPECIALS = (
    ("\\", r"\textbackslash{}"),
    ("&", r"\&"),
    ("%", r"\%"),
    ("$", r"\$"),
    ("#", r"\#"),
    ("_", r"\_"),
    ("{", r"\{"),
    ("}", r"\}"),
    ("~", r"\textasciitilde{}"),
    ("^", r"\textasciicircum{}"),
    ("±", r"$\pm$"),
    ("↑", r"$\uparrow$"),
    ("↓", r"$\downarrow$"),
    ("†", r"$^\dagger$"),
    ("‡", r"$^\ddagger$"),
    ("≈", r"$^\approx$"),
    ("§", r"$^\S$"),
    ("°", r"$^\circ$"),
    ("Δ", r"$\Delta$"),
)


def plain(text: object) -> str:
    """``text`` as one line: control characters and every run of whitespace become one space."""
    return " ".join(CONTROL.sub(" ", str(text)).split())


def markdown(text: object) -> str:
    """``plain(text)`` for a Markdown table cell or line, shown as the text it is (``MARKDOWN_SPECIALS``
    escaped, and a block marker at its start)."""
    out = "".join(MARKDOWN_SPECIALS.get(ch, ch) for ch in plain(text))
    return MARKDOWN_BLOCK_START.sub(r"\1\\\2", WORD_EDGE_UNDERSCORE.sub(r"\\_", out))


def tex_escape(text: object) -> str:
    """LaTeX for ``plain(text)``: specials escaped, ± ↑ ↓ † ‡ ≈ § ° Δ as math."""
    specials = dict(TEX_SPECIALS)
    return "".join(specials.get(ch, ch) for ch in plain(text))


def csv_cell(text: object) -> str:
    """``text`` as a CSV cell a spreadsheet shows as text, not a formula (a leading ``'``; numbers unchanged)."""
    text = str(text)
    return f"'{text}" if text.startswith(FORMULA_START) and not NUMBER.fullmatch(text) else text


def as_csv(frame: pd.DataFrame, text: Sequence[str], float_format: str | None = None) -> str:
    """``frame`` as CSV (no index), each text cell of its columns named in ``text`` (those holding names from
    records and settings) a ``csv_cell``; other cells, and empty ones, as they are."""
    escaped = frame.copy()
    for name in (name for name in text if name in frame.columns):
        escaped[name] = frame[name].map(lambda value: csv_cell(value) if isinstance(value, str) else value)
    return escaped.to_csv(index=False, float_format=float_format)


def plot_text(text: object) -> str:
    """``plain(text)`` for a matplotlib title or legend: ``$`` escaped, so it is never read as mathtext."""
    return plain(text).replace("$", r"\$")
