"""A config node as plain Python: ``as_dict`` is ``OmegaConf.to_container`` for a mapping node, typed as the
``dict[str, Any]`` it is (OmegaConf's own return type covers lists and scalars too)."""

from typing import Any

from omegaconf import DictConfig, OmegaConf


def as_dict(node: Any, resolve: bool = True) -> dict[str, Any]:
    """The mapping node ``node`` (a ``DictConfig``) as a plain dict, interpolations resolved unless
    ``resolve`` is False; a TypeError for a node that is not a mapping."""
    if not isinstance(node, DictConfig):
        raise TypeError(f"expected a mapping config node, got {type(node).__name__}")
    container = OmegaConf.to_container(node, resolve=resolve)
    assert isinstance(container, dict)
    return {str(key): value for key, value in container.items()}
