"""pipeline/metrics/image.py + pipeline/metrics/lpips_weights.py: PROTOCOL.md 4 metric definitions."""

import math

import numpy as np
import pytest
import torch
import trimesh
from PIL import Image
from skimage.metrics import structural_similarity

from pipeline.metrics import image as metrics
from pipeline.metrics.correlation import uncertainty_correlation
from pipeline.metrics.geometry import geometry_metrics, points_from_rays
from pipeline.metrics.image import LpipsMetric, image_metrics, psnr, psnr_from_mse, rgb_mse, ssim
from pipeline.metrics.info import METRICS, PAPER_METRICS
from pipeline.metrics.lpips_weights import LpipsUnavailable, default_sources, load_lpips_alex
from pipeline.metrics.visual_coverage import seen_faces, visual_coverage

# Published LPIPS(alex, v0.1) of the IQA-PyTorch calibration pairs (ResultsCalibra; files under NVF_CALIBRATION,
# README.md).
CALIBRATION = {"I03": 0.7237, "I04": 0.2572, "I06": 0.0508, "I08": 0.0521, "I19": 0.4253}


def _random_pair(seed: int, shape=(2, 40, 48, 3)) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    gt = rng.random(shape)
    pred = np.clip(gt + 0.1 * rng.standard_normal(shape), 0.0, 1.0)
    return pred, gt


# --- 4.1 image metrics -------------------------------------------------------------------------


def test_psnr_uses_pooled_mse():
    assert round(psnr_from_mse(0.0041), 2) == 23.87  # PROTOCOL 4.1 check (Table S3 chair NVF)
    gt = np.zeros((2, 4, 4, 3))
    pred = gt.copy()
    pred[0] += 0.1
    pred[1] += 0.3
    mse = (0.01 + 0.09) / 2
    assert rgb_mse(pred, gt) == pytest.approx(mse)
    assert psnr(pred, gt) == pytest.approx(10 * math.log10(1 / mse))
    assert psnr(pred, gt) != pytest.approx(np.mean([10 * math.log10(1 / 0.01), 10 * math.log10(1 / 0.09)]))
    assert psnr(torch.from_numpy(pred).float(), torch.from_numpy(gt).float()) == pytest.approx(psnr(pred, gt))


def test_edge_pixels_and_off_edge_psnr():
    gt = np.zeros((1, 6, 6, 3))
    gt[0, :, 3:] = 1.0  # a vertical edge between columns 2 and 3
    edge = metrics.edge_pixels(gt)
    assert edge[0, :, 2:4].all() and not edge[0, :, [0, 1, 4, 5]].any()
    pred = gt.copy()
    pred[0, :, 2:4] = 0.5  # wrong only on the edge
    pred[0, :, 0] += 0.1
    assert metrics.off_edge_psnr(pred, gt) == pytest.approx(10 * math.log10(1 / (0.01 / 4)))
    assert metrics.off_edge_psnr(pred, gt) > psnr(pred, gt)


def test_image_metrics_clip_to_unit_range():
    gt = np.zeros((1, 4, 4, 3))
    assert rgb_mse(gt + 2.0, gt) == pytest.approx(1.0)


def test_ssim_identical_images_is_one():
    _, gt = _random_pair(0)
    assert ssim(gt, gt) == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("data_range", [None, 1.0])
def test_ssim_matches_skimage_gaussian_population_statistics(data_range):
    pred, gt = _random_pair(1)
    pred[0, :5] = 0.0  # a dark band so that the inferred data range differs from 1
    pred, gt = pred * 0.8, gt * 0.9
    expected_range = max(np.ptp(pred), np.ptp(gt)) if data_range is None else data_range
    # skimage: 11 x 11 Gaussian (sigma 1.5, truncate 3.5), population covariance, 5-pixel crop.
    reference = np.mean(
        [
            structural_similarity(
                p,
                g,
                data_range=expected_range,
                channel_axis=-1,
                gaussian_weights=True,
                sigma=1.5,
                use_sample_covariance=False,
            )
            for p, g in zip(pred, gt, strict=True)
        ]
    )
    assert ssim(pred, gt, data_range=data_range) == pytest.approx(reference, abs=1e-9)
    assert ssim(torch.from_numpy(pred), torch.from_numpy(gt), data_range=data_range) == pytest.approx(reference)


# --- 4.1 LPIPS ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def lpips_metric() -> LpipsMetric:
    metric = LpipsMetric()
    if metric.missing is not None:
        pytest.skip(f"LPIPS weights unavailable: {metric.missing}")
    return metric


