"""The scene model: NVF field plus occupancy grid, rendering packed rays (METHOD.md sections 2 and 4)."""

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import torch
from jaxtyping import Bool, Float, Int
from torch import Tensor, nn

from nvf.cameras import Intrinsics, pixel_rays
from nvf.config import FieldConfig, SamplerConfig
from nvf.density_lattice import DensityLattice
from nvf.field import FieldOutput, RadianceField
from nvf.occupancy import OccupancyGrid
from nvf.rendering import Samples, alpha_from_density, expected_depth, ray_sum, weights_from_alpha

SAMPLERS = ("occupancy", "uniform")


class DensitySupport(NamedTuple):
    """Where a model's density can be non-zero: inside ``box`` (min, max) and, with ``grid``, in its occupied
    cells (``SceneModel.density_support``)."""

    box: Float[Tensor, "2 3"]
    grid: OccupancyGrid | None


@dataclass
class RenderResult:
    """Per-sample field values on the kept samples and per-ray composites (M1-M3, black background)."""

    samples: Samples
    sigma: Float[Tensor, " S"]
    alpha: Float[Tensor, " S"]
    weights: Float[Tensor, " S"]
    trans: Float[Tensor, " S"]
    rgb_s: Float[Tensor, "S 3"] | None
    variance: Float[Tensor, "S 3"] | None
    visibility: Float[Tensor, " S"] | None
    rgb: Float[Tensor, "R 3"]
    depth: Float[Tensor, " R"]
    acc: Float[Tensor, " R"]


