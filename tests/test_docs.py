"""The repository stands on its own: docs and code comments cite only files it contains, every
"METHOD n" / "PROTOCOL n.m" / M-label / D-label citation lands on docs/METHOD.md or docs/PROTOCOL.md,
and no work-diary label ("Session 12", "on that day's machine", a date of work) is in a tracked file.

Docs are README.md, docs/*.md and results/**/README.md; code is the comments and docstrings of
nvf/, pipeline/, conf/, scripts/ and tests/.
"""

import ast
import io
import re
import subprocess
import tokenize
from functools import cache
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"
CODE_DIRS = ("nvf", "pipeline", "conf", "scripts", "tests")
CODE_SUFFIXES = {".py", ".yaml", ".yml", ".sh", ".cpp"}
THIS_FILE = Path(__file__).resolve().relative_to(REPO).as_posix()
DOC_NAMES = ("METHOD.md", "PROTOCOL.md", "BUDGETS.md", "DEVIATIONS.md", "ARCHITECTURE.md", "USAGE.md", "RECORDS.md")
BINARY_SUFFIXES = {".png", ".jpg", ".pdf", ".blend", ".glb", ".ply", ".npz", ".pth"}
DATA_SUFFIXES = {".json", ".jsonl", ".csv", ".tex"}  # records and tables: timestamps are data there

# `a/b/c.ext` or `a/b/` mentions; a repository path starts with ./ ../ or a top-level entry of the checkout
PATH_TOKEN = re.compile(r"(?<![\w.\-/$}>])((?:\.\.?/)*[\w.\-]+(?:/[\w.\-]+)*/[\w.\-]*)")
FILE_EXTENSIONS = ("md", "py", "yaml", "yml", "json", "jsonl", "csv", "tex", "png", "cpp", "sh", "toml", "txt")
MARKDOWN_LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")
BARE_DOC = re.compile(r"(?<![\w/.\-])([A-Z][A-Z_]*\.md)\b")
PLACEHOLDER = re.compile(r"^(?:NAME|DIR|PATH|FILE|SCENE)(?:\.\w+)?$")  # usage lines: pipeline/bench/NAME.py
FORBIDDEN_PHRASES = re.compile(r"project brief|\.\./shared", re.IGNORECASE)

DIARY = re.compile(
    r"\bSessions? \d+|\b[Oo]n that day\b|\bthat day's\b|\b(?:last|this|previous|earlier|next) session\b|\byesterday\b",
    re.IGNORECASE,
)
WORK_DATE = re.compile(r"\b20\d\d-[01]\d-[0-3]\d\b")

CITATION = re.compile(
    r"\b(METHOD|PROTOCOL)(?:\.md)?(?:\s+sections?)?(?:\s+§)?\s+(\d+(?:\.\d+)?)(?![\w^])"
    r"(?:\s*(?:-|–|and|,)\s*(\d+(?:\.\d+)?)(?![\w^.]))?"
)
M_LABEL = re.compile(r"(?<![\w.])M(\d{1,2})(?![\w])")
D_LABEL = re.compile(r"(?<![\w.])D(\d{1,2})(?![\w])")


@cache
def tracked_files() -> tuple[str, ...]:
    """Repository-relative paths of the checkout's files (git's index; a plain walk without git)."""
    try:
        out = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, capture_output=True, check=True).stdout
        return tuple(sorted(p for p in out.decode().split("\0") if p and (REPO / p).exists()))
    except (OSError, subprocess.CalledProcessError):
        skip = {".git", ".venv", "outputs", "data", "__pycache__"}
        return tuple(
            sorted(
                p.relative_to(REPO).as_posix()
                for p in REPO.rglob("*")
                if p.is_file() and not skip.intersection(p.relative_to(REPO).parts)
            )
        )


@cache
def tracked_paths() -> frozenset[str]:
    """Tracked files and every directory above them."""
    paths = set(tracked_files())
    for file in tracked_files():
        parts = file.split("/")
        paths.update("/".join(parts[:i]) for i in range(1, len(parts)))
    return frozenset(paths)