def _load(path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB"), dtype=np.float32)[None] / 255.0


@pytest.mark.parametrize("pair", sorted(CALIBRATION))
def test_lpips_reproduces_published_calibration(lpips_metric, lpips_calibration_dir, pair):
    dist, ref = _load(lpips_calibration_dir / f"{pair}_dist.png"), _load(lpips_calibration_dir / f"{pair}_ref.png")
    assert round(lpips_metric(dist, ref), 4) == CALIBRATION[pair]


def test_lpips_mean_over_images(lpips_metric):
    pred, gt = _random_pair(2, shape=(2, 64, 64, 3))
    per_image = [lpips_metric(pred[i : i + 1], gt[i : i + 1]) for i in range(2)]
    assert lpips_metric(pred, gt) == pytest.approx(np.mean(per_image), rel=1e-6)
    assert lpips_metric(gt, gt) == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize("chunk_pixels", [1 << 20, 3 * 48 * 40])  # one batch; batches of 3 (the last of 2)
def test_lpips_batched_and_cached_equal_the_per_image_forward(lpips_metric, monkeypatch, chunk_pixels):
    monkeypatch.setattr(metrics, "LPIPS_CHUNK_PIXELS", chunk_pixels)
    pred, gt = _random_pair(5, shape=(5, 40, 48, 3))
    pred[0] += 0.5  # values above 1 are clipped first (4.1)
    x = torch.from_numpy(pred).clamp(0, 1).permute(0, 3, 1, 2).float()
    y = torch.from_numpy(gt).permute(0, 3, 1, 2).float()
    with torch.no_grad():  # the lpips package's own forward, one image at a time
        pairs = zip(x, y, strict=True)
        straightforward = np.mean([lpips_metric.model(a[None], b[None], normalize=True).item() for a, b in pairs])
    reference = lpips_metric.reference(gt)
    assert [f.shape[0] for f in reference] == [5] * 5
    assert lpips_metric(pred, gt) == pytest.approx(straightforward, rel=1e-6)
    assert lpips_metric.against(pred, reference) == pytest.approx(straightforward, rel=1e-6)
    cached = image_metrics(pred, gt, lpips_metric, lpips_reference=reference)
    assert cached == image_metrics(pred, gt, lpips_metric)


def test_lpips_loads_torchvision_checkpoint_and_rejects_random_trunk(lpips_metric, tmp_path):
    state = lpips_metric.model.state_dict()
    slices = {0: "net.slice1.0", 3: "net.slice2.3", 6: "net.slice3.6", 8: "net.slice4.8", 10: "net.slice5.10"}
    real = {f"features.{i}.{p}": state[f"{key}.{p}"].clone() for i, key in slices.items() for p in ("weight", "bias")}
    torch.save(real, tmp_path / "alexnet-owt-7be5be79.pth")
    model = load_lpips_alex([tmp_path / "alexnet-owt-7be5be79.pth"])
    assert torch.equal(model.net.slice1[0].weight, lpips_metric.model.net.slice1[0].weight)

    torch.save({k: torch.randn_like(v) * 0.01 for k, v in real.items()}, tmp_path / "random.pth")
    with pytest.raises(LpipsUnavailable, match="does not match"):
        load_lpips_alex([tmp_path / "random.pth"])


def test_lpips_unavailable_is_missing_never_a_number(tmp_path):
    with pytest.warns(UserWarning, match="missing"):
        metric = LpipsMetric(sources=[tmp_path / "nothing.pth"])
    assert metric.model is None and "not found" in metric.missing
    pred, gt = _random_pair(3, shape=(1, 16, 16, 3))
    assert math.isnan(metric(pred, gt))
    assert metric.reference(gt) is None and math.isnan(metric.against(pred, None))
    result = image_metrics(pred, gt, metric)
    assert math.isnan(result.lpips) and result.lpips_missing == metric.missing
    assert result.psnr == pytest.approx(psnr(pred, gt)) and result.rgb == pytest.approx(rgb_mse(pred, gt))
    with pytest.raises(LpipsUnavailable, match="no weight source"):
        load_lpips_alex([])


def test_default_sources_order(tmp_path, monkeypatch):
    monkeypatch.setenv("TORCH_HOME", str(tmp_path))
    sources = default_sources(tmp_path / "mine.pth")
    assert sources[0] == tmp_path / "mine.pth"
    assert sources[1] == tmp_path / "hub" / "checkpoints" / "alexnet-owt-7be5be79.pth"
    assert all(s.name == "alexnet.ckpt" for s in sources[2:])


# --- 4.2 geometry ------------------------------------------------------------------------------


def _square() -> trimesh.Trimesh:
    vertices = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]]
    return trimesh.Trimesh(vertices, [[0, 1, 2], [0, 2, 3]], process=False)


def test_geometry_shifted_copy_gives_the_shift():
    mesh = _square()
    gt, _ = trimesh.sample.sample_surface(mesh, 5000, seed=7)  # the very points geometry_metrics draws
    exact = geometry_metrics(gt, mesh, threshold=0.01, seed=7, num_gt_samples=5000)
    assert exact.acc == pytest.approx(0.0, abs=1e-12) and exact.comp == pytest.approx(0.0, abs=1e-12)
    assert exact.cr == 1.0 and exact.num_points == 5000
    shifted = geometry_metrics(gt + [0.0, 0.0, 0.05], mesh, threshold=0.01, seed=7, num_gt_samples=5000)
    assert shifted.acc == pytest.approx(0.05) and shifted.comp == pytest.approx(0.05)
    assert shifted.cr == 0.0
    assert geometry_metrics(gt + [0.0, 0.0, 0.05], mesh, threshold=0.1, seed=7, num_gt_samples=5000).cr == 1.0


