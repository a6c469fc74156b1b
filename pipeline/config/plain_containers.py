"""A config node as plain Python: ``as_dict`` and ``as_list`` are ``OmegaConf.to_container`` for a mapping and
a sequence node, typed as the ``dict[str, Any]`` and ``list[Any]`` they are (OmegaConf's own return type covers
both and scalars too)."""

from typing import Any

from omegaconf import DictConfig, ListConfig, OmegaConf


def as_dict(node: Any, resolve: bool = True) -> dict[str, Any]:
    """The mapping node ``node`` (a ``DictConfig``) as a plain dict, interpolations resolved unless
    ``resolve`` is False; a TypeError for a node that is not a mapping."""
    if not isinstance(node, DictConfig):
        raise TypeError(f"expected a mapping config node, got {type(node).__name__}")
    container = OmegaConf.to_container(node, resolve=resolve)
    assert isinstance(container, dict)
    return {str(key): value for key, value in container.items()}


def as_list(node: Any, resolve: bool = True) -> list[Any]:
    """The sequence node ``node`` (a ``ListConfig``) as a plain list, interpolations resolved unless
    ``resolve`` is False; a TypeError for a node that is not a sequence."""
    if not isinstance(node, ListConfig):
        raise TypeError(f"expected a sequence config node, got {type(node).__name__}")
    container = OmegaConf.to_container(node, resolve=resolve)
    assert isinstance(container, list)
    return container
