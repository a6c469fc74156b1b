"""Image metrics (PROTOCOL.md 4.1): RGB (pooled MSE), PSNR, SSIM and LPIPS of the rendered evaluation
views against the ground truth, plus the off-edge PSNR diagnostic. Every metric returns a plain float."""

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import lpips
import numpy as np
import torch
import torch.nn.functional as F
from jaxtyping import Bool, Float
from torch import Tensor

from pipeline.metrics.arrays import Array, as_numpy, clipped
from pipeline.metrics.lpips_weights import LpipsUnavailable, load_lpips_alex


def rgb_mse(pred: Float[Array, "V H W 3"], gt: Float[Array, "V H W 3"]) -> float:
    """RGB: MSE pooled over every value of the clipped stacks (4.1)."""
    return (clipped(pred) - clipped(gt)).square().mean().item()


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
    squared = (clipped(pred) - clipped(gt)).square().mean(1)  # [V, H, W]
    off_edge = torch.from_numpy(~edge_pixels(as_numpy(gt))).to(squared.device)
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
    x, y = clipped(pred), clipped(gt)
    if min(x.shape[-2:]) < window:
        raise ValueError(f"SSIM needs images of at least {window} x {window} pixels, got {tuple(x.shape[-2:])}")
    if data_range is None:
        data_range = max((x.max() - x.min()).item(), (y.max() - y.min()).item())
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    g = _gaussian_1d(window, sigma, x)
    kernel_h, kernel_w = g.view(1, 1, window, 1).expand(3, 1, -1, -1), g.view(1, 1, 1, window).expand(3, 1, -1, -1)
    total, count = 0.0, 0
    for a, b in zip(x, y, strict=True):  # one image at a time bounds memory at 512 x 512
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

    ``sources`` as in ``pipeline.metrics.lpips_weights.load_lpips_alex`` (None: ``default_sources()``).
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
        assert self.model is not None, "features are computed only with the weights loaded"
        model = self.model.to(x.device)
        return [lpips.normalize_tensor(f) for f in model.net(model.scaling_layer(2 * x.float() - 1))]

    def _distances(self, a: LpipsFeatures, b: LpipsFeatures) -> Float[Tensor, " B"]:
        """Per-image LPIPS: sum over layers of the spatial mean of the linear head on ``(a - b)^2``."""
        assert self.model is not None, "distances are computed only with the weights loaded"
        layers = zip(self.model.lins, a, b, strict=True)
        return sum(lpips.spatial_average(lin((fa - fb) ** 2), keepdim=True) for lin, fa, fb in layers).reshape(-1)

    @torch.inference_mode()
    def reference(self, gt: Float[Array, "V H W 3"]) -> LpipsFeatures | None:
        """The GT side of ``against`` (None without weights); ~10 MB per 512 x 512 image."""
        if self.model is None:
            return None
        y = clipped(gt)
        parts = [self._features(b) for b in y.split(self._batch(y))]
        return [torch.cat(layer) for layer in zip(*parts, strict=True)]

    @torch.inference_mode()
    def against(self, pred: Float[Array, "V H W 3"], reference: LpipsFeatures | None) -> float:
        """Mean LPIPS of ``pred`` against the images ``reference`` was computed from."""
        if self.model is None:
            return math.nan
        assert reference is not None, "reference() returns features whenever the weights are loaded"
        x = clipped(pred)
        if len(reference[0]) != len(x):
            raise ValueError(f"LPIPS reference holds {len(reference[0])} images, got {len(x)} predictions")
        n = self._batch(x)
        values = [
            self._distances(self._features(a), [f[i : i + n].to(x.device) for f in reference])
            for i, a in zip(range(0, len(x), n), x.split(n), strict=True)
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
