"""``Run``: one run's composed config as the typed objects everything below the entry points reads: the
schema's sections (``RunConfig``), the method built from its yaml with its run settings filled in
(``nvf.methods``; NVF's ``entropy`` with M13's ``d0`` resolved on the scene), the ``diagnostics.rank_against``
rival, and the composed config as plain data (what a run record stores). An entry point builds it once
(``pipeline.config.validation.validate`` or ``compose_run``)."""

import dataclasses
import functools
from dataclasses import dataclass
from typing import Any

import torch

from nvf.config import EntropyConfig
from nvf.methods import Method
from pipeline.config.structured_configs import RunConfig, SceneConfig


@dataclass(kw_only=True)
class Run(RunConfig):
    """A composed, validated run config. ``method``: the built method; ``rival``: the ``rank_against``
    ablation's name and the method under its settings, or None; ``composed``: the config as plain data
    (interpolations resolved, enums as their names), what ``run.json`` records."""

    method: Method
    rival: tuple[str, Method] | None
    composed: dict[str, Any]

    @property
    def names(self) -> tuple[str, str, str, str, str]:
        """The run's identity keys but the seed: scene, method, planner, ablation and budget names."""
        return self.scene.name, self.method.name, str(self.planner.name), self.ablation.name, self.budget.name

    def setting(self, key: str) -> Any:
        """The value at a dotted config key (``"budget.image_size"``)."""
        return functools.reduce(getattr, key.split("."), self)


def resolved_d0(d0: float | int | str | None, scene: SceneConfig) -> float:
    """(M13) NVF's correlation length: None = the scene's value (1.0, Room 6.0; D4), ``"auto"`` = 0.25 x
    the diagonal of the scene's object box (METHOD 8), a number as given (0 = Ind. Rays)."""
    if d0 is None:
        return float(scene.d0)
    if d0 == "auto":
        box = torch.tensor(scene.object_aabb, dtype=torch.float32)
        return 0.25 * float(torch.linalg.norm(box[1] - box[0]))
    return float(d0)


def resolved_entropy(entropy: EntropyConfig, scene: SceneConfig) -> EntropyConfig:
    """``entropy`` with its ``d0`` resolved on ``scene`` (``resolved_d0``)."""
    return dataclasses.replace(entropy, d0=resolved_d0(entropy.d0, scene))


def run_of(config: RunConfig, method: Method, rival: tuple[str, Method] | None, composed: dict[str, Any]) -> Run:
    """``config``'s sections with the built ``method``, ``rival`` and the ``composed`` plain config."""
    sections = {f.name: getattr(config, f.name) for f in dataclasses.fields(RunConfig) if f.name != "method"}
    return Run(**sections, method=method, rival=rival, composed=composed)