def test_geometry_sphere():
    mesh = trimesh.creation.icosphere(subdivisions=5)
    rng = np.random.default_rng(0)
    dirs = rng.standard_normal((20000, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    on = geometry_metrics(torch.from_numpy(dirs), mesh, threshold=0.05, num_gt_samples=20000)
    assert on.acc < 0.02 and on.comp < 0.02 and on.cr > 0.99  # sample spacing ~0.0125
    outside = geometry_metrics(1.1 * dirs, mesh, threshold=0.05, num_gt_samples=20000)
    assert outside.acc == pytest.approx(0.1, abs=0.005) and outside.comp == pytest.approx(0.1, abs=0.01)
    assert outside.cr == 0.0


def test_geometry_outliers_are_removed():
    mesh = _square()
    gt, _ = trimesh.sample.sample_surface(mesh, 2000, seed=1)
    with_outlier = np.concatenate([gt, [[0.5, 0.5, 50.0]]])
    result = geometry_metrics(with_outlier, mesh, threshold=0.01, seed=1, num_gt_samples=2000)
    assert result.num_points == 2000 and result.acc == pytest.approx(0.0, abs=1e-12)


def test_empty_reconstruction():
    empty = geometry_metrics(np.zeros((0, 3)), _square(), threshold=0.01, num_gt_samples=100)
    assert math.isnan(empty.acc) and math.isnan(empty.comp) and empty.cr == 0.0 and empty.num_points == 0


def test_points_from_rays_keeps_opaque_rays():
    origins = torch.zeros(3, 3)
    dirs = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    depth = torch.tensor([2.0, 3.0, 4.0])
    acc = torch.tensor([0.9, 0.5, 0.51])
    points = points_from_rays(origins, dirs, depth, acc)
    assert torch.equal(points, torch.tensor([[2.0, 0.0, 0.0], [0.0, 0.0, 4.0]]))
    none = points_from_rays(origins.numpy(), dirs.numpy(), depth.numpy(), np.zeros(3, dtype=np.float32))
    assert none.shape == (0, 3)


# --- 4.3 visual coverage / 4.4 uncertainty quality / table metadata -----------------------------


def test_visual_coverage_counts_faces_and_area():
    vertices = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [3, 0, 0], [0, 3, 0], [0, 0, 1]]
    mesh = trimesh.Trimesh(vertices, [[0, 1, 2], [0, 3, 4], [0, 1, 5], [0, 2, 5]], process=False)
    view_a = np.full((4, 4), -1, dtype=np.int64)
    view_a[:2, :2] = 0
    view_b = np.full((4, 4), -1, dtype=np.int64)
    view_b[0, 0], view_b[3, 3] = 1, 0
    seen = seen_faces(view_a, 4) | seen_faces(view_b, 4)
    assert seen.tolist() == [True, True, False, False]
    coverage = visual_coverage(seen, mesh)
    areas = mesh.area_faces
    assert coverage.vis == 0.5
    assert coverage.vis_area == pytest.approx((areas[0] + areas[1]) / areas.sum())
    assert seen_faces(torch.from_numpy(np.stack([view_a, view_b])), 4).tolist() == seen.tolist()


def test_uncertainty_correlation_perfect_scores():
    pred, gt = _random_pair(4, shape=(3, 64, 64, 3))
    error = np.abs(pred - gt).sum(-1)
    result = uncertainty_correlation(pred, gt, 2.0 * error + 1.0)
    assert result.patch_pearson == pytest.approx(1.0) and result.view_pearson == pytest.approx(1.0)
    assert uncertainty_correlation(pred, gt, -error).patch_pearson == pytest.approx(-1.0)


def test_uncertainty_correlation_reports_the_per_view_sums_the_view_r_pairs():
    """(PROTOCOL 4.4) view r is Pearson over per-view sums of error and score; both lists are returned."""
    pred, gt = _random_pair(5, shape=(3, 32, 32, 3))
    error = np.abs(pred - gt).sum(-1)
    score = np.random.default_rng(0).random(error.shape)
    result = uncertainty_correlation(pred, gt, score)
    assert result.view_error == pytest.approx(error.sum((1, 2)).tolist(), rel=1e-5)
    assert result.view_score == pytest.approx(score.sum((1, 2)).tolist(), rel=1e-9)
    assert result.view_pearson == pytest.approx(np.corrcoef(result.view_error, result.view_score)[0, 1], abs=1e-9)


def test_metric_table():
    paper = [m.name for m in PAPER_METRICS]
    assert paper == ["psnr", "ssim", "lpips", "rgb", "acc", "comp", "cr", "vis"]  # the paper's column order
    assert [m.decimals for m in PAPER_METRICS] == [2, 3, 3, 4, 4, 4, 3, 3]
    higher = {m.name for m in METRICS.values() if m.higher_is_better}
    assert higher == {"psnr", "ssim", "cr", "vis", "vis_area", "patch_pearson", "view_pearson"}
    assert METRICS["lpips"].arrow == "↓" and METRICS["vis"].label == "Vis."
