"""nvf/visibility_source.py and M17's ``train.label_margin``: where NVF's scores read ``v`` from (METHOD 9.3)."""

import pytest
import torch

from nvf.cameras import Intrinsics, look_at, pixel_rays
from nvf.config import FieldConfig, SamplerConfig, TrainConfig
from nvf.model import SceneModel
from nvf.visibility import segment_transmittance, visibility_labels
from nvf.visibility_source import SourcedVisibility, label_visibility
from pipeline.bench._replaced_labels import every_sample_labels

AABB = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
INTR = Intrinsics.from_fov(8, 8)


def small_model() -> SceneModel:
    torch.manual_seed(0)
    field = FieldConfig(log2_hashmap_size=10, num_levels=4, max_resolution=32)
    model = SceneModel(AABB, field, SamplerConfig(grid_resolution=16))
    model.grid.occupied[:] = True
    return model


def rays():
    return pixel_rays(look_at(torch.tensor([0.0, -2.5, 0.3]), torch.zeros(3)), INTR)


def test_sourced_visibility_replaces_only_v():
    """The wrapped render is the model's, with v = source(sample positions); without the visibility head asked
    for, it is the model's render unchanged."""
    model = small_model()
    origins, dirs = rays()
    wrapped = SourcedVisibility(model, lambda points: (points[:, 0] > 0).float())
    heads = frozenset({"variance", "visibility"})
    own, theirs = model.render(origins, dirs, heads), wrapped.render(origins, dirs, heads)
    assert own.samples.num_samples > 0
    torch.testing.assert_close(theirs.alpha, own.alpha)
    torch.testing.assert_close(theirs.variance, own.variance)
    expected = (own.samples.positions(origins, dirs)[:, 0] > 0).float()
    torch.testing.assert_close(theirs.visibility, expected)
    plain = wrapped.render(origins, dirs)
    torch.testing.assert_close(plain.rgb, model.render(origins, dirs).rgb)
    assert wrapped.aabb is model.aabb
    torch.testing.assert_close(wrapped.density(origins), model.density(origins))


def test_label_source_is_m18_at_the_samples():
    """``labels``: V* of M17-M18 through the model's density from the training cameras, bin centres."""
    model = small_model()
    cams = torch.stack(
        [
            look_at(torch.tensor([0.0, -2.5, 0.0]), torch.zeros(3)),
            look_at(torch.tensor([2.5, 0.0, 0.0]), torch.zeros(3)),
        ]
    )
    cfg = TrainConfig(label_samples=16)
    points = torch.rand(50, 3) - 0.5
    got = label_visibility(model, cams, INTR, cfg)(points)
    torch.testing.assert_close(got, visibility_labels(model.density, points, cams, INTR, cfg))


@pytest.mark.parametrize("margin", [0.0, 0.3])
def test_label_margin_stops_the_segment_short(margin):
    """M17 with ``train.label_margin``: the transmittance to x is METHOD's transmittance to the point
    ``margin`` closer to the camera (0: unchanged); a point within the margin of the camera reads T = 1."""
    origin = torch.tensor([0.0, -2.0, 0.0])
    points = torch.tensor([[0.0, 0.2, 0.0], [0.3, 0.5, -0.2], [0.0, -1.9, 0.0]])

    def density(x: torch.Tensor) -> torch.Tensor:
        return torch.where(x.norm(dim=-1) < 0.5, 50.0, 0.0)

    got = segment_transmittance(density, origin, points, 24, margin=margin)
    seg = points - origin
    length = seg.norm(dim=-1, keepdim=True)
    pulled = origin + seg * (length - margin).clamp(min=0) / length
    torch.testing.assert_close(got, segment_transmittance(density, origin, pulled, 24))
    assert got[2] == 1.0
    cam = look_at(origin, torch.zeros(3))[None]
    labels = visibility_labels(density, points[:2], cam, INTR, TrainConfig(label_samples=24, label_margin=margin))
    torch.testing.assert_close(labels, got[:2])