class SceneModel(nn.Module):
    """``RadianceField`` over the object AABB and its ``OccupancyGrid``."""

    aabb: Tensor

    def __init__(
        self, aabb: Float[Tensor, "2 3"], field_cfg: FieldConfig, sampler_cfg: SamplerConfig, num_images: int = 0
    ):
        super().__init__()
        self.sampler_cfg = sampler_cfg
        self.register_buffer("aabb", aabb.detach().clone().to(torch.float32))
        self.field = RadianceField(self.aabb, field_cfg, num_images)
        self.grid = OccupancyGrid(self.aabb, sampler_cfg)

    def density(self, x: Float[Tensor, "N 3"]) -> Float[Tensor, " N"]:
        """Density as the renderer sees it, for visibility labels (M17) and the planning filters
        (M28, M29): ``sigma(x)``, read as 0 in cells the occupancy grid marks empty when
        ``sampler.mask_density_with_grid`` (default). Such cells are never sampled, so their density
        is never trained: a fresh hash grid starts at ``sigma = exp(0) = 1`` there, a fog that would
        hide every point behind a few scene units of free space (deviation, see docs/DEVIATIONS.md)."""
        if not self.sampler_cfg.mask_density_with_grid:
            return self.field.density(x)[0]
        return self._density_where(x, self.grid.is_occupied(x))

    def label_density(self, lattice: int = 0) -> Callable[[Float[Tensor, "N 3"]], Float[Tensor, " N"]]:
        """The density M17's labels read: :meth:`density` itself (``lattice`` 0), or that density sampled once on
        the lattice ``lattice`` times finer than the grid and read by trilinear interpolation (``DensityLattice``,
        ``train.label_lattice``); for a density that no longer changes."""
        if lattice == 0:
            return self.density
        masked = self.sampler_cfg.mask_density_with_grid
        cells = self.grid.occupied if masked else torch.ones_like(self.grid.occupied)
        return DensityLattice(lambda x: self.field.density(x)[0], self.grid, lattice, cells)

    def density_support(self) -> "DensitySupport":
        """Where :meth:`density` can be non-zero. With ``sampler.mask_density_with_grid``: the occupied cells
        (``grid``) and their bounds grown by half a cell (for rounding) within the AABB (``box``; empty, min
        above max, when no cell is occupied); else the AABB. Visibility labels evaluate only there (M17)."""
        if not self.sampler_cfg.mask_density_with_grid:
            return DensitySupport(self.aabb, None)
        box = self.grid.occupied_box()
        if box is None:
            return DensitySupport(self.aabb.flip(0), self.grid)
        half = 0.5 * self.grid.cell_size
        lo, hi = torch.maximum(box[0] - half, self.aabb[0]), torch.minimum(box[1] + half, self.aabb[1])
        return DensitySupport(torch.stack([lo, hi]), self.grid)

    def observed_density(self, x: Float[Tensor, "N 3"]) -> Float[Tensor, " N"]:
        """:meth:`density`, read as 0 in cells no kept training sample reached (``grid.observed``):
        the line of sight of the collision-free sampler with ``planner.los_unobserved_free``
        (M29 deviation, docs/DEVIATIONS.md)."""
        keep = self.grid.is_observed(x)
        if self.sampler_cfg.mask_density_with_grid:
            keep &= self.grid.is_occupied(x)
        return self._density_where(x, keep)

    def _density_where(self, x: Float[Tensor, "N 3"], keep: Bool[Tensor, " N"]) -> Float[Tensor, " N"]:
        """``sigma(x)`` where ``keep``, 0 elsewhere; only the kept points are evaluated."""
        idx = keep.nonzero().squeeze(1)
        sigma = torch.zeros(x.shape[0], dtype=x.dtype, device=x.device)
        if idx.numel() == 0:
            return sigma
        return sigma.index_put((idx,), self.field.density(x[idx])[0].to(x.dtype))

    def update_grid(self, iteration: int, generator: torch.Generator | None = None) -> None:
        """(M5) ``grid.update`` with the field's density; a no-op unless ``iteration % update_every == 0``."""
        self.grid.update(iteration, lambda x: self.field.density(x)[0], generator)

    def _uniform_samples(
        self, origins: Float[Tensor, "R 3"], jitter: bool, generator: torch.Generator | None
    ) -> Samples:
        """``uniform_samples`` stratified intervals on ``[0, uniform_far]`` (section 4, entropy option).

        Without jitter the bins are the fixed partition (sample at the bin midpoints); with jitter each
        bin edge moves uniformly between its neighbouring bin centres (nerfstudio's stratified sampler).
        """
        cfg = self.sampler_cfg
        n_rays, n, device = origins.shape[0], cfg.uniform_samples, origins.device
        edges = torch.linspace(0.0, cfg.uniform_far, n + 1, device=device).expand(n_rays, n + 1)
        if jitter:
            centres = 0.5 * (edges[:, 1:] + edges[:, :-1])
            lower = torch.cat([edges[:, :1], centres], dim=-1)
            upper = torch.cat([centres, edges[:, -1:]], dim=-1)
            u = torch.rand((n_rays, n + 1), generator=generator, device=device)
            edges = lower + (upper - lower) * u
        ray_idx = torch.arange(n_rays, device=device).repeat_interleave(n)
        return Samples(ray_idx, edges[:, :-1].reshape(-1), edges[:, 1:].reshape(-1), n_rays)

    @torch.no_grad()
    def _skip(
        self, samples: Samples, origins: Float[Tensor, "R 3"], dirs: Float[Tensor, "R 3"], for_autograd: bool
    ) -> tuple[Samples, FieldOutput | None, Float[Tensor, "K E"] | None]:
        """Section 4: drop samples with ``alpha < min(alpha_threshold, mean(occ))`` and those after the
        ray's transmittance (over all marched samples) falls below ``early_stop_eps``. Returns the
        kept samples and what the field's forward reuses for them (no gradient): their encoding if
        ``for_autograd`` (the density MLP must rerun), else their density and geometry features."""
        cfg = self.sampler_cfg
        sigma, geo, encoded = self.field.density_and_encoding(samples.positions(origins, dirs))
        alpha = alpha_from_density(sigma, samples.deltas)
        _, trans = weights_from_alpha(alpha, samples.ray_idx, samples.n_rays)
        keep = (alpha >= min(cfg.alpha_threshold, self.grid.mean_occupancy)) & (trans >= cfg.early_stop_eps)
        if for_autograd:
            return samples.select(keep), None, encoded[keep]
        return samples.select(keep), FieldOutput(sigma=sigma[keep], geo=geo[keep]), None

    def render(
        self,
        origins: Float[Tensor, "R 3"],
        dirs: Float[Tensor, "R 3"],
        heads: frozenset[str] = frozenset({"rgb"}),
        train: bool = False,
        generator: torch.Generator | None = None,
        sampler: str = "occupancy",
        image_idx: Int[Tensor, " R"] | None = None,
        displacement: Callable[[Tensor], Tensor] | None = None,
    ) -> RenderResult:
        """Render rays ``o + t d`` (unit ``d``): sample, then M1-M3 on the kept samples.

        ``sampler="occupancy"``: grid marching (M6), jittered if ``train`` or ``inference_jitter``, then
        alpha skipping and early stop (section 4). ``sampler="uniform"``: stratified samples on
        ``[0, uniform_far]`` (jittered only if ``train``), no skipping. Positions ``o + t_m d`` carry
        gradients into ``origins`` and ``dirs`` (-OPT); ``t`` never does. ``rgb`` is zero if the
        ``rgb`` head is not requested. ``image_idx``: each ray's training image, for the appearance
        embedding (D8; ``None`` = image 0's). The skipping pass's results are reused for the kept samples:
        without autograd (``torch.no_grad``) their density and geometry features, with autograd their
        encoding (whose forward is then skipped; the density MLP reruns for its gradients).
        ``displacement``: maps the kept samples' positions ``[S, 3]`` to where the field reads them (Bayes' Rays'
        perturbation, M34: the positions plus a zero offset whose gradient is wanted); the values must be the
        positions' own (the reused density or encoding is theirs).
        """
        density = encoded = None  # reused from the skipping pass: density without autograd, else encoding
        if sampler == "occupancy":
            jitter = train or self.sampler_cfg.inference_jitter
            samples = self.grid.march(origins, dirs, jitter=jitter, generator=generator)
            samples, density, encoded = self._skip(
                samples, origins.detach(), dirs.detach(), for_autograd=torch.is_grad_enabled()
            )
        elif sampler == "uniform":
            samples = self._uniform_samples(origins, train, generator)
        else:
            raise ValueError(f"unknown sampler {sampler!r}; expected one of {SAMPLERS}")
        n_rays = samples.n_rays
        sample_image = None if image_idx is None else image_idx[samples.ray_idx]
        positions = samples.positions(origins, dirs)
        if displacement is not None:
            positions = displacement(positions)
        out = self.field(positions, dirs[samples.ray_idx], heads, sample_image, density=density, encoded=encoded)
        alpha = alpha_from_density(out.sigma, samples.deltas)
        weights, trans = weights_from_alpha(alpha, samples.ray_idx, n_rays)
        if out.rgb is None:
            rgb = torch.zeros((n_rays, 3), dtype=weights.dtype, device=weights.device)
        else:
            rgb = ray_sum(weights[:, None] * out.rgb, samples.ray_idx, n_rays)
        return RenderResult(
            samples=samples,
            sigma=out.sigma,
            alpha=alpha,
            weights=weights,
            trans=trans,
            rgb_s=out.rgb,
            variance=out.variance,
            visibility=out.visibility,
            rgb=rgb,
            depth=expected_depth(weights, samples.t_mid, samples.ray_idx, n_rays),
            acc=ray_sum(weights, samples.ray_idx, n_rays),
        )

    @torch.no_grad()
    def render_image(
        self,
        c2w: Float[Tensor, "4 4"],
        intr: Intrinsics,
        heads: frozenset[str] = frozenset({"rgb"}),
        chunk: int = 4096,
    ) -> dict[str, Tensor]:
        """Deterministic (``train=False``) render of a whole image in row-major ray chunks.

        Returns ``rgb [H,W,3]``, ``depth [H,W]`` and ``acc [H,W]``.
        """
        origins, dirs = pixel_rays(c2w.to(self.aabb.device, torch.float32), intr)
        parts: dict[str, list[Tensor]] = {"rgb": [], "depth": [], "acc": []}
        for start in range(0, origins.shape[0], chunk):
            result = self.render(origins[start : start + chunk], dirs[start : start + chunk], heads=heads)
            parts["rgb"].append(result.rgb)
            parts["depth"].append(result.depth)
            parts["acc"].append(result.acc)
        shape = (intr.height, intr.width)
        return {key: torch.cat(value).reshape(*shape, *value[0].shape[1:]) for key, value in parts.items()}
