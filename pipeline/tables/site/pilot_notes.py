"""The pilots' Markdown notes as HTML text (``pilots.html`` and the duel page's closing note): raw HTML in a note
escaped, links only to http(s), mailto and the files beside the note; a note that is a symbolic link, or lies
behind one leaving the pilots, is not read."""

import html
import re
from pathlib import Path
from xml.etree import ElementTree

import markdown
from markdown.extensions import Extension
from markdown.treeprocessors import Treeprocessor

from pipeline.records.files import RecordError, escaping_link, is_plain_file, read_plain_file
from pipeline.tables.site.page_frame import link, page_html

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


class NoteLinks(Treeprocessor):
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


class TextNote(Extension):
    """A note rendered as text: raw HTML (blocks and inline) is not recognised, so it is escaped like any text."""

    def __init__(self, base: str):
        super().__init__()
        self.base = base

    def extendMarkdown(self, md: markdown.Markdown) -> None:
        md.preprocessors.deregister("html_block")
        md.inlinePatterns.deregister("html")
        md.treeprocessors.register(NoteLinks(md, self.base), "note_links", 0)


def note_html(path: Path, page: Path) -> str:
    """A Markdown note as HTML under the page's own headings (``TextNote``); read only from a regular file (never
    through a symbolic link, at most ``MAX_NOTE_BYTES``), else one line saying why it is not shown."""
    try:
        data = read_plain_file(path, MAX_NOTE_BYTES) or b""
    except RecordError as err:
        return f'<p class="note">not shown: {html.escape(str(err))}</p>'
    text = data.decode("utf-8", "replace")
    return markdown.markdown(text, extensions=["tables", "fenced_code", TextNote(link(path.parent, page))])


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
            parts.append(f"<h3>{html.escape(where)}</h3>{note_html(path, page)}")
        parts.append("</div>")
    return page_html("Pilots", "".join(parts))
