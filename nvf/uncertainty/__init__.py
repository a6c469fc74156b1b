"""View scorers: NVF's per-pixel entropy, the baselines' per-ray scores (METHOD.md 5-8, 12) and FisherRF's
whole-view information gain (METHOD.md 17, ``nvf.uncertainty.fisher``)."""

from nvf.uncertainty.entropy import H_MIN, gmm_entropy_upper_bound, moment_matched_entropy
from nvf.uncertainty.mixture import RayMixture, mixture_log_density, ray_mixture
from nvf.uncertainty.scorers import StepScorer, ViewScorer, WholeViewScorer

__all__ = [
    "H_MIN",
    "RayMixture",
    "StepScorer",
    "ViewScorer",
    "WholeViewScorer",
    "gmm_entropy_upper_bound",
    "mixture_log_density",
    "moment_matched_entropy",
    "ray_mixture",
]
