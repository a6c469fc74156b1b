"""NVF's per-pixel view entropy ``H'`` (METHOD.md sections 5-8, M7-M15, ablations section 11)."""

from dataclasses import dataclass
from typing import ClassVar

import torch
from jaxtyping import Float, Int
from torch import Tensor

from nvf.config import EntropyConfig
from nvf.model import RenderResult
from nvf.uncertainty.entropy import (
    TERMS,
    corrected_entropy,
    entropy_floor,
    entropy_terms,
    equivalent_depth,
    mixture_moment_matched_entropy,
    upper_bound_and_depth,
)
from nvf.uncertainty.mixture import checked_variance, checked_visibility, equivalent_weights, ray_mixture

BOUNDS = ("huber", "moment_matched")
CORRELATIONS = ("quadratic", "exp")
DEPTH_MODES = ("pixel", "chunk")
SAMPLERS = ("occupancy", "uniform")


@dataclass(frozen=True)
class NVFEntropyScorer:
    """Per-ray ``alpha -> alpha_bar (M7) -> w_bar (M8) -> mixture (M9) -> H (M10 | M12) -> d (M15)
    -> H' (M13, M14)``.

    ``d0``: the resolved correlation length (``cfg.d0`` is not read here); 0 disables the
    correction (Ind. Rays: ``H' = max(H, H_min)``). Rays without samples get exactly the floor
    ``H_min`` (M11, from ``cfg.var_bg``).
    """

    cfg: EntropyConfig
    d0: float
    name: ClassVar[str] = "nvf"

    def __post_init__(self) -> None:
        for key, allowed in (
            ("bound", BOUNDS),
            ("corr", CORRELATIONS),
            ("depth_mode", DEPTH_MODES),
            ("sampler", SAMPLERS),
        ):
            if getattr(self.cfg, key) not in allowed:
                raise ValueError(f"nvf.entropy.{key}={getattr(self.cfg, key)!r} not in {allowed}")
        if self.d0 < 0:
            raise ValueError(f"d0 must be >= 0 (resolve auto/scene values first), got {self.d0}")

    @property
    def heads(self) -> frozenset[str]:
        """variance and visibility unless ablated, plus rgb (the component means) for the Loose bound
        (M12) only: the component-wise bound (M10) does not depend on the means."""
        used = {
            "rgb": self.cfg.bound == "moment_matched",
            "variance": self.cfg.use_variance,
            "visibility": self.cfg.use_visibility,
        }
        return frozenset(head for head, wanted in used.items() if wanted)

    @property
    def sampler(self) -> str:
        return self.cfg.sampler

    def pixel_scores(self, result: RenderResult, pixel_index: Int[Tensor, " R"] | None = None) -> Float[Tensor, " R"]:
        """``H' [R]`` of each rendered ray (nats).

        The default bound (M10) goes through ``upper_bound_and_depth`` (no packed mixture); the Loose
        bound (M12) through ``ray_mixture``. ``depth_mode=chunk`` recomputes ``d`` per chunk (D3).
        A batch without samples (and no gradient to keep) is the floor ``H_min`` everywhere (M11).
        """
        cfg, samples = self.cfg, result.samples
        visibility = checked_visibility(result.visibility, cfg)
        variance = checked_variance(result.variance, cfg)
        if cfg.depth_mode == "chunk" and pixel_index is None:
            raise ValueError("depth_mode='chunk' needs the rays' row-major pixel_index")
        floor = entropy_floor(cfg.var_bg)
        if samples.num_samples == 0 and not result.alpha.requires_grad:
            return result.alpha.new_full((samples.n_rays,), floor)
        ray_idx, n_rays, t_mid = samples.ray_idx, samples.n_rays, samples.t_mid
        counts = torch.bincount(ray_idx, minlength=n_rays)
        if cfg.bound == "huber":
            eq_weights = equivalent_weights(result.alpha, visibility, ray_idx, counts, cfg)
            entropy, depth = upper_bound_and_depth(eq_weights, visibility, variance, t_mid, ray_idx, n_rays, cfg)
        else:
            assert result.rgb_s is not None, "rendered with the variance head (its per-sample colours)"
            mixture, eq_weights = ray_mixture(
                result.alpha, result.rgb_s, result.variance, result.visibility, ray_idx, n_rays, cfg
            )
            entropy = mixture_moment_matched_entropy(mixture)
        if cfg.bound != "huber" or cfg.depth_mode == "chunk":
            depth = equivalent_depth(eq_weights, t_mid, ray_idx, n_rays, cfg.depth_mode, pixel_index, cfg.chunk_rays)
        scores = corrected_entropy(entropy, depth, self.d0, cfg.corr, floor)
        return torch.where(counts == 0, floor, scores)

    def pixel_terms(
        self, result: RenderResult, pixel_index: Int[Tensor, " R"] | None = None
    ) -> dict[str, Float[Tensor, " R"]]:
        """``H' [R]`` of ``pixel_scores`` split into additive terms (nats):
        ``H' = H_min + seen + unknown + background + mixing + correction``.

        The first four are ``entropy_terms`` of the bound (M10); ``correction`` is what M13-M14 (the
        depth-based correction and the floor) add to ``H``. Only for the component-wise bound
        (``bound=huber``): the Loose bound (M12) has no such split.
        """
        if self.cfg.bound != "huber":
            raise ValueError("pixel_terms needs bound=huber: the moment-matched bound (M12) has no per-component split")
        samples = result.samples
        visibility = checked_visibility(result.visibility, self.cfg)
        variance = checked_variance(result.variance, self.cfg)
        counts = torch.bincount(samples.ray_idx, minlength=samples.n_rays)
        eq_weights = equivalent_weights(result.alpha, visibility, samples.ray_idx, counts, self.cfg)
        terms = entropy_terms(eq_weights, visibility, variance, samples.ray_idx, samples.n_rays, self.cfg)
        bound = entropy_floor(self.cfg.var_bg) + sum(terms[name] for name in TERMS)
        terms["correction"] = self.pixel_scores(result, pixel_index) - bound
        return terms