def test_a_margin_uncovers_the_shell_of_a_seen_surface():
    """The shell-average hypothesis in one ray: a soft surface spans several samples; without a margin the
    labels of the samples inside it fall from 1 to 0, so their weight-averaged label is about 1/2; a margin
    as thick as the shell lifts it towards 1 while the far side of a thick object stays unseen."""
    origin = torch.tensor([0.0, -2.0, 0.0])

    def density(x: torch.Tensor) -> torch.Tensor:  # a ball of radius 0.5 with a soft shell from 0.6 to 0.4
        return 40.0 * ((0.6 - x.norm(dim=-1)) / 0.2).clamp(0.0, 1.0)

    t = torch.linspace(1.3, 1.7, 41)  # along the camera ray through the front shell
    points = origin + t[:, None] * torch.tensor([0.0, 1.0, 0.0])
    sigma = density(points)
    alpha = 1 - torch.exp(-sigma * 0.01)
    weights = alpha * torch.cumprod(torch.cat([torch.ones(1), 1 - alpha[:-1]]), 0)
    cam = look_at(origin, torch.zeros(3))[None]
    average = {}
    for margin in (0.0, 0.2):
        v = visibility_labels(density, points, cam, INTR, TrainConfig(label_samples=400, label_margin=margin))
        average[margin] = float((weights * v).sum() / weights.sum())
    assert 0.3 < average[0.0] < 0.7 and average[0.2] > 0.9
    back = visibility_labels(
        density, torch.tensor([[0.0, 0.45, 0.0]]), cam, INTR, TrainConfig(label_samples=400, label_margin=0.2)
    )
    assert back.item() < 0.01


def test_labels_inside_the_density_support_are_bitwise_the_aabbs():
    """(M17, M18) ``SceneModel.density_support`` (the occupied cells' box, grown by half a cell) bounds where
    ``density`` is non-zero, so labels that evaluate only inside it are bitwise the labels over the whole AABB
    (every bin placed, ``pipeline.bench._replaced_labels``); with no occupied cell the support is empty (free space
    everywhere)."""
    model = small_model()
    res = model.grid.resolution
    cells = model.grid.occupied.view(res, res, res)
    cells[:] = False
    cells[3:9, 5:12, 2:7] = True  # a block off the centre: the support is well inside the AABB
    support, grid = model.density_support()
    assert grid is model.grid and (support[0] > AABB[0]).all() and (support[1] < AABB[1]).all()
    cams = torch.stack(
        [
            look_at(torch.tensor([0.2, -2.5, 0.4]), torch.zeros(3)),
            look_at(torch.tensor([2.5, 0.3, 0.0]), torch.zeros(3)),
        ]
    )
    cfg = TrainConfig(label_samples=40)
    points = torch.rand(400, 3, generator=torch.Generator().manual_seed(1)) * 2 - 1

    def density(x: torch.Tensor) -> torch.Tensor:  # the model's, dense enough to occlude
        return 1e3 * model.density(x)

    reference = every_sample_labels(density, points, cams, INTR, cfg, torch.Generator().manual_seed(3), AABB)
    clipped = visibility_labels(density, points, cams, INTR, cfg, torch.Generator().manual_seed(3), support, grid=grid)
    boxed = visibility_labels(density, points, cams, INTR, cfg, torch.Generator().manual_seed(3), support)
    assert torch.equal(reference, boxed)
    assert torch.equal(reference, clipped)
    assert 0 < int((reference > 0.5).sum()) < points.shape[0]
    model.grid.occupied[:] = False
    empty, grid = model.density_support()
    assert (empty[0] > empty[1]).all()
    free = every_sample_labels(model.density, points, cams, INTR, cfg, aabb=AABB)
    assert torch.equal(visibility_labels(model.density, points, cams, INTR, cfg, aabb=empty, grid=grid), free)


def test_label_kernel_finds_the_torch_paths_samples(monkeypatch):
    """(M17) On the CPU the C++ kernel (``nvf.kernels.labels``) finds the samples in occupied cells; the torch
    path finds the same: the density sees bitwise the same positions in the same order, stratified or not."""
    from nvf import kernels

    if kernels.labels() is None:
        pytest.skip("C++ label kernel unavailable (no compiler or ninja)")
    model = small_model()
    res = model.grid.resolution
    model.grid.occupied.view(res, res, res)[:] = (
        torch.rand(res, res, res, generator=torch.Generator().manual_seed(4)) < 0.3
    )
    support, grid = model.density_support()
    origin = torch.tensor([0.3, -2.6, 0.4])
    points = torch.rand(600, 3, generator=torch.Generator().manual_seed(5)) * 2 - 1
    for jitter in (False, True):
        seen: dict[str, list[torch.Tensor]] = {"cpp": [], "torch": []}
        out = {}
        for path in ("cpp", "torch"):
            if path == "torch":
                monkeypatch.setattr(kernels, "labels", lambda: None)

            def density(x: torch.Tensor, path: str = path, seen: dict = seen) -> torch.Tensor:
                seen[path].append(x.clone())
                return 50.0 * model.density(x)

            gen = torch.Generator().manual_seed(6) if jitter else None
            out[path] = segment_transmittance(density, origin, points, 48, gen, support, 3000, grid=grid)
            monkeypatch.undo()
        assert torch.equal(out["cpp"], out["torch"])
        assert len(seen["cpp"]) == len(seen["torch"]) > 1
        for want, got in zip(seen["torch"], seen["cpp"], strict=True):
            assert want.shape[0] > 0 and torch.equal(want, got)
