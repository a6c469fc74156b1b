"""View scorers: NVF's per-pixel entropy and the baselines' per-ray scores (METHOD.md 5-8, 12)."""

from nvf.uncertainty.entropy import H_MIN, gmm_entropy_upper_bound, moment_matched_entropy
from nvf.uncertainty.mixture import RayMixture, mixture_log_density, ray_mixture
from nvf.uncertainty.scorers import ViewScorer

__all__ = [
    "H_MIN",
    "RayMixture",
    "ViewScorer",
    "gmm_entropy_upper_bound",
    "mixture_log_density",
    "moment_matched_entropy",
    "ray_mixture",
]
