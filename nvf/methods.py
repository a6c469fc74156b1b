"""Next-best-view methods (METHOD.md section 12): a method is its view scorer and, where it has one, the
auxiliary loss it adds to stage 1.

One frozen dataclass per method: its fields are what ``conf/method/<name>.yaml`` declares of the method itself.
Every method has a name and the training stages it needs (``stages``; a method whose score reads the variance or
visibility head trains it there); a subclass adds its own settings as fields, a fixed set of values as a
``Literal``, and checks each value against its field's type when built (``__post_init__``). Fields have no
defaults: the yaml is their one default. The one exception is a field declared with ``run_setting(key)``:
its value is the run's config at ``key`` (NVF's entropy settings, ``nvf.entropy``, which the variance
head's loss reads too), filled in by the pipeline, never set in the yaml. The yaml names the class in
``_target_`` and the pipeline builds it with Hydra's ``instantiate`` (``pipeline.config.method``), so
adding a method is one subclass (here or in any importable module) and one yaml file. How results show a
method (its label, row order and the experiments it joins) is the harness's: the same yaml declares it, but it
is no part of the method.
"""

import dataclasses
import typing
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

from beartype.door import is_bearable

from nvf.config import EntropyConfig
from nvf.cover import CoverScorer
from nvf.coverage import FarthestViewScorer
from nvf.losses import AuxLoss, activenerf_loss, neurar_loss
from nvf.uncertainty.baselines import ActiveRMAPScorer, AIRScorer, RenderedVarianceScorer, WDScorer
from nvf.uncertainty.fisher import FisherRFScorer
from nvf.uncertainty.laplace import BayesRaysScorer
from nvf.uncertainty.nvf_entropy import NVFEntropyScorer
from nvf.uncertainty.scorers import StepScorer, ViewScorer
from nvf.warp_consistency import WarpScorer

RUN_SETTING = "run_setting"  # a field's metadata key: the run config key its value comes from
MAX_PERTURBATION_VERTICES = 1 << 28  # Bayes' Rays' grid (M34): 2 GB of its float64 Hessian diagonal


def run_setting(key: str, default: Callable[[], Any]) -> Any:
    """A method field whose value is the run's config at ``key`` (filled in by the pipeline when it builds the
    run, ``run_settings``); ``default()`` until then."""
    return dataclasses.field(default_factory=default, metadata={RUN_SETTING: key})


def run_settings(cls: type["Method"]) -> dict[str, str]:
    """``cls``'s fields that are run settings: field name -> the run config key they come from."""
    return {f.name: f.metadata[RUN_SETTING] for f in dataclasses.fields(cls) if RUN_SETTING in f.metadata}


@dataclass(frozen=True, kw_only=True)
class Method:
    """A method with no scorer (the planner then picks uniformly, as Random) and no auxiliary loss.

    ``score_unit``: the unit of its per-pixel score (labels the score map's colour bar).
    ``not_implemented``: settings of METHOD 12 named but not implemented, ``field -> (value, recommended)``.
    """

    name: str
    """The method's name (its yaml file's, and its runs' folder's)."""
    stages: list[str]
    """The training stages it needs: a start of ``nvf.config.STAGES``, ``backbone`` first."""

    aux_loss: ClassVar[AuxLoss | None] = None
    score_unit: ClassVar[str] = ""
    not_implemented: ClassVar[dict[str, tuple[Any, Any]]] = {}

    def __post_init__(self) -> None:
        """Each field's value is of its declared type (a ``Literal``'s choices; every item of a list);
        ``TypeError`` naming the field otherwise."""
        hints = typing.get_type_hints(type(self))
        for field in dataclasses.fields(self):
            value, hint = getattr(self, field.name), hints[field.name]
            items = value if isinstance(value, list) else []
            if not is_bearable(value, hint) or not all(is_bearable([item], hint) for item in items):
                raise TypeError(f"{field.name}={value!r} must be {_expected(hint)}")

    def scorer(self) -> ViewScorer | StepScorer | None:
        """The per-pixel view scorer (M16 averages it over the planning image), or a ``StepScorer`` that scores
        whole views once prepared from the step's model (FisherRF); None: the planner picks uniformly."""
        return None

    def unsupported(self) -> str | None:
        """Why these settings cannot run (one line naming the field), or None."""
        for name, (value, recommended) in self.not_implemented.items():
            if getattr(self, name) == value:
                return (
                    f"{name}={value!r} (a METHOD.md section 12 alternative) is not implemented; drop the override "
                    f"to use the recommended {recommended!r}"
                )
        return None


@dataclass(frozen=True, kw_only=True)
class Random(Method):
    """Uniform choice among unfiltered candidates, stage 1 only (METHOD 12, D25)."""