def top_level() -> set[str]:
    return {p.split("/")[0] for p in tracked_files()}


def doc_files() -> list[str]:
    return [
        p
        for p in tracked_files()
        if p == "README.md" or re.fullmatch(r"docs/[^/]+\.md", p) or re.fullmatch(r"results/.+/README\.md", p)
    ]


def code_files() -> list[str]:
    return [
        p
        for p in tracked_files()
        if p.split("/")[0] in CODE_DIRS and Path(p).suffix in CODE_SUFFIXES and p != THIS_FILE
    ]


def python_comments_and_docstrings(source: str) -> str:
    parts = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            doc = ast.get_docstring(node, clean=False)
            if doc:
                parts.append(doc)
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type == tokenize.COMMENT:
            parts.append(token.string)
    return "\n".join(parts)


def comments(path: str) -> str:
    """The prose of a code file: docstrings and comments, never code or string values."""
    source = (REPO / path).read_text(encoding="utf-8")
    suffix = Path(path).suffix
    if suffix == ".py":
        return python_comments_and_docstrings(source)
    if suffix == ".cpp":
        return "\n".join(re.findall(r"//[^\n]*|/\*.*?\*/", source, flags=re.DOTALL))
    return "\n".join(line.partition("#")[2] for line in source.splitlines() if "#" in line)


@cache
def prose() -> dict[str, str]:
    """Every doc's text and every code file's comments, by path."""
    texts = {p: (REPO / p).read_text(encoding="utf-8") for p in doc_files()}
    texts.update({p: comments(p) for p in code_files()})
    return texts


def resolves(target: str, base: str) -> bool:
    """``target`` (relative to the directory of ``base``, or ``./``/``../`` from it) is in the checkout."""
    root = REPO.resolve()
    path = ((REPO / base).parent / target).resolve()
    if root != path and root not in path.parents:
        return False
    return path.relative_to(root).as_posix() in tracked_paths() or path == root


def is_repo_path(token: str) -> bool:
    if token.startswith(("./", "../")):
        return True
    return token.split("/")[0] in top_level() and (token.endswith("/") or token.rsplit(".", 1)[-1] in FILE_EXTENSIONS)


def missing_citations(path: str, text: str) -> list[str]:
    problems = []
    for match in MARKDOWN_LINK.finditer(text):
        target = match.group(1).split("#")[0]
        if not target or "://" in target or target.startswith("mailto:"):
            continue
        if not resolves(target, path):
            problems.append(f"{path}: link to {target}, not in the repository")
    for match in PATH_TOKEN.finditer(text):
        token = match.group(1).rstrip(".,;:")
        if not is_repo_path(token) or any(PLACEHOLDER.match(part) for part in token.split("/")):
            continue
        if token.startswith(("./", "../")):
            ok = resolves(token, path)
        else:
            ok = token.rstrip("/") in tracked_paths()
        if not ok:
            problems.append(f"{path}: mentions {token}, not in the repository")
    for match in BARE_DOC.finditer(text):
        name = match.group(1)
        if name in DOC_NAMES:
            ok = f"docs/{name}" in tracked_paths()
        else:
            ok = name in tracked_paths() or resolves(name, path)
        if not ok:
            problems.append(f"{path}: cites {name}, not in the repository")
    for match in FORBIDDEN_PHRASES.finditer(text):
        problems.append(f"{path}: cites {match.group(0)!r}, which is outside the repository")
    return problems


@cache
def doc_sections(name: str) -> tuple[frozenset[str], str]:
    """Section numbers of ``docs/<name>`` (headings ``## n.`` and ``### n.m``) and its text."""
    text = (DOCS / name).read_text(encoding="utf-8")
    numbers = re.findall(r"^#{2,3}\s+(\d+(?:\.\d+)?)[.\s]", text, flags=re.MULTILINE)
    return frozenset(numbers), text


