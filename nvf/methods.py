"""Next-best-view methods (METHOD.md section 12): a method is its view scorer and, where it has one, the
auxiliary loss it adds to stage 1. One class per method; ``conf/method/<name>.yaml`` names the class by
import path (``implementation``) and holds everything else (table label and order, training stages).

Adding a method is adding a ``Method`` subclass (here or in any importable module) and one yaml file.
"""

import importlib
from typing import ClassVar

from nvf.config import BaselineConfig, EntropyConfig
from nvf.training import AuxLoss, activenerf_loss, neurar_loss
from nvf.uncertainty.baselines import ActiveRMAPScorer, AIRScorer, RenderedVarianceScorer, WDScorer
from nvf.uncertainty.nvf_entropy import NVFEntropyScorer
from nvf.uncertainty.scorers import ViewScorer


class Method:
    """A method with no scorer (the planner then picks uniformly, as Random) and no auxiliary loss.
    ``score_unit``: the unit of its per-pixel score (labels the score map's colour bar)."""

    aux_loss: ClassVar[AuxLoss | None] = None
    score_unit: ClassVar[str] = ""

    def scorer(self, entropy: EntropyConfig, baseline: BaselineConfig, d0: float) -> ViewScorer | None:
        """The per-pixel view scorer (M16 averages it over the planning image); ``d0`` is NVF's resolved
        correlation length (M13), which the baselines ignore."""
        return None


class Random(Method):
    """Uniform choice among unfiltered candidates, stage 1 only (METHOD 12, D25)."""


class WD(Method):
    """Weight-distribution entropy (M22)."""

    score_unit = "nats"  # an entropy

    def scorer(self, entropy: EntropyConfig, baseline: BaselineConfig, d0: float) -> ViewScorer:
        return WDScorer()


class ActiveRMAP(Method):
    """Binary opacity entropy summed along the ray (M23; ``baseline.rmap_occlusion_weighted``)."""

    score_unit = "nats"  # an entropy

    def scorer(self, entropy: EntropyConfig, baseline: BaselineConfig, d0: float) -> ViewScorer:
        return ActiveRMAPScorer(occlusion_weighted=baseline.rmap_occlusion_weighted)


class AIR(Method):
    """Occlusion-aware opacity entropy, mean over the ray's samples (M24; ``baseline.air_reduce``)."""

    score_unit = "nats"  # an entropy

    def scorer(self, entropy: EntropyConfig, baseline: BaselineConfig, d0: float) -> ViewScorer:
        if baseline.air_view_score != "pixel_mean":
            raise NotImplementedError(f"AIR view score {baseline.air_view_score!r}: only pixel_mean is implemented")
        return AIRScorer(reduce=baseline.air_reduce)


class ActiveNeRF(Method):
    """Rendered variance (M26) of a variance head trained in stage 1 on its NLL (M25, variant A)."""

    score_unit = "colour variance"  # of colours in [0, 1]

    aux_loss = staticmethod(activenerf_loss)

    def scorer(self, entropy: EntropyConfig, baseline: BaselineConfig, d0: float) -> ViewScorer:
        if baseline.activenerf_variant != "A":
            raise NotImplementedError(
                f"ActiveNeRF variant {baseline.activenerf_variant!r}: only A (the NVF variance head, M26) is implemented"
            )
        return RenderedVarianceScorer(name="activenerf")


class NeurAR(Method):
    """Rendered variance (M26) of a variance head regressed in stage 1 on the squared residual (M27)."""

    score_unit = "colour variance"  # of colours in [0, 1]

    aux_loss = staticmethod(neurar_loss)

    def scorer(self, entropy: EntropyConfig, baseline: BaselineConfig, d0: float) -> ViewScorer:
        return RenderedVarianceScorer(name="neurar")


class NVF(Method):
    """Neural Visibility Field: the corrected view entropy of the visibility-aware ray mixture (M7-M16)."""

    score_unit = "nats"  # an entropy

    def scorer(self, entropy: EntropyConfig, baseline: BaselineConfig, d0: float) -> ViewScorer:
        return NVFEntropyScorer(entropy, d0)


def load_method(path: str) -> Method:
    """An instance of the ``Method`` subclass at import path ``package.module.Class``; ValueError (one
    line) when it cannot be imported or is not a ``Method``."""
    module_name, _, class_name = path.rpartition(".")
    try:
        cls = getattr(importlib.import_module(module_name), class_name) if module_name else None
    except (ImportError, AttributeError) as err:
        raise ValueError(f"cannot import method class {path!r}: {err}") from None
    if not (isinstance(cls, type) and issubclass(cls, Method)):
        raise ValueError(f"{path!r} is not a subclass of nvf.methods.Method")
    return cls()
