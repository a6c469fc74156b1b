"""``python -m pipeline.run --help-keys [overrides]``: every config key of a run, dotted, with its default and its
one-line description, read from the config dataclasses themselves: each field's docstring (the string literal on
the line after it, ``pipeline.config.structured_configs`` and ``nvf.config``; a method's keys from its
``nvf.methods`` class and ``pipeline.config.method.Presentation``). Where the composed config (``conf/config.yaml``
with the overrides given) sets another value than the default, the listing adds it: ``[run: 64]``.

A section (a field that is itself a dataclass, ``train.backbone``) is listed with its description before its
keys. A method's keys are those of the method the overrides choose (``method=air``), its run settings (filled
from the run's config, e.g. NVF's ``entropy`` from ``nvf.entropy``) aside.
"""

import ast
import dataclasses
import enum
import inspect
import json
import textwrap
import typing
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

from hydra import compose, initialize_config_dir
from omegaconf import MISSING, OmegaConf

from pipeline.cli import plain
from pipeline.config.structured_configs import RunConfig, register_configs
from pipeline.repo import CONF

NOT_SET = "???"  # a default a yaml must set (OmegaConf's MISSING)


@dataclass(frozen=True)
class KeyHelp:
    """One listed key: ``key`` (dotted), its ``default`` as text (empty for a section), its ``doc`` (one line) and
    whether it is a ``section`` (a dataclass whose keys follow)."""

    key: str
    default: str
    doc: str
    section: bool = False


def field_docs(cls: type, markup: Callable[[str], str] = plain) -> dict[str, str]:
    """Each field's docstring in ``cls`` and its bases (the string literal right after the field's line), as one
    line with its ````code```` marks as ``markup`` writes them (dropped); a field without one is absent."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if klass is object or not dataclasses.is_dataclass(klass):
            continue
        tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        body = next(node for node in tree.body if isinstance(node, ast.ClassDef)).body
        for statement, after in zip(body, body[1:], strict=False):
            if (
                isinstance(statement, ast.AnnAssign)
                and isinstance(statement.target, ast.Name)
                and isinstance(after, ast.Expr)
                and isinstance(after.value, ast.Constant)
                and isinstance(after.value.value, str)
            ):
                docs[statement.target.id] = " ".join(markup(after.value.value).split())
    return docs


def value_text(value: Any) -> str:
    """A value as the command line writes it: ``true``, ``null``, an enum member's name, a list as JSON."""
    if isinstance(value, enum.Enum):
        return str(value.value)
    if value is MISSING or value == MISSING:
        return NOT_SET
    if isinstance(value, bool) or value is None:
        return json.dumps(value)
    if isinstance(value, (list, dict)):
        return json.dumps(value, default=value_text)
    return str(value)


def _default(field: dataclasses.Field) -> Any:
    if field.default is not dataclasses.MISSING:
        return field.default
    if field.default_factory is not dataclasses.MISSING:
        return field.default_factory()
    return MISSING


def dataclass_keys(cls: type, instance: Any, prefix: str) -> Iterator[KeyHelp]:
    """The keys of dataclass ``cls`` under ``prefix``, defaults from ``instance`` (None: the fields' own), its
    dataclass fields as sections followed by their keys."""
    hints = typing.get_type_hints(cls)
    docs = field_docs(cls)
    for field in dataclasses.fields(cls):
        key = f"{prefix}{field.name}"
        default = getattr(instance, field.name) if instance is not None else _default(field)
        hint = hints[field.name]
        if dataclasses.is_dataclass(hint) and isinstance(hint, type):
            yield KeyHelp(key, "", docs.get(field.name, ""), section=True)
            yield from dataclass_keys(hint, default if dataclasses.is_dataclass(default) else None, f"{key}.")
        else:
            allowed = field.metadata.get("range")
            doc = docs.get(field.name, "") + (f" Values: {allowed.text()}." if allowed is not None else "")
            yield KeyHelp(key, value_text(default), doc.strip())


def method_keys(node: dict[str, Any]) -> list[KeyHelp]:
    """A composed method node's keys (``method.<key>``), described by its class's field docstrings and the
    ``Presentation``'s; its run settings are not keys of the node."""
    from nvf.methods import run_settings  # the method library (torch) only where a method is listed
    from pipeline.config.method import Presentation, method_class

    cls = method_class(node.get("_target_"))
    docs = field_docs(Presentation) | field_docs(cls)
    keys = [KeyHelp("method._target_", value_text(node.get("_target_")), "The method's class (its import path).")]
    names = [f.name for f in dataclasses.fields(cls) if f.name not in run_settings(cls)]
    names += [f.name for f in dataclasses.fields(Presentation)]
    return keys + [KeyHelp(f"method.{name}", value_text(node.get(name, MISSING)), docs.get(name, "")) for name in names]


def composed(overrides: list[str]) -> dict[str, Any]:
    """``conf/config.yaml`` with ``overrides``, as plain data (interpolations resolved)."""
    register_configs()
    with initialize_config_dir(str(CONF), version_base="1.3"):
        cfg = compose("config", overrides=overrides)
    container = OmegaConf.to_container(cfg, resolve=True)
    assert isinstance(container, dict)
    return {str(key): value for key, value in container.items()}


def _at(config: dict[str, Any], key: str) -> Any:
    node: Any = config
    for part in key.split("."):
        if not isinstance(node, dict) or part not in node:
            return MISSING
        node = node[part]
    return node


def config_keys(overrides: list[str] | None = None) -> list[tuple[KeyHelp, str | None]]:
    """Every key of the run ``overrides`` compose (``conf/config.yaml``'s defaults when None: a cpu-budget NVF
    run) with the composed value where it differs from the default, else None."""
    config = composed(overrides or [])
    rows: list[tuple[KeyHelp, str | None]] = []
    for item in dataclass_keys(RunConfig, None, ""):
        if item.key == "method":
            rows.append((KeyHelp("method", "", item.doc, section=True), None))
            rows += [(key, None) for key in method_keys(config.get("method") or {})]
            continue
        value = None if item.section else value_text(_at(config, item.key))
        rows.append((item, value if value is not None and value != item.default else None))
    return rows


def listing(overrides: list[str] | None = None) -> str:
    """The ``--help-keys`` page."""
    rows = config_keys(overrides)
    width = max(len(item.key) for item, _ in rows)
    dwidth = min(max(len(item.default) for item, _ in rows), 24)
    lines = [
        "usage: python -m pipeline.run [--help-keys] [overrides]   (overrides: key=value, group=option)",
        "",
        "Every config key of a run: its default (the schema's, the paper budget's), what it does and, in brackets,",
        f"the value this run would use where it differs ({' '.join(overrides) if overrides else 'conf/config.yaml'}).",
        "",
    ]
    for item, value in rows:
        if item.section:
            lines.append(f"{item.key + ':':<{width + dwidth + 4}}  {item.doc}")
            continue
        run = f"  [run: {value}]" if value is not None else ""
        lines.append(f"  {item.key:<{width}}  {item.default:<{dwidth}}  {item.doc}{run}")
    return "\n".join(lines)


def main(overrides: list[str]) -> None:
    print(listing(overrides))
