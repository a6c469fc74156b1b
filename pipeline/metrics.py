"""Benchmark metrics (PROTOCOL.md 4): image quality, geometry, visual coverage, uncertainty quality.

Images are ``[V, H, W, 3]`` floats (numpy or torch) and are clipped to ``[0, 1]`` first (4.1);
points are ``[P, 3]`` in scene units; meshes are ``trimesh.Trimesh``. Every metric returns plain
Python floats. Names, labels and directions for tables are in ``pipeline.metric_info``.
"""

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import lpips
import numpy as np
import open3d as o3d
import torch
import torch.nn.functional as F
import trimesh
from jaxtyping import Bool, Float, Int
from scipy.spatial import cKDTree
from torch import Tensor

from nvf.uncertainty import correlation
from pipeline.lpips_weights import LpipsUnavailable, load_lpips_alex

Array = np.ndarray | Tensor


def _tensor(x: Array) -> Tensor:
    return x if isinstance(x, Tensor) else torch.from_numpy(np.asarray(x))


def _numpy(x: Array) -> np.ndarray:
    return x.detach().cpu().numpy() if isinstance(x, Tensor) else np.asarray(x)


def _clipped(images: Float[Array, "V H W 3"]) -> Float[Tensor, "V 3 H W"]:
    """Images as float64 ``[V, 3, H, W]`` clipped to [0, 1], on their own device."""
    return _tensor(images).to(torch.float64).clamp(0.0, 1.0).permute(0, 3, 1, 2)


# --- 4.1 image metrics -------------------------------------------------------------------------


def rgb_mse(pred: Float[Array, "V H W 3"], gt: Float[Array, "V H W 3"]) -> float:
    """RGB: MSE pooled over every value of the clipped stacks (4.1)."""
    return (_clipped(pred) - _clipped(gt)).square().mean().item()


def psnr_from_mse(mse: float) -> float:
    """PSNR in dB of a pooled MSE for peak 1: ``10 log10(1 / mse)`` (4.1)."""
    return 10.0 * math.log10(1.0 / mse) if mse > 0 else math.inf


def psnr(pred: Float[Array, "V H W 3"], gt: Float[Array, "V H W 3"]) -> float:
    """PSNR of the pooled MSE, not a mean of per-image PSNRs (4.1)."""
    return psnr_from_mse(rgb_mse(pred, gt))


def edge_pixels(gt: Float[np.ndarray, "V H W 3"], tol: float = 0.02) -> Bool[np.ndarray, "V H W"]:
    """Pixels whose colour differs from a 4-neighbour's by more than ``tol`` in some channel. With one
    sample per pixel (the ground truth renderer), their colour depends on sub-pixel geometry."""
    edge = np.zeros(gt.shape[:3], dtype=bool)
    for axis in (1, 2):
        step = np.abs(np.diff(gt, axis=axis)).max(-1) > tol
        before, after = [slice(None)] * 3, [slice(None)] * 3
        before[axis], after[axis] = slice(None, -1), slice(1, None)
        edge[tuple(before)] |= step
        edge[tuple(after)] |= step
    return edge


def off_edge_psnr(pred: Float[Array, "V H W 3"], gt: Float[Array, "V H W 3"]) -> float:
    """``psnr`` (clipped, pooled MSE) over the pixels that are not ``edge_pixels`` of ``gt`` (a
    diagnostic, not a paper metric)."""
    squared = (_clipped(pred) - _clipped(gt)).square().mean(1)  # [V, H, W]
    off_edge = torch.from_numpy(~edge_pixels(_numpy(gt))).to(squared.device)
    return psnr_from_mse(squared[off_edge].mean().item())


def _gaussian_1d(size: int, sigma: float, like: Tensor) -> Tensor:
    x = torch.arange(size, dtype=like.dtype, device=like.device) - (size - 1) / 2
    g = torch.exp(-0.5 * (x / sigma) ** 2)
    return g / g.sum()