def section_exists(doc: str, number: str) -> bool:
    """``n`` or ``n.m`` is a heading of the doc, or ``m`` is a numbered item of section ``n``."""
    numbers, text = doc_sections(doc)
    if number in numbers:
        return True
    section, _, item = number.partition(".")
    if not item or section not in numbers:
        return False
    body = re.split(rf"^## {section}\.", text, flags=re.MULTILINE)[1]
    body = re.split(r"^## ", body, flags=re.MULTILINE)[0]
    return re.search(rf"^\s*{item}\.\s", body, flags=re.MULTILINE) is not None


def unresolved_labels(path: str, text: str) -> list[str]:
    problems = []
    for match in CITATION.finditer(text):
        doc = f"{match.group(1)}.md"
        for number in filter(None, match.group(2, 3)):
            if not section_exists(doc, number):
                problems.append(f"{path}: '{match.group(0)}' cites {doc} {number}, which has no such section")
    method, protocol = doc_sections("METHOD.md")[1], doc_sections("PROTOCOL.md")[1]
    m_defined = set(re.findall(r"\(M(\d+)\)", method))
    d_defined = set(re.findall(r"^\| D(\d+) \|", protocol, flags=re.MULTILINE))
    problems += [f"{path}: M{n} is not defined in docs/METHOD.md" for n in M_LABEL.findall(text) if n not in m_defined]
    problems += [
        f"{path}: D{n} is not in docs/PROTOCOL.md's table" for n in D_LABEL.findall(text) if n not in d_defined
    ]
    return problems


def diary_labels(path: str, text: str, dates: bool) -> list[str]:
    found = [m.group(0) for m in DIARY.finditer(text)]
    if dates:
        found += [m.group(0) for m in WORK_DATE.finditer(text)]
    return [f"{path}: diary label {label!r}" for label in found]


def test_docs_and_comments_cite_only_files_in_the_repository():
    problems = [p for path, text in prose().items() for p in missing_citations(path, text)]
    assert not problems, "\n".join(problems)


def test_method_and_protocol_citations_land_on_the_shipped_docs():
    problems = [p for path, text in prose().items() for p in unresolved_labels(path, text)]
    assert not problems, "\n".join(problems)


def test_method_defines_every_label_and_protocol_every_disagreement():
    method, protocol = doc_sections("METHOD.md")[1], doc_sections("PROTOCOL.md")[1]
    assert set(re.findall(r"\(M(\d+)\)", method)) == {str(n) for n in range(1, 43)}
    assert set(re.findall(r"^\| D(\d+) \|", protocol, flags=re.MULTILINE)) == {str(n) for n in range(1, 29)}
    assert doc_sections("METHOD.md")[0] >= {str(n) for n in range(1, 22)}


def test_no_work_diary_in_tracked_files():
    problems = []
    for path in tracked_files():
        suffix = Path(path).suffix
        if path == THIS_FILE or suffix in BINARY_SUFFIXES:
            continue
        try:
            text = (REPO / path).read_text(encoding="utf-8")
        except UnicodeDecodeError:
            continue
        problems += diary_labels(path, text, dates=False)
    for path, text in prose().items():  # dates of work in prose; records keep their timestamps
        if Path(path).suffix not in DATA_SUFFIXES:
            problems += diary_labels(path, text, dates=True)
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize(
    "text, kind",
    [
        ("Meshes are in `../shared/assets` for development.", "path"),
        ("The budget table (see DESIGN.md, budgets).", "path"),
        ("measured in docs/NOTES.md.", "path"),
        ("As the project brief says.", "path"),
        ("METHOD 31 has it.", "label"),
        ("(M99) an equation that does not exist", "label"),
        ("PROTOCOL 4.7's metric", "label"),
        ("Session 14 vectorised the kernel.", "diary"),
        ("On that day's machine it ran 1.5x faster.", "diary"),
    ],
)
def test_the_checks_catch_what_they_are_for(text, kind):
    """Each check fails on a line of the kind it exists to catch (from README.md's point of view)."""
    found = {
        "path": missing_citations("README.md", text),
        "label": unresolved_labels("README.md", text),
        "diary": diary_labels("README.md", text, dates=True),
    }
    assert found[kind]
    assert not [problem for other, problems in found.items() if other != kind for problem in problems]
