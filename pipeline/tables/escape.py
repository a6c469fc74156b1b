"""Record text made safe for the files it goes into. Labels, budget labels, sources and reasons come from run
records (untrusted input): in a table they are plain text, never markup, and never more than one line.

- ``plain``: one line (control characters and line breaks become spaces); CSV cells and comment lines.
- ``markdown``: ``plain`` with ``\\``, ``|`` and ``<`` escaped (no cell break, escape or HTML of its own).
- ``tex_escape``: LaTeX for plain text (TeX's specials escaped); comment lines take ``plain``.
- ``plot_text``: ``plain`` with ``$`` escaped (no matplotlib mathtext).
"""

import re

CONTROL = re.compile(r"[\x00-\x1f\x7f]")
MARKDOWN_SPECIALS = (("\\", "\\\\"), ("|", "\\|"), ("<", "&lt;"))
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
    ("Δ", r"$\Delta$"),
)


def plain(text: object) -> str:
    """``text`` as one line: control characters and every run of whitespace become one space."""
    return " ".join(CONTROL.sub(" ", str(text)).split())


def markdown(text: object) -> str:
    """``plain(text)`` for a Markdown table cell or line: ``\\``, ``|`` and ``<`` escaped."""
    out = plain(text)
    for special, escaped in MARKDOWN_SPECIALS:
        out = out.replace(special, escaped)
    return out


def tex_escape(text: object) -> str:
    """LaTeX for ``plain(text)`` (specials escaped, ± ↑ ↓ † as math); '**x**' (a best cell) becomes bold."""
    text = plain(text)
    specials = dict(TEX_SPECIALS)
    bold = text.startswith("**") and "**" in text[2:]
    if bold:
        inner, rest = text[2:].split("**", 1)
        return r"\textbf{" + tex_escape(inner) + "}" + tex_escape(rest)
    return "".join(specials.get(ch, ch) for ch in text)


def plot_text(text: object) -> str:
    """``plain(text)`` for a matplotlib title or legend: ``$`` escaped, so it is never read as mathtext."""
    return plain(text).replace("$", r"\$")