def ssim(
    pred: Float[Array, "V H W 3"],
    gt: Float[Array, "V H W 3"],
    data_range: float | None = None,
    window: int = 11,
    sigma: float = 1.5,
) -> float:
    """Mean SSIM as torchmetrics computes it (4.1).

    Gaussian ``window`` x ``window`` (sigma 1.5), K1 = 0.01, K2 = 0.03, population statistics,
    per channel; the SSIM map keeps only pixels whose window lies inside the image (a 5-pixel
    border is discarded); mean over pixels, channels and images. ``data_range=None`` uses
    ``max(range(pred stack), range(gt stack))``.
    """
    x, y = _clipped(pred), _clipped(gt)
    if min(x.shape[-2:]) < window:
        raise ValueError(f"SSIM needs images of at least {window} x {window} pixels, got {tuple(x.shape[-2:])}")
    if data_range is None:
        data_range = max((x.max() - x.min()).item(), (y.max() - y.min()).item())
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    g = _gaussian_1d(window, sigma, x)
    kernel_h, kernel_w = g.view(1, 1, window, 1).expand(3, 1, -1, -1), g.view(1, 1, 1, window).expand(3, 1, -1, -1)
    total, count = 0.0, 0
    for a, b in zip(x, y):  # one image at a time bounds memory at 512 x 512
        maps = torch.stack([a, b, a * a, b * b, a * b])  # [5, 3, H, W]
        mu_a, mu_b, e_aa, e_bb, e_ab = F.conv2d(F.conv2d(maps, kernel_h, groups=3), kernel_w, groups=3)
        var_a, var_b = (e_aa - mu_a**2).clamp_min(0.0), (e_bb - mu_b**2).clamp_min(0.0)
        cov = e_ab - mu_a * mu_b
        s = ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / ((mu_a**2 + mu_b**2 + c1) * (var_a + var_b + c2))
        total += s.sum().item()
        count += s.numel()
    return total / count


LPIPS_CHUNK_PIXELS = 1 << 20  # pixels per AlexNet batch: all 20 views at 64 x 64, 4 at 512 x 512

LpipsFeatures = list[Tensor]  # per AlexNet layer, unit-normalised activations [V, C_l, H_l, W_l]


