"""Every code name a doc puts in backticks exists in the code: docs/*.md and README.md name functions,
classes, modules, config keys and settings, and a rename that leaves a doc behind fails here.

What counts as a code name (anything else in backticks, such as maths or shell lines, is prose):
- ``name(...)`` (a name of 4 characters or more, not one of Hydra's sweep functions): a function or class
  defined in nvf/ or pipeline/;
- ``nvf.x.y`` / ``pipeline.x.y`` (optionally ``=value``): a config key of the composed config, or a module
  (and names defined in it);
- ``key.sub=value`` whose first part is a config group or top-level key: that config key;
- ``CamelCase`` and ``Class.attr``: a class or name defined in the code;
- ``snake_case`` names of 8 characters or more: an identifier or config key used in the code.
"""

import ast
import io
import re
import tokenize
from functools import cache
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from pipeline.config.structured_configs import register_configs

REPO = Path(__file__).resolve().parents[1]
DOCS = sorted((REPO / "docs").glob("*.md")) + [REPO / "README.md"]
PACKAGES = ("nvf", "pipeline")

BACKTICKED = re.compile(r"`([^`\n]+)`")
CALL = re.compile(r"^([A-Za-z_][\w.]*)\([^()]*\)$")
DOTTED = re.compile(r"^([a-z_][\w]*(?:\.[\w]+)+)(?:=\S*)?$")
CAMEL = re.compile(r"^([A-Z][a-z0-9]+[A-Z]\w*)(?:\.(\w+))?$")
SNAKE = re.compile(r"^[a-z][a-z0-9]*(?:_[a-z0-9]+)+$")
FILE_NAME = re.compile(r"\.(?:py|yaml|md|json|jsonl|csv|tex|png|txt|toml|sh|cpp|blend|glb|ply|obj|gltf)$")
# names of other projects' code that the docs cite as theirs
EXTERNAL = {"DynamicBatchPipeline": "nerfstudio", "use_uniform": "NVF's reference code"}
SWEEP_FUNCTIONS = {"glob", "range", "choice", "interval", "tag", "sort", "shuffle"}  # Hydra's override grammar


@cache
def python_files() -> tuple[Path, ...]:
    return tuple(sorted(p for package in PACKAGES for p in (REPO / package).rglob("*.py")))


@cache
def defined_names() -> frozenset[str]:
    """Functions, classes, assigned names and dataclass fields defined anywhere in nvf/ and pipeline/."""
    names: set[str] = set()
    for path in python_files():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                names.add(node.name)
            elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
                names.add(node.id)
            elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
                names.add(node.target.id)
            elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
                names.add(node.attr)
    return frozenset(names)


@cache
def config_keys() -> frozenset[str]:
    """Every dotted key of the composed config, over every method, ablation and budget (a method's own
    settings exist only when it is chosen), and every config group's name."""
    keys: set[str] = set()

    def walk(prefix: str, node: object) -> None:
        if isinstance(node, dict):
            for key, value in node.items():
                dotted = f"{prefix}.{key}" if prefix else str(key)
                keys.add(dotted)
                walk(dotted, value)

    conf = REPO / "conf"
    groups = {path.name: sorted(p.stem for p in path.glob("*.yaml")) for path in conf.iterdir() if path.is_dir()}
    choices = [f"method={m}" for m in groups["method"]] + [f"budget={b}" for b in groups["budget"]]
    register_configs()
    with initialize_config_dir(config_dir=str(conf), version_base="1.3"):
        for choice in choices:
            config = compose(config_name="config", overrides=[choice])
            walk("", OmegaConf.to_container(config, resolve=False))
    return frozenset(keys | set(groups))


@cache
def identifiers() -> frozenset[str]:
    """Every NAME token and every word inside string constants of nvf/, pipeline/ and scripts/, and the
    config keys' parts."""
    words: set[str] = set()
    for path in python_files() + tuple((REPO / "scripts").rglob("*.py")):
        for token in tokenize.generate_tokens(io.StringIO(path.read_text()).readline):
            if token.type == tokenize.NAME:
                words.add(token.string)
            elif token.type == tokenize.STRING:
                words.update(re.findall(r"\w+", token.string))
    for key in config_keys():
        words.update(key.split("."))
    return frozenset(words)


def module_exists(dotted: str) -> bool:
    """``pipeline.bench`` or ``nvf.methods.NVF``: the longest module prefix exists and every further part is
    a name defined in the code."""
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        base = REPO.joinpath(*parts[:cut])
        if base.with_suffix(".py").is_file() or (base / "__init__.py").is_file():
            return all(part in defined_names() for part in parts[cut:])
    return False


def missing(token: str) -> str | None:
    """Why a backticked token names no code, or None when it does (or is not a code name)."""
    if token in EXTERNAL:
        return None
    if FILE_NAME.search(token):
        return None  # a file: tests/test_docs.py checks those
    if call := CALL.match(token):
        name = call.group(1).split(".")[-1]
        if len(name) < 4 or name in SWEEP_FUNCTIONS:
            return None  # maths (`F(x)`, `R_z(θ)`) or Hydra's sweep syntax
        return None if name in defined_names() else f"{token}: no function or class {name!r}"
    if dotted := DOTTED.match(token):
        key = dotted.group(1)
        first = key.split(".")[0]
        if key in config_keys() or (first in PACKAGES and module_exists(key)):
            return None
        if first in PACKAGES or first in {k.split(".")[0] for k in config_keys()}:
            return f"{token}: neither a config key nor a module"
        return None
    if camel := CAMEL.match(token):
        names = [n for n in camel.groups() if n]
        absent = [n for n in names if n not in defined_names()]
        return f"{token}: {', '.join(absent)} not defined in nvf/ or pipeline/" if absent else None
    if SNAKE.match(token) and len(token) >= 8:
        return None if token in identifiers() else f"{token}: no such identifier in the code or conf/"
    return None


def doc_tokens() -> list[tuple[str, str]]:
    return [
        (path.relative_to(REPO).as_posix(), token)
        for path in DOCS
        for token in dict.fromkeys(BACKTICKED.findall(path.read_text()))
    ]


def test_every_code_name_in_the_docs_exists():
    problems = [f"{doc}: `{why}`" for doc, token in doc_tokens() if (why := missing(token))]
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize(
    "token",
    ["make_scorer(cfg)", "pipeline.no_such_module", "nvf.entropy.no_such_key=1", "NoSuchClass", "no_such_identifier"],
)
def test_the_check_catches_a_missing_name(token):
    assert missing(token) is not None


@pytest.mark.parametrize(
    "token",
    [
        "train_backbone(model, views)",
        "pipeline.bench",
        "nvf.entropy.logdet_coeff=1.0",
        "RunRecord",
        "label_margin",
        "z_i",
    ],
)
def test_the_check_accepts_names_that_exist(token):
    assert missing(token) is None
