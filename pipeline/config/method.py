"""A run's method from its config node (``conf/method/<name>.yaml``): Hydra's ``instantiate`` builds the
class the node's ``_target_`` names (an ``nvf.methods.Method`` dataclass) from the node's other keys, after
each key is checked against the field it sets (its type; a ``Literal`` field's choices)."""

import dataclasses
import typing
from collections.abc import Mapping
from typing import Any, Literal

from beartype.door import is_bearable
from hydra.utils import get_class, instantiate
from omegaconf import DictConfig

from nvf.config import STAGES
from nvf.methods import Method
from pipeline.cli import BadInput
from pipeline.config.plain import as_dict


class MethodError(BadInput, ValueError):
    """A method node that cannot be built; the message is one line naming the key."""


def method_class(target: Any) -> type[Method]:
    """The ``Method`` subclass at import path ``target`` (``package.module.Class``)."""
    if not isinstance(target, str) or not target:
        raise MethodError("method._target_ is missing: name the method's class, e.g. nvf.methods.NVF")
    try:
        cls = get_class(target)
    except Exception as err:  # Hydra wraps import and attribute errors alike
        cause = err.__cause__ or err
        raise MethodError(
            f"method._target_: cannot import method class {target!r}: {' '.join(str(cause).split())}"
        ) from None
    if not issubclass(cls, Method):
        raise MethodError(f"method._target_={target!r} is not a subclass of nvf.methods.Method")
    return cls


def _expected(hint: Any) -> str:
    if typing.get_origin(hint) is Literal:
        return f"one of {', '.join(map(str, typing.get_args(hint)))}"
    return f"a {getattr(hint, '__name__', str(hint))}"


def field_problem(cls: type[Method], values: Mapping[str, Any]) -> str | None:
    """The first key of ``values`` that ``cls`` does not declare, lacks, or whose value its field's type
    refuses, as one line; None when every field is set to a value of its type."""
    fields = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - fields)
    if unknown:
        keys = ", ".join(sorted(fields))
        return f"unknown key 'method.{unknown[0]}': {cls.__name__} has no such setting (its keys: {keys})"
    missing = sorted(fields - set(values))
    if missing:
        return f"method.{missing[0]} is missing: {cls.__name__} declares it; set it in the method's yaml"
    hints = typing.get_type_hints(cls)
    for name in sorted(fields):
        value, hint = values[name], hints[name]
        if not is_bearable(value, hint) or (isinstance(value, list) and not all(is_bearable([v], hint) for v in value)):
            return f"method.{name}={value!r} must be {_expected(hint)}"
    return None


def build_method(node: DictConfig | Mapping[str, Any]) -> Method:
    """The method a config node declares; ``MethodError`` (one line) when its class cannot be imported, a
    key is unknown, missing or of the wrong type, its stages are not a start of ``nvf.config.STAGES``'s
    order beginning with the backbone, or it asks for an alternative that is not implemented."""
    plain: dict[str, Any] = as_dict(node) if isinstance(node, DictConfig) else dict(node)
    cls = method_class(plain.get("_target_"))
    values = {key: value for key, value in plain.items() if key != "_target_"}
    problem = field_problem(cls, values)
    if problem is not None:
        raise MethodError(problem)
    stages = list(values["stages"])
    if not stages or stages[0] != "backbone" or any(s not in STAGES for s in stages):
        raise MethodError(f"method.stages={stages} must start with 'backbone' and use only {', '.join(STAGES)}")
    method = instantiate(plain, _convert_="all")
    problem = method.unsupported()
    if problem is not None:
        raise MethodError(f"method.{problem}")
    return method
