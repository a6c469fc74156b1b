"""nvf/visibility.py: frustum test, transmittance (M17), noisy-OR with early skip (M18)."""

import math

import pytest
import torch

from nvf.cameras import Intrinsics, look_at
from nvf.config import TrainConfig
from nvf.visibility import SATURATION, frustum_mask, segment_transmittance, visibility_labels
from pipeline.bench._replaced_labels import every_sample_transmittance
from pipeline.scenes.loading import load_scene
from pipeline.scenes.mesh_renderer import GroundTruthRenderer

RADIUS = 0.5
INTR = Intrinsics.from_fov(16, 16, 90.0)
AABB = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


def sphere_density(x: torch.Tensor) -> torch.Tensor:
    """An opaque ball of radius 0.5 at the origin (sigma = 1e3 inside, 0 outside)."""
    return torch.where(x.norm(dim=-1) < RADIUS, 1e3, 0.0)


def first_hit(origin: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Distance along ``o -> x`` to the first ray-sphere intersection (inf when the line misses)."""
    seg = points - origin
    length = seg.norm(dim=-1)
    d = seg / length[:, None]
    b = (d * origin).sum(-1)
    disc = b * b - (origin.norm() ** 2 - RADIUS**2)
    return torch.where(disc > 0, -b - disc.clamp_min(0).sqrt(), torch.full_like(b, math.inf))


def test_frustum_mask_depth_and_image_bounds():
    c2w = look_at(torch.tensor([0.0, -3.0, 0.0]), torch.zeros(3))
    points = torch.tensor(
        [
            [0.0, 0.0, 0.0],  # centre of the image, depth 3
            [0.0, -4.0, 0.0],  # behind the camera
            [0.0, 8.0, 0.0],  # depth 11 > label_max_depth 10
            [3.5, 0.0, 0.0],  # 3.5 right at depth 3: outside a 90-degree FoV
            [2.9, 0.0, 0.0],  # inside
        ]
    )
    mask = frustum_mask(points, c2w, INTR, 10.0)
    assert mask.tolist() == [True, False, False, False, True]


def test_transmittance_constant_density_is_exact():
    """(M17) with constant sigma: ``T = exp(-sigma |x-o| (K-1)/K)``, the last interval excluded."""
    origin = torch.zeros(3)
    points = torch.tensor([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 0.0]])
    k, sigma = 10, 0.3

    def density(x: torch.Tensor) -> torch.Tensor:
        return torch.full(x.shape[:1], sigma)

    expected = torch.exp(-sigma * points.norm(dim=-1) * (k - 1) / k)
    for gen in (None, torch.Generator().manual_seed(1)):
        got = segment_transmittance(density, origin, points, k, gen, chunk_samples=7)
        assert torch.allclose(got, expected, atol=1e-6)


def test_transmittance_stratified_positions_stay_in_their_bins():
    origin, point, k = torch.zeros(3), torch.tensor([[2.0, 0.0, 0.0]]), 8
    seen = []

    def density(x: torch.Tensor) -> torch.Tensor:
        seen.append(x[:, 0].clone())
        return torch.zeros(x.shape[0])

    segment_transmittance(density, origin, point, k, torch.Generator().manual_seed(0))
    t = torch.cat(seen)
    assert t.numel() == k - 1  # the interval ending at x is excluded
    bins = torch.arange(k - 1) * 2.0 / k
    assert ((t >= bins) & (t < bins + 2.0 / k)).all()
    segment_transmittance(density, origin, point, k)  # deterministic: bin centres
    assert torch.allclose(seen[-1], bins + 1.0 / k)


@pytest.mark.parametrize("jitter", [False, True])
def test_labels_match_analytic_depth_test(jitter):
    """M17-M18 on an opaque sphere seen by two cameras: >= 90% agreement with ray-sphere visibility."""
    cfg = TrainConfig(label_samples=200)
    cams = [torch.tensor([0.0, -3.0, 0.0]), torch.tensor([3.0, 0.0, 0.5])]
    c2w = torch.stack([look_at(p, torch.zeros(3)) for p in cams])
    gen = torch.Generator().manual_seed(0)
    points = torch.rand(3000, 3, generator=gen) * 2.0 - 1.0
    labels = visibility_labels(sphere_density, points, c2w, INTR, cfg, generator=gen if jitter else None, aabb=AABB)
    assert labels.min() >= 0.0 and labels.max() <= 1.0

    expected = torch.zeros(points.shape[0], dtype=torch.bool)
    for pos, cam in zip(cams, c2w, strict=True):
        reach = first_hit(pos, points) >= (points - pos).norm(dim=-1)
        expected |= frustum_mask(points, cam, INTR, cfg.label_max_depth) & reach
    agree = (labels > 0.5) == expected
    assert agree.float().mean().item() >= 0.9
    assert agree[expected].float().mean().item() >= 0.9  # both classes are populated and recovered
    assert agree[~expected].float().mean().item() >= 0.9
    assert expected.sum() > 100 and (~expected).sum() > 100


def test_near_surface_visible_far_surface_hidden_outside_zero():
    cfg = TrainConfig()
    pos = torch.tensor([0.0, -3.0, 0.0])
    c2w = look_at(pos, torch.zeros(3))[None]
    gen = torch.Generator().manual_seed(3)
    n = torch.nn.functional.normalize(torch.randn(4000, 3, generator=gen), dim=-1)
    facing = n @ (pos / pos.norm())  # cosine between the normal and the direction to the camera
    near = n[facing > 0.5] * RADIUS * 1.001
    far = n[facing < -0.5] * RADIUS * 1.001
    outside = torch.tensor([[0.0, -4.0, 0.0], [0.0, 8.0, 0.0], [0.9, -2.4, 0.0]])  # behind, too deep, off-image
    points = torch.cat([near, far, outside])
    labels = visibility_labels(sphere_density, points, c2w, INTR, cfg, aabb=AABB)
    assert (labels[: len(near)] > 0.99).all()
    assert (labels[len(near) : len(near) + len(far)] < 1e-3).all()
    assert (labels[-3:] == 0).all()


def test_early_skip_saturates_near_099():
    """M18: cameras in order; a point stops once its running product is <= 0.01."""
    cfg = TrainConfig(label_samples=20)
    origin_dist, t_single = 2.0, 0.5
    sigma = -math.log(t_single) / (origin_dist * (cfg.label_samples - 1) / cfg.label_samples)
    calls = []

    def density(x: torch.Tensor) -> torch.Tensor:
        calls.append(x.shape[0])
        return torch.full(x.shape[:1], sigma)

    c2w = look_at(torch.tensor([0.0, -origin_dist, 0.0]), torch.zeros(3))[None].repeat(10, 1, 1)
    label = visibility_labels(density, torch.zeros(1, 3), c2w, INTR, cfg)
    n_used = math.ceil(math.log(SATURATION) / math.log(t_single))  # 0.5^7 <= 0.01 < 0.5^6
    assert n_used == 7
    assert label.item() == pytest.approx(1 - 0.5**n_used, abs=1e-5)
    assert len(calls) == n_used and sum(calls) == n_used * (cfg.label_samples - 1)


def test_labels_zero_outside_every_frustum_and_without_cameras():
    cfg = TrainConfig(label_samples=8)
    points = torch.rand(50, 3)
    c2w = look_at(torch.tensor([0.0, -3.0, 0.0]), torch.tensor([0.0, -6.0, 0.0]))[None]  # looks away
    assert (visibility_labels(sphere_density, points, c2w, INTR, cfg) == 0).all()
    assert (visibility_labels(sphere_density, points, torch.zeros(0, 4, 4), INTR, cfg) == 0).all()


def test_aabb_skip_and_chunking_do_not_change_labels():
    cfg = TrainConfig(label_samples=64)
    positions = [torch.tensor([0.3, -3.0, 0.2]), torch.tensor([0.0, 0.0, 3.0])]
    c2w = torch.stack([look_at(p, torch.zeros(3)) for p in positions])
    points = torch.rand(500, 3, generator=torch.Generator().manual_seed(5)) * 2 - 1

    def boxed(x: torch.Tensor) -> torch.Tensor:  # density 0 outside the AABB, as the field's
        inside = ((x >= AABB[0]) & (x <= AABB[1])).all(-1)
        return torch.where(inside, sphere_density(x) + 0.5, 0.0)

    full = visibility_labels(boxed, points, c2w, INTR, cfg)
    skipped = visibility_labels(boxed, points, c2w, INTR, cfg, aabb=AABB, chunk_samples=100)
    assert torch.allclose(full, skipped, atol=1e-6)


def test_labels_do_not_track_gradients():
    lin = torch.nn.Linear(3, 1)
    c2w = look_at(torch.tensor([0.0, -3.0, 0.0]), torch.zeros(3))[None]
    cfg = TrainConfig(label_samples=8)
    labels = visibility_labels(lambda x: torch.relu(lin(x)[:, 0]), torch.rand(10, 3), c2w, INTR, cfg)
    assert not labels.requires_grad


def test_exact_density_labels_of_the_default_scene_agree_with_line_of_sight():
    """M17-M18 with the default scene's exact density (sigma = 1e3 inside the mesh, open3d's
    occupancy) and its three initial 64-px views, on 4000 points 0.01 outside the surface: with
    METHOD's K = 200 the labels agree with the exact line of sight on >= 95% of the points (measured
    0.980), so the label rule is not what holds the trained model's agreement below 90%
    (test_integration). The cpu budget's K = 32 agrees less (measured 0.868): its samples are ~0.06
    apart and step over thin walls."""
    scene = load_scene("default")
    points, faces = scene.mesh.sample(4000, return_index=True, seed=0)
    points = torch.tensor(points + 0.01 * scene.mesh.face_normals[faces], dtype=torch.float32)
    intr = Intrinsics.from_fov(64, 64)
    accuracy = {}
    with GroundTruthRenderer(scene.mesh) as renderer:
        truth = renderer.line_of_sight(points, scene.init_poses, intr)

        def exact_density(x: torch.Tensor) -> torch.Tensor:
            return renderer.inside(x).float() * 1e3

        for k in (32, 200):
            labels = visibility_labels(exact_density, points, scene.init_poses, intr, TrainConfig(label_samples=k))
            accuracy[k] = ((labels > 0.5) == truth).float().mean().item()
    print(f"exact-density label agreement: K=32 {accuracy[32]:.3f}, K=200 {accuracy[200]:.3f}")
    assert accuracy[200] >= 0.95
    assert accuracy[32] < accuracy[200]
    assert 0.2 < truth.float().mean().item() < 0.8  # both classes populated


@pytest.mark.parametrize("jitter", [False, True])
def test_clipped_bins_evaluate_the_reference_samples_bitwise(jitter):
    """(M17) Only the bins between a segment's entry into and exit from the box are placed: the density sees
    exactly the samples (same positions, same order) that placing every bin and testing it gives (the code this
    replaced, ``pipeline.bench._replaced_labels``), so the transmittances are bitwise the same; segments that miss
    the box evaluate nothing."""
    box = torch.tensor([[-0.6, -0.4, -0.5], [0.7, 0.5, 0.3]])
    origin = torch.tensor([0.3, -3.0, 0.2])
    points = torch.rand(700, 3, generator=torch.Generator().manual_seed(2)) * 3.0 - 1.5
    seen: dict[bool, list[torch.Tensor]] = {True: [], False: []}
    out = {}
    for clip in (False, True):

        def density(x: torch.Tensor, clip: bool = clip) -> torch.Tensor:
            seen[clip].append(x.clone())
            return sphere_density(x) * 0.01 + x[:, 0].abs()

        gen = torch.Generator().manual_seed(7) if jitter else None
        compute = segment_transmittance if clip else every_sample_transmittance
        out[clip] = compute(density, origin, points, 64, gen, box, chunk_samples=2000)
    assert torch.equal(out[True], out[False])
    assert len(seen[True]) == len(seen[False]) > 1
    for want, got in zip(seen[False], seen[True], strict=True):
        assert torch.equal(want, got)
    assert (out[True] < 1).any() and (out[True] == 1).any()  # some segments cross the box, some miss it


def _occluders(x: torch.Tensor) -> torch.Tensor:
    """Two opaque slabs and a thin fog: segments that die early, late, or never."""
    slab = ((x[:, 1] > -0.2) & (x[:, 1] < 0.0)) | ((x[:, 0] > 0.3) & (x[:, 0] < 0.5))
    return torch.where(slab, 60.0, 0.05)


@pytest.mark.parametrize("jitter", [False, True])
def test_early_stop_keeps_each_transmittance_within_the_cutoff(jitter):
    """(M17, early stop) With ``cutoff`` a segment stops once its transmittance falls below it: each ``T`` is at
    least the exact one (less optical depth is summed) and off by less than the cutoff (plus float rounding), and
    the density is asked for fewer samples. ``cutoff=0`` is the exact path, bitwise."""
    origin = torch.tensor([0.1, -3.0, 0.2])
    points = torch.rand(900, 3, generator=torch.Generator().manual_seed(8)) * 2 - 1
    asked: dict[float, int] = {}
    out = {}
    for cutoff in (0.0, 1e-3):

        def density(x: torch.Tensor, cutoff: float = cutoff) -> torch.Tensor:
            asked[cutoff] = asked.get(cutoff, 0) + x.shape[0]
            return _occluders(x)

        gen = torch.Generator().manual_seed(9) if jitter else None
        out[cutoff] = segment_transmittance(density, origin, points, 200, gen, AABB, 5000, cutoff=cutoff)
    exact, stopped = out[0.0], out[1e-3]
    assert ((stopped - exact).abs() < 1e-3 + 1e-6).all() and (stopped >= exact - 1e-6).all()
    assert (exact < 1e-3).sum() > 100 and (exact > 0.5).sum() > 100  # both kinds of segment are there
    assert asked[1e-3] < 0.8 * asked[0.0]
    gen = torch.Generator().manual_seed(9) if jitter else None
    assert torch.equal(exact, segment_transmittance(_occluders, origin, points, 200, gen, AABB, 5000))


def test_early_stop_labels_stay_within_the_stated_tolerance():
    """(M17, M18) Labels with ``train.label_cutoff=1e-3`` against the exact labels on the same samples: mean
    absolute difference <= 0.005 and none off by more than 0.05 (the tolerance of the paper-size speed-up), over
    six cameras around the occluders."""
    cams = [torch.tensor(p) for p in ([0.1, -3.0, 0.2], [3.0, 0.2, 0.1], [-2.0, 2.0, 1.0], [0.0, 0.5, 3.0])]
    cams += [torch.tensor([-3.0, -0.5, 0.3]), torch.tensor([0.4, 3.0, -0.6])]
    c2w = torch.stack([look_at(p, torch.zeros(3)) for p in cams])
    points = torch.rand(3000, 3, generator=torch.Generator().manual_seed(10)) * 2 - 1
    intr = Intrinsics.from_fov(64, 64, 90.0)
    labels = {}
    for cutoff in (0.0, 1e-3):
        cfg = TrainConfig(label_samples=200, label_cutoff=cutoff)
        labels[cutoff] = visibility_labels(_occluders, points, c2w, intr, cfg, torch.Generator().manual_seed(1), AABB)
    diff = (labels[1e-3] - labels[0.0]).abs()
    assert diff.mean() <= 0.005 and diff.max() <= 0.05
    assert 0.1 < (labels[0.0] > 0.5).float().mean() < 0.9
