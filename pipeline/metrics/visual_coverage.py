"""Visual coverage, Vis. (PROTOCOL.md 4.3): the fraction of ground-truth mesh faces hit by a pixel-centre
ray of some observed pose (a face count), and the area-weighted fraction (logged only)."""

from dataclasses import dataclass

import numpy as np
import trimesh
from jaxtyping import Bool, Int

from pipeline.metrics.arrays import Array, as_numpy


def seen_faces(face_ids: Int[Array, "*views H W"], num_faces: int) -> Bool[np.ndarray, " F"]:
    """Mask of the faces hit by at least one pixel of the face-id images (-1 = miss) (4.3)."""
    ids = as_numpy(face_ids).ravel()
    seen = np.zeros(num_faces, dtype=bool)
    seen[ids[ids >= 0]] = True
    return seen


@dataclass(frozen=True)
class Coverage:
    """Vis. (fraction of faces seen) and the area-weighted fraction ``vis_area`` (logged only)."""

    vis: float
    vis_area: float


def visual_coverage(seen: Bool[np.ndarray, " F"], mesh: trimesh.Trimesh) -> Coverage:
    """Vis. = |seen faces| / |faces| and the seen fraction of the surface area (4.3).

    ``seen`` is the union over all observed poses, e.g. ``seen_faces(...) | seen_faces(...)``.
    """
    if len(seen) != len(mesh.faces):
        raise ValueError(f"seen mask has {len(seen)} entries, the mesh has {len(mesh.faces)} faces")
    areas = np.asarray(mesh.area_faces, dtype=np.float64)
    return Coverage(vis=float(seen.mean()), vis_area=float(areas[seen].sum() / areas.sum()))
