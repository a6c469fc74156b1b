"""Geometry metrics (PROTOCOL.md 4.2): reconstructed points from the model's depth, and Acc., Comp. and
C.R. against area-uniform samples of the ground-truth mesh (points ``[P, 3]`` in scene units)."""

import math
from dataclasses import dataclass

import numpy as np
import open3d as o3d
import trimesh
from jaxtyping import Float
from scipy.spatial import cKDTree

from pipeline.metrics.arrays import Array, as_numpy


def points_from_rays(
    origins: Float[Array, "R 3"],
    dirs: Float[Array, "R 3"],
    depth: Float[Array, " R"],
    acc: Float[Array, " R"],
    min_acc: float = 0.5,
) -> Float[Array, "P 3"]:
    """Reconstructed points ``o + D d`` of the rays with accumulation ``A > min_acc`` (4.2, M3)."""
    keep = acc > min_acc
    return origins[keep] + depth[keep][:, None] * dirs[keep]


def sample_surface(mesh: trimesh.Trimesh, count: int, seed: int) -> Float[np.ndarray, "N 3"]:
    """``count`` area-uniform samples of the mesh surface, reproducible from ``seed`` (4.2)."""
    points, _ = trimesh.sample.sample_surface(mesh, count, seed=seed)
    return np.asarray(points, dtype=np.float64)


def remove_statistical_outliers(
    points: Float[Array, "P 3"], neighbors: int = 20, std_ratio: float = 10.0
) -> Float[np.ndarray, "M 3"]:
    """Drop points whose mean distance to their ``neighbors`` nearest points exceeds the global
    mean + ``std_ratio`` std of that quantity (open3d ``remove_statistical_outlier``, 4.2)."""
    pts = np.ascontiguousarray(as_numpy(points), dtype=np.float64)
    if len(pts) == 0:
        return pts.reshape(0, 3)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    _, kept = cloud.remove_statistical_outlier(nb_neighbors=neighbors, std_ratio=std_ratio)
    return pts[np.asarray(kept, dtype=np.int64)]


@dataclass(frozen=True)
class GeometryMetrics:
    """Acc. and Comp. (mean NN distances, NaN for an empty reconstruction), C.R. and the point count used."""

    acc: float
    comp: float
    cr: float
    num_points: int


def geometry_metrics(
    points: Float[Array, "P 3"],
    mesh: trimesh.Trimesh,
    threshold: float,
    seed: int = 0,
    num_gt_samples: int = 500_000,
    outlier_neighbors: int = 20,
    outlier_std_ratio: float = 10.0,
) -> GeometryMetrics:
    """Acc., Comp. and C.R. of reconstructed points against the GT mesh (4.2).

    Outliers are removed from ``points`` first; GT points are ``num_gt_samples`` area-uniform samples
    drawn with ``seed``; C.R. counts GT points whose nearest reconstructed point is closer than
    ``threshold`` (0.01; Room 0.1). An empty reconstruction gives Acc = Comp = NaN and C.R. = 0.
    """
    rec = remove_statistical_outliers(points, outlier_neighbors, outlier_std_ratio)
    if len(rec) == 0:
        return GeometryMetrics(acc=math.nan, comp=math.nan, cr=0.0, num_points=0)
    gt = sample_surface(mesh, num_gt_samples, seed)
    to_gt, _ = cKDTree(gt).query(rec)
    to_rec, _ = cKDTree(rec).query(gt)
    return GeometryMetrics(
        acc=float(np.mean(to_gt)),
        comp=float(np.mean(to_rec)),
        cr=float(np.mean(to_rec < threshold)),
        num_points=len(rec),
    )
