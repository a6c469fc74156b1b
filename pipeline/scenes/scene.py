"""What a scene is (PROTOCOL.md 2): its mesh in the Z-up scene frame, boxes, views and constants, as an
episode observes it; and the one-line error of a scene that cannot be built. ``pipeline.scenes.loading``
builds scenes from their yaml declarations."""

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from jaxtyping import Float
from torch import Tensor

from pipeline.cli import BadInput
from pipeline.records.schema import SceneSource


class SceneError(BadInput):
    """A scene cannot be built (unknown name, missing, unreadable or degenerate asset); one-line message."""


@dataclass(frozen=True, eq=False)
class Scene:
    """One benchmark scene (PROTOCOL.md 2): mesh in the Z-up scene frame, boxes, views and constants.

    ``asset`` is the file the ground truth comes from (None for proxies and the procedural default);
    ``asset_to_scene`` the similarity that placed its triangles in the scene frame (for a .blend, the
    Blender backend moves the cameras by its inverse instead)."""

    name: str
    source: SceneSource
    mesh: trimesh.Trimesh
    object_aabb: Float[Tensor, "2 3"]
    camera_box: Float[Tensor, "2 3"]
    tight_box: Float[Tensor, "2 3"]
    init_poses: Float[Tensor, "n 4 4"]  # c2w, OpenGL axes
    eval_poses: Float[Tensor, "e 4 4"]  # the 20 of PROTOCOL 2.4 (a benchmark may keep fewer: paper_shape)
    density_threshold: float  # tau (M28)
    d0: float  # M13
    cr_threshold: float  # C.R. distance (PROTOCOL 4.2)
    collision_free: bool  # M29 candidate sampler (Room)
    asset: Path | None = None
    asset_to_scene: Float[np.ndarray, "4 4"] | None = None
    declared_files: tuple[str, ...] = ()  # the scene yaml's ``files`` (paths under the assets directory)

    @property
    def n_init(self) -> int:
        return int(self.init_poses.shape[0])