@dataclass(frozen=True, kw_only=True)
class WD(Method):
    """Weight-distribution entropy (M22)."""

    score_unit: ClassVar[str] = "nats"  # an entropy

    def scorer(self) -> ViewScorer:
        return WDScorer()


@dataclass(frozen=True, kw_only=True)
class ActiveRMAP(Method):
    """Binary opacity entropy summed along the ray (M23)."""

    occlusion_weighted: bool
    """M23's alternative: each sample's entropy weighted by its transmittance."""

    score_unit: ClassVar[str] = "nats"  # an entropy

    def scorer(self) -> ViewScorer:
        return ActiveRMAPScorer(occlusion_weighted=self.occlusion_weighted)


@dataclass(frozen=True, kw_only=True)
class AIR(Method):
    """Occlusion-aware opacity entropy, mean over the ray's samples (M24, the recommended variant)."""

    reduce: Literal["mean", "sum"]
    """M24: the mean or the sum over the ray's samples."""
    view_score: Literal["pixel_mean", "topk"]
    """M24: the mean over the planning image's pixels; ``topk`` (the paper's alternative) is not implemented."""

    score_unit: ClassVar[str] = "nats"  # an entropy
    not_implemented: ClassVar[dict[str, tuple[Any, Any]]] = {"view_score": ("topk", "pixel_mean")}

    def scorer(self) -> ViewScorer:
        return AIRScorer(reduce=self.reduce)


@dataclass(frozen=True, kw_only=True)
class ActiveNeRF(Method):
    """Rendered variance (M26) of a variance head trained in stage 1 on its NLL (M25, variant A)."""

    variant: Literal["A", "B"]
    """M25's variant; B is not implemented."""

    score_unit: ClassVar[str] = "colour variance"  # of colours in [0, 1]
    aux_loss: ClassVar[AuxLoss | None] = staticmethod(activenerf_loss)
    not_implemented: ClassVar[dict[str, tuple[Any, Any]]] = {"variant": ("B", "A")}

    def scorer(self) -> ViewScorer:
        return RenderedVarianceScorer(name="activenerf")


@dataclass(frozen=True, kw_only=True)
class NeurAR(Method):
    """Rendered variance (M26) of a variance head regressed in stage 1 on the squared residual (M27)."""

    loss: Literal["residual_mse", "nll"]
    """M27's loss; ``nll`` is not implemented."""
    detach: bool
    """M27's target detached from the backbone; false is not implemented."""

    score_unit: ClassVar[str] = "colour variance"  # of colours in [0, 1]
    aux_loss: ClassVar[AuxLoss | None] = staticmethod(neurar_loss)
    not_implemented: ClassVar[dict[str, tuple[Any, Any]]] = {
        "loss": ("nll", "residual_mse"),
        "detach": (False, True),
    }

    def scorer(self) -> ViewScorer:
        return RenderedVarianceScorer(name="neurar")


@dataclass(frozen=True, kw_only=True)
class NVF(Method):
    """Neural Visibility Field: the corrected view entropy of the visibility-aware ray mixture (M7-M16).
    ``entropy``: its settings, the run's ``nvf.entropy`` with ``d0`` resolved on the scene (M13's correlation
    length, a number), which the variance head's loss (M21) reads too."""

    entropy: EntropyConfig = run_setting("nvf.entropy", lambda: EntropyConfig(d0=1.0))
    """Its view entropy's settings: the run's ``nvf.entropy``, ``d0`` resolved on the scene (a run setting)."""

    score_unit: ClassVar[str] = "nats"  # an entropy

    def scorer(self) -> ViewScorer:
        d0 = self.entropy.d0
        assert isinstance(d0, (int, float)), f"entropy.d0={d0!r} is not resolved"
        return NVFEntropyScorer(self.entropy, float(d0))


@dataclass(frozen=True, kw_only=True)
class FisherRF(Method):
    """FisherRF (Jiang, Lei and Daniilidis, ECCV 2024; not in the NVF paper) on NVF's backbone: a view's
    expected information gain about the backbone's parameters, ``sum_j diag(H_c)_j / (diag(H_D)_j + lambda)``
    (METHOD 17, M30-M32). Stage 1 only; it scores whole views, so argmax planning only (-OPT is n/a)."""

    probes: int
    """K, Rademacher probes per view (M31); docs/BUDGETS.md says why its value."""
    prior_precision: float
    """lambda (M32); FisherRF's code default."""

    def scorer(self) -> StepScorer:
        return FisherRFScorer(self.probes, self.prior_precision)

    def unsupported(self) -> str | None:
        if self.probes < 1:
            return f"probes={self.probes} must be at least 1 (Rademacher probes per view, docs/METHOD.md M31)"
        if not self.prior_precision > 0:
            return f"prior_precision={self.prior_precision} must be > 0 (lambda, docs/METHOD.md M32)"
        return None


