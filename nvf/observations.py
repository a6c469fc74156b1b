"""The observations of an active-mapping step: every image observed so far, its pose and the shared intrinsics
(METHOD.md section 10), and rays drawn uniformly over their pixels."""

from dataclasses import dataclass

import torch
from jaxtyping import Float, Int
from torch import Tensor

from nvf.cameras import Intrinsics, camera_directions


@dataclass
class Observations:
    """All images observed so far: RGBA in ``[0, 1]`` (RGB zero where alpha = 0), their poses and
    the shared intrinsics. Rays are drawn uniformly over all pixels of all images (section 10)."""

    images: Float[Tensor, "N H W 4"]
    c2w: Float[Tensor, "N 4 4"]
    intrinsics: Intrinsics

    def __post_init__(self) -> None:
        if self.c2w.shape[0] != self.images.shape[0]:
            raise ValueError(f"{self.images.shape[0]} images but {self.c2w.shape[0]} poses")
        if self.images.shape[1:3] != (self.intrinsics.height, self.intrinsics.width):
            raise ValueError(
                f"images are {tuple(self.images.shape[1:3])} (H, W) but the intrinsics are "
                f"{self.intrinsics.height}x{self.intrinsics.width}"
            )

    @property
    def num_images(self) -> int:
        return int(self.images.shape[0])

    def sample_rays(
        self, batch: int, generator: torch.Generator
    ) -> tuple[Float[Tensor, "B 3"], Float[Tensor, "B 3"], Float[Tensor, "B 4"], Int[Tensor, " B"]]:
        """``batch`` pixels drawn uniformly (with replacement) over all pixels of all images:
        world-frame origins, unit directions, the RGBA ground truth and each ray's image index."""
        self.require_images()
        n, h, w = self.images.shape[:3]
        flat = torch.randint(n * h * w, (batch,), generator=generator, device=generator.device)
        flat = flat.to(self.images.device)
        image, pixel = flat // (h * w), flat % (h * w)
        cam_dirs = camera_directions(self.intrinsics, self.images.device)[pixel]
        c2w = self.c2w[image]
        dirs = torch.einsum("bij,bj->bi", c2w[:, :3, :3], cam_dirs)
        dirs = dirs / torch.linalg.norm(dirs, dim=-1, keepdim=True)
        return c2w[:, :3, 3], dirs, self.images.reshape(-1, 4)[flat], image

    def require_images(self) -> None:
        """A ``ValueError`` for an empty training set."""
        if self.num_images == 0:
            raise ValueError("empty training set: no observed images")
