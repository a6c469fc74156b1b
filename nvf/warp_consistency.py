"""WarpRF (WACV 2026; not in the NVF paper) on NVF's backbone: a training-free uncertainty of a candidate view, the
disagreement between its rendering and the training views' renderings warped into it by its depth
(METHOD.md section 21, M40-M42).

``prepare`` renders every training view from the step's model (the reference warps renderings, not the captured
images) at the training image size. A candidate's rays are rendered (colour and M3's depth), each pixel's surface
point is projected into every training view and that view's rendering is read there (backward warping, M40); a
pixel's uncertainty is its smallest colour disagreement over the training views (M41), and a view's score the mean
over its pixels (M42). As the reference's view selector, no occlusion, in-front or in-frame test is made: a point
outside a training image reads its border.
"""

from dataclasses import dataclass
from typing import ClassVar

import torch
from jaxtyping import Float
from torch import Tensor, nn

from nvf.cameras import Intrinsics, pixel_rays, project
from nvf.observations import Observations
from nvf.seeding import GeneratorFactory

RGB = frozenset({"rgb"})


@torch.no_grad()
def render_image(
    model: nn.Module, c2w: Float[Tensor, "4 4"], intrinsics: Intrinsics, chunk_rays: int
) -> Float[Tensor, "H W 3"]:
    """The model's colour image at ``c2w`` (planning's render: no jitter), in chunks of rays."""
    origins, dirs = pixel_rays(c2w, intrinsics)
    rgb = [
        model.render(origins[s : s + chunk_rays], dirs[s : s + chunk_rays], heads=RGB).rgb  # type: ignore[operator]  # a duck-typed nn.Module's attribute
        for s in range(0, origins.shape[0], chunk_rays)
    ]
    return torch.cat(rgb).reshape(intrinsics.height, intrinsics.width, 3)


def warped(
    points: Float[Tensor, "R 3"], image: Float[Tensor, "H W 3"], c2w: Float[Tensor, "4 4"], intrinsics: Intrinsics
) -> Float[Tensor, "R 3"]:
    """(M40) ``image`` (a training view's rendering) read at the projection of ``points`` into its camera:
    bilinear, a point projecting outside the image reading its border (as the reference samples)."""
    uv, _ = project(points, c2w, intrinsics)
    grid = torch.stack([2.0 * uv[:, 0] / intrinsics.width - 1.0, 2.0 * uv[:, 1] / intrinsics.height - 1.0], dim=-1)
    sampled = nn.functional.grid_sample(
        image.permute(2, 0, 1)[None], grid[None, None], mode="bilinear", padding_mode="border", align_corners=False
    )
    return sampled[0, :, 0].T


def pixel_disagreement(
    colours: Float[Tensor, "R 3"], points: Float[Tensor, "R 3"], views: "WarpedViews"
) -> Float[Tensor, " R"]:
    """(M41) ``U(p) = min_t sum_ch |I_t->c(p) - I_c(p)|``: the candidate's rendered colours against each training
    view's rendering warped to its pixels, the smallest disagreement over the training views."""
    errors = [
        (warped(points, image, c2w, views.intrinsics) - colours).abs().sum(-1)
        for image, c2w in zip(views.images, views.c2w, strict=True)
    ]
    return torch.stack(errors).amin(dim=0)


@dataclass(frozen=True)
class WarpScorer:
    """WarpRF's scorer (a ``StepScorer``): ``prepare`` renders the training views from the step's model."""

    name: ClassVar[str] = "warprf"

    def prepare(
        self, model: nn.Module, observations: Observations, generators: GeneratorFactory, chunk_rays: int
    ) -> "WarpedViews":
        c2w = observations.c2w.to(torch.float32)
        images = torch.stack([render_image(model, pose, observations.intrinsics, chunk_rays) for pose in c2w])
        return WarpedViews(images, c2w, observations.intrinsics)


@dataclass(frozen=True)
class WarpedViews:
    """One step's WarpRF scorer (a ``WholeViewScorer``): the training views' renderings, poses and intrinsics."""

    images: Float[Tensor, "V H W 3"]
    c2w: Float[Tensor, "V 4 4"]
    intrinsics: Intrinsics
    name: ClassVar[str] = "warprf"

    @torch.no_grad()
    def view_score(
        self, model: nn.Module, origins: Float[Tensor, "R 3"], dirs: Float[Tensor, "R 3"], chunk_rays: int
    ) -> Float[Tensor, ""]:
        """(M42) The mean over the view's pixels of ``U(p)`` (M41), each pixel's point ``o + D d`` at M3's depth
        (the camera's centre where its ray meets nothing, as the reference's zero depth)."""
        total = torch.zeros((), dtype=torch.float64, device=origins.device)
        for start in range(0, origins.shape[0], chunk_rays):
            o, d = origins[start : start + chunk_rays], dirs[start : start + chunk_rays]
            result = model.render(o, d, heads=RGB)  # type: ignore[operator]  # a duck-typed nn.Module's attribute
            points = o + result.depth[:, None] * d
            total += pixel_disagreement(result.rgb, points, self).to(torch.float64).sum()
        return total / origins.shape[0]