@dataclass(frozen=True, kw_only=True)
class FVS(Method):
    """Farthest view sampling (NeRF Director, Xiao et al., CVPR 2024; not in the NVF paper): the candidate
    farthest from every observed view (METHOD 18, M33), no uncertainty; stage 1 only, for the planner's filters
    (M28, M29) and the evaluation. It scores whole views, so argmax planning only (-OPT is n/a)."""

    facing: bool
    """Only views that look at the object's box are farthest-ranked; the others rank below them (M33's facing
    variant: NeRF Director's candidates all look at the object)."""

    score_unit: ClassVar[str] = "radians"  # a view distance

    def scorer(self) -> StepScorer:
        return FarthestViewScorer(facing=self.facing)


@dataclass(frozen=True, kw_only=True)
class BayesRays(Method):
    """Bayes' Rays (Goli et al., CVPR 2024; not in the NVF paper) on NVF's backbone: post-hoc Laplace
    uncertainty of a spatial perturbation field, its diagonal Gauss-Newton Hessian over the training pixels and a
    prior, rendered along the candidate's rays (METHOD 19, M34-M36). Stage 1 only; it scores whole views, so
    argmax planning only (-OPT is n/a). ``cells_per_grid_cell``: the perturbation grid's cells a side per cell
    of the occupancy grid (``grid_resolution``, the run's ``sampler.grid_resolution``), so it scales with the
    budget as the grid does: 2 gives the reference's 256 at the paper's 128^3."""

    cells_per_grid_cell: int
    """The perturbation grid's cells a side per cell of the occupancy grid (M34)."""
    grid_resolution: int = run_setting("sampler.grid_resolution", lambda: 128)
    """The run's ``sampler.grid_resolution`` (a run setting)."""

    score_unit: ClassVar[str] = "scaled log10 deviation"  # M36's rendered uncertainty in [0, 1]

    def scorer(self) -> StepScorer:
        return BayesRaysScorer(self.cells_per_grid_cell * self.grid_resolution)

    def unsupported(self) -> str | None:
        if self.cells_per_grid_cell < 1:
            return f"cells_per_grid_cell={self.cells_per_grid_cell} must be at least 1 (docs/METHOD.md M34)"
        vertices = (self.cells_per_grid_cell * self.grid_resolution + 1) ** 3
        if vertices > MAX_PERTURBATION_VERTICES:
            return (
                f"cells_per_grid_cell={self.cells_per_grid_cell} makes M34's grid {vertices:.2e} vertices at "
                f"sampler.grid_resolution={self.grid_resolution} (at most 2^28, 2 GB of float64 Hessian); lower it"
            )
        return None


@dataclass(frozen=True, kw_only=True)
class COVER(Method):
    """COVER (CVPR 2026; not in the NVF paper) on NVF's backbone: a candidate scores the mean over its pixels of the
    opacity it sees less how closely it looks along a direction the training views saw each surface element from
    (METHOD 20, M37-M39; the elements the occupied cells of the backbone's grid a training view holds). Stage 1
    only; it scores whole views, so argmax planning only (-OPT is n/a)."""

    bins: int
    """Direction bins on the Fibonacci sphere (COVER's ``n_sphere_bins``)."""

    score_unit: ClassVar[str] = "uncovered opacity"  # M39's mean over the pixels, in [0, 1]

    def scorer(self) -> StepScorer:
        return CoverScorer(self.bins)

    def unsupported(self) -> str | None:
        if not 1 <= self.bins <= 4096:
            return f"bins={self.bins} must be 1..4096 (direction bins on the sphere, docs/METHOD.md M37)"
        return None


@dataclass(frozen=True, kw_only=True)
class WarpRF(Method):
    """WarpRF (WACV 2026; not in the NVF paper) on NVF's backbone: a candidate scores the mean over its pixels of the
    smallest colour disagreement between its rendering and a training view's rendering warped into it by its depth
    (METHOD 21, M40-M42). Stage 1 only; it scores whole views, so argmax planning only (-OPT is n/a)."""

    score_unit: ClassVar[str] = "colour L1"  # summed over the channels, colours in [0, 1]

    def scorer(self) -> StepScorer:
        return WarpScorer()


def _expected(hint: Any) -> str:
    if typing.get_origin(hint) is Literal:
        return f"one of {', '.join(map(str, typing.get_args(hint)))}"
    return f"a {getattr(hint, '__name__', str(hint))}"
