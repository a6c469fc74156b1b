"""A run's method from its config node (``conf/method/<name>.yaml``): Hydra's ``instantiate`` builds the
class the node's ``_target_`` names (an ``nvf.methods.Method`` dataclass, which checks each value against
its field's type) from the node's keys but the presentation's (``Presentation``: how results show the method,
which the method library knows nothing of); the method's run settings (``nvf.methods.run_setting``, e.g.
NVF's ``entropy``) are then filled in from the run's config."""

import dataclasses
import logging
import typing
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from beartype.door import is_bearable
from hydra.utils import get_class, instantiate

from nvf.config import STAGES
from nvf.methods import Method, run_settings
from pipeline.cli import BadInput


class MethodError(BadInput, ValueError):
    """A method node that cannot be built; the message is one line naming the key."""


@dataclass(frozen=True)
class Presentation:
    """How results show a method, declared in its yaml beside the method's own keys: harness metadata that the
    tables (``pipeline.tables.labels``) and the experiments' sweeps (``pipeline.config.catalog.members``) read
    from the yaml and the records, never from the built method."""

    label: str
    """The method's row name in tables and figures."""
    rank: int
    """Its row order in tables (the paper's order; smaller first)."""
    experiments: list[str]
    """The paper tables' sweeps (``conf/experiment``) and ``pipeline.experiments.discriminate`` it joins."""


PRESENTATION_KEYS = tuple(f.name for f in dataclasses.fields(Presentation))


def presentation(node: Mapping[str, Any]) -> Presentation:
    """The presentation a method node declares; ``MethodError`` (one line naming the key) for a key that is
    missing or of the wrong type."""
    hints = typing.get_type_hints(Presentation)
    for key in PRESENTATION_KEYS:
        if key not in node:
            raise MethodError(f"method.{key} is missing: every method declares it ({Presentation.__name__})")
        value, hint = node[key], hints[key]
        items = value if isinstance(value, list) else []
        if not is_bearable(value, hint) or not all(is_bearable([item], hint) for item in items):
            raise MethodError(f"method.{key}={value!r} must be a {getattr(hint, '__name__', str(hint))}")
    if not str(node["label"]).strip():
        raise MethodError("method.label is empty: tables and figures name the method's rows by it; give it a label")
    return Presentation(**{key: node[key] for key in PRESENTATION_KEYS})


def method_class(target: Any) -> type[Method]:
    """The ``Method`` subclass at import path ``target`` (``package.module.Class``)."""
    if not isinstance(target, str) or not target:
        raise MethodError("method._target_ is missing: name the method's class, e.g. nvf.methods.NVF")
    quiet = logging.getLogger("hydra.utils")  # Hydra logs its own [ERROR] before raising: the error line says it
    level = quiet.level
    quiet.setLevel(logging.CRITICAL)
    try:
        cls = get_class(target)
    except Exception as err:  # Hydra wraps import and attribute errors alike
        cause = err.__cause__ or err
        raise MethodError(
            f"method._target_: cannot import method class {target!r}: {' '.join(str(cause).split())}"
        ) from None
    finally:
        quiet.setLevel(level)
    if not isinstance(cls, type) or not issubclass(cls, Method):
        raise MethodError(f"method._target_={target!r} is not a subclass of nvf.methods.Method")
    return cls


def key_problem(cls: type[Method], keys: set[str]) -> str | None:
    """The first of ``keys`` that ``cls`` does not declare in its yaml (its fields and the presentation's keys),
    or the first it declares that is missing, as one line; None when they match."""
    from_run = run_settings(cls)
    declared = ({f.name for f in dataclasses.fields(cls)} - set(from_run)) | set(PRESENTATION_KEYS)
    for key in sorted(keys & set(from_run)):
        return f"method.{key} is the run's {from_run[key]}: set {from_run[key]}.* instead of method.{key}"
    unknown = sorted(keys - declared)
    if unknown:
        return (
            f"unknown key 'method.{unknown[0]}': {cls.__name__} has no such setting "
            f"(its keys: {', '.join(sorted(declared))})"
        )
    missing = sorted(declared - keys)
    if missing:
        return f"method.{missing[0]} is missing: {cls.__name__} declares it; set it in the method's yaml"
    return None


def build_method(node: Mapping[str, Any], run: Mapping[str, Any] | None = None) -> Method:
    """The method a config node (a plain mapping) declares, its run settings taken from ``run`` (the run
    config's values by key, e.g. ``{"nvf.entropy": EntropyConfig(...)}``; the class defaults where absent);
    ``MethodError`` (one line) when its class cannot be imported, a key is unknown, missing or of the wrong
    type (the ``Presentation``'s keys included, which the built method does not hold), its stages are not a start
    of ``nvf.config.STAGES``'s order beginning with the backbone, or it asks for an alternative that is not
    implemented."""
    plain = dict(node)
    cls = method_class(plain.get("_target_"))
    problem = key_problem(cls, set(plain) - {"_target_"})
    if problem is not None:
        raise MethodError(problem)
    presentation(plain)  # checked here, read by the tables from the yaml and the records
    plain = {key: value for key, value in plain.items() if key not in PRESENTATION_KEYS}
    from_run = {name: run[key] for name, key in run_settings(cls).items() if run is not None and key in run}
    try:
        method = dataclasses.replace(instantiate(plain, _convert_="all"), **from_run)
    except Exception as err:  # the dataclass's own check of a value (TypeError), wrapped by Hydra
        cause = err.__cause__ or err
        raise MethodError(f"method.{' '.join(str(cause).split())}") from None
    stages = list(method.stages)
    if not stages or stages[0] != "backbone" or any(s not in STAGES for s in stages):
        raise MethodError(f"method.stages={stages} must start with 'backbone' and use only {', '.join(STAGES)}")
    problem = method.unsupported()
    if problem is not None:
        raise MethodError(f"method.{problem}")
    return method