class LpipsMetric:
    """LPIPS (AlexNet, v0.1), mean over images (4.1); holds the model or the reason it is missing.

    ``sources`` as in ``pipeline.lpips_weights.load_lpips_alex`` (None: ``default_sources()``).
    When no verified weights exist, ``missing`` holds the reason, a warning is issued once, and
    every call returns NaN: LPIPS is never computed with random weights. Images are batched
    (``LPIPS_CHUNK_PIXELS``); ``reference`` computes the GT side once for repeated comparisons.
    """

    def __init__(self, sources: Sequence[str | Path] | None = None):
        self.model, self.missing = None, None
        try:
            self.model = load_lpips_alex(sources)
        except LpipsUnavailable as err:
            self.missing = str(err)
            warnings.warn(f"LPIPS will be reported as missing: {err}", stacklevel=2)

    @staticmethod
    def _batch(images: Tensor) -> int:
        """Images ``[V, 3, H, W]`` per AlexNet batch."""
        return max(1, LPIPS_CHUNK_PIXELS // (images.shape[-2] * images.shape[-1]))

    def _features(self, x: Float[Tensor, "B 3 H W"]) -> LpipsFeatures:
        """``lpips.LPIPS.forward`` up to the feature difference: [0,1] -> [-1,1], scaling layer,
        AlexNet, unit-normalised activations of the five layers."""
        model = self.model.to(x.device)
        return [lpips.normalize_tensor(f) for f in model.net(model.scaling_layer(2 * x.float() - 1))]

    def _distances(self, a: LpipsFeatures, b: LpipsFeatures) -> Float[Tensor, "B"]:
        """Per-image LPIPS: sum over layers of the spatial mean of the linear head on ``(a - b)^2``."""
        total = 0
        for lin, fa, fb in zip(self.model.lins, a, b):
            total = total + lpips.spatial_average(lin((fa - fb) ** 2), keepdim=True)
        return total.reshape(-1)

    @torch.inference_mode()
    def reference(self, gt: Float[Array, "V H W 3"]) -> LpipsFeatures | None:
        """The GT side of ``against`` (None without weights); ~10 MB per 512 x 512 image."""
        if self.model is None:
            return None
        y = _clipped(gt)
        parts = [self._features(b) for b in y.split(self._batch(y))]
        return [torch.cat(layer) for layer in zip(*parts)]

    @torch.inference_mode()
    def against(self, pred: Float[Array, "V H W 3"], reference: LpipsFeatures | None) -> float:
        """Mean LPIPS of ``pred`` against the images ``reference`` was computed from."""
        if self.model is None:
            return math.nan
        x = _clipped(pred)
        if len(reference[0]) != len(x):
            raise ValueError(f"LPIPS reference holds {len(reference[0])} images, got {len(x)} predictions")
        n = self._batch(x)
        values = [
            self._distances(self._features(a), [f[i : i + n].to(x.device) for f in reference])
            for i, a in zip(range(0, len(x), n), x.split(n))
        ]
        return torch.cat(values).double().mean().item()

    def __call__(self, pred: Float[Array, "V H W 3"], gt: Float[Array, "V H W 3"]) -> float:
        """Mean LPIPS of ``pred`` against ``gt`` (``against`` with a fresh ``reference``)."""
        return self.against(pred, self.reference(gt))


@dataclass(frozen=True)
class ImageMetrics:
    """PROTOCOL 4.1 image metrics of one evaluation; ``lpips`` is NaN when ``lpips_missing`` says why."""

    psnr: float
    ssim: float
    lpips: float
    rgb: float
    lpips_missing: str | None = None


def image_metrics(
    pred: Float[Array, "V H W 3"],
    gt: Float[Array, "V H W 3"],
    lpips_metric: LpipsMetric,
    ssim_data_range: float | None = None,
    lpips_reference: LpipsFeatures | None = None,
) -> ImageMetrics:
    """PSNR, SSIM, LPIPS and RGB of rendered evaluation views against the GT views (4.1);
    ``lpips_reference``: ``lpips_metric.reference(gt)`` if already computed."""
    mse = rgb_mse(pred, gt)
    lpips_value = lpips_metric(pred, gt) if lpips_reference is None else lpips_metric.against(pred, lpips_reference)
    return ImageMetrics(
        psnr=psnr_from_mse(mse),
        ssim=ssim(pred, gt, data_range=ssim_data_range),
        lpips=lpips_value,
        rgb=mse,
        lpips_missing=lpips_metric.missing,
    )


# --- 4.2 geometry ------------------------------------------------------------------------------


def points_from_rays(
    origins: Float[Array, "R 3"],
    dirs: Float[Array, "R 3"],
    depth: Float[Array, "R"],
    acc: Float[Array, "R"],
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
    pts = np.ascontiguousarray(_numpy(points), dtype=np.float64)
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
        acc=float(to_gt.mean()),
        comp=float(to_rec.mean()),
        cr=float((to_rec < threshold).mean()),
        num_points=len(rec),
    )


# --- 4.3 visual coverage -----------------------------------------------------------------------


def seen_faces(face_ids: Int[Array, "*views H W"], num_faces: int) -> Bool[np.ndarray, "F"]:
    """Mask of the faces hit by at least one pixel of the face-id images (-1 = miss) (4.3)."""
    ids = _numpy(face_ids).ravel()
    seen = np.zeros(num_faces, dtype=bool)
    seen[ids[ids >= 0]] = True
    return seen


@dataclass(frozen=True)
class Coverage:
    """Vis. (fraction of faces seen) and the area-weighted fraction ``vis_area`` (logged only)."""

    vis: float
    vis_area: float


def visual_coverage(seen: Bool[np.ndarray, "F"], mesh: trimesh.Trimesh) -> Coverage:
    """Vis. = |seen faces| / |faces| and the seen fraction of the surface area (4.3).

    ``seen`` is the union over all observed poses, e.g. ``seen_faces(...) | seen_faces(...)``.
    """
    if len(seen) != len(mesh.faces):
        raise ValueError(f"seen mask has {len(seen)} entries, the mesh has {len(mesh.faces)} faces")
    areas = np.asarray(mesh.area_faces, dtype=np.float64)
    return Coverage(vis=float(seen.mean()), vis_area=float(areas[seen].sum() / areas.sum()))


# --- 4.4 uncertainty quality -------------------------------------------------------------------


@dataclass(frozen=True)
class UncertaintyCorrelation:
    """Pearson r between error and uncertainty over 32 x 32 patches and over views (4.4), and the per-view
    sums of error and score that the view-level r pairs (``[V]`` each)."""

    patch_pearson: float
    view_pearson: float
    ause: float
    view_error: tuple[float, ...]
    view_score: tuple[float, ...]


def uncertainty_correlation(
    pred: Float[Array, "V H W 3"], gt: Float[Array, "V H W 3"], scores: Float[Array, "V H W"], patch: int = 32
) -> UncertaintyCorrelation:
    """Correlation of the per-pixel error ``sum_ch |pred - gt|`` with the per-pixel score (4.4),
    computed by ``nvf.uncertainty.correlation``: patch level over ``patch`` x ``patch`` tiles, view
    level over per-view sums, and AUSE (an addition, labelled so). NaN where undefined."""
    err = (_clipped(pred) - _clipped(gt)).abs().sum(1)
    u = _tensor(scores).to(err.device)
    view_error, view_score = correlation.view_sums(err, u)
    return UncertaintyCorrelation(
        patch_pearson=correlation.patch_pearson(err, u, patch),
        view_pearson=correlation.view_pearson(err, u),
        ause=correlation.ause(err, u),
        view_error=tuple(view_error.tolist()),
        view_score=tuple(view_score.tolist()),
    )
