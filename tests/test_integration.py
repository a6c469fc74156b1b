"""Whole-stack checks at the cpu budget on the embedded scene (slow): backbone quality, visibility
labels against the renderer's depth test, the NVF entropy's seen/unseen gap and the unknown component's side
(METHOD 9, 8, 11)."""

import dataclasses
import math

import numpy as np
import pytest
import torch

from nvf.cameras import Intrinsics, camera_directions, look_at, matrix_to_pose, rays_from_camera_dirs
from nvf.model import SceneModel
from nvf.planning import score_poses
from nvf.training import train_model
from nvf.uncertainty.mixture import ray_mixture
from nvf.uncertainty.nvf_entropy import NVFEntropyScorer
from nvf.visibility import visibility_labels
from pipeline.bench._models import held_out_poses, view_psnr
from pipeline.config.validation import compose_run
from pipeline.diagnostics.initial_view_model import observations
from pipeline.episode.settings import EpisodeSettings
from pipeline.metrics.image import edge_pixels, off_edge_psnr, psnr
from pipeline.scenes.loading import load_scene
from pipeline.scenes.mesh_renderer import GroundTruthRenderer

pytestmark = pytest.mark.slow
HEAD_STAGES = ("variance", "visibility")


@pytest.fixture(scope="module")
def setup():
    cfg = compose_run(["budget=cpu", "scene=default"])
    scene = load_scene("default")
    settings = EpisodeSettings.of(cfg, scene)
    renderer = GroundTruthRenderer(scene.mesh)
    size = int(cfg.budget.image_size)
    return cfg, scene, settings, renderer, Intrinsics.from_fov(size, size)


def trained(settings, scene, obs, stages, seed=0) -> SceneModel:
    torch.manual_seed(seed)
    model = SceneModel(scene.object_aabb, settings.field, settings.sampler)
    train_model(model, obs, settings.train, stages, settings.entropy, torch.Generator().manual_seed(seed))
    return model


def ring(scene, n: int, elevation_deg: float, azimuth0_deg: float, radius: float) -> torch.Tensor:
    centre = scene.tight_box.mean(0)
    poses = []
    for i in range(n):
        theta = math.radians(azimuth0_deg + 360.0 * i / n)
        phi = math.radians(elevation_deg)
        offset = radius * torch.tensor(
            [math.cos(theta) * math.cos(phi), math.sin(theta) * math.cos(phi), math.sin(phi)]
        )
        poses.append(look_at(centre + offset, centre))
    return torch.stack(poses)


@pytest.fixture(scope="module")
def held_out(setup):
    """The backbone at the cpu budget trained on the 20 evaluation views, rendered at 5 held-out views:
    ``(pred, gt)``, each ``[5, H, W, 3]``."""
    cfg, scene, settings, renderer, intr = setup
    obs = observations(renderer, scene.eval_poses, intr)
    model = trained(settings, scene, obs, ["backbone"])
    poses = held_out_poses(scene)
    pred = np.stack([model.render_image(c2w, intr)["rgb"].numpy() for c2w in poses])
    gt = np.stack([renderer.render(c2w, intr).rgb for c2w in poses])
    return pred, gt


def test_backbone_held_out_psnr_at_the_cpu_budget(held_out):
    """The backbone at the cpu budget, trained on 20 views, renders 5 held-out views at >= 22.5 dB
    (measured 23.42 dB; 23.3 on another day). The paper-level 28 dB is not reached at 64 px: the 13% of
    pixels on edges of the aliased ground truth carry 79% of the error (25.1 dB after 1500 iterations,
    whose training views reach 53.9 dB); off the edges 30.2 dB (next test); against a 4x4-supersampled
    ground truth 28.4-29.0 dB with 400 iterations (test_backbone_reaches_28db_against_antialiased_ground_truth,
    docs/BUDGETS.md). A drop of 0.9 dB fails this test."""
    pred, gt = held_out
    value = psnr(pred, gt)
    print(f"held-out PSNR at the cpu budget: {value:.2f} dB")
    assert value >= 22.5


def test_backbone_reaches_28db_off_edges(held_out):
    """The same renders, PSNR over the pixels that are not on an edge of the ground truth. The
    ground truth has one sample per pixel, so at 64 px an edge pixel's colour depends on sub-pixel
    geometry, which 20 views of 64 px do not pin down (measured at the cpu budget: 30.2 dB here, 29.5
    on another day, edge pixels 13% of the pixels and 79% of the squared error)."""
    pred, gt = held_out
    value = off_edge_psnr(pred, gt)
    print(
        f"held-out PSNR off the ground truth's edges: {value:.2f} dB ({edge_pixels(gt).mean():.3f} of pixels on edges)"
    )
    assert value >= 28.0


def test_backbone_reaches_28db_against_antialiased_ground_truth(setup):
    """The whole stack can reach the 28 dB goal when the ground truth is anti-aliased like the paper's
    Blender renders (every training and held-out pixel the mean of 4 x 4 sub-pixel samples,
    ``budget.gt_samples=4``) and stage 1 runs 400 iterations instead of the cpu budget's 150
    (seeds 0 / 1 / 2 at one thread: 28.48 / 28.40 / 29.02 dB; seed 0 at two threads 28.36; at 300 iterations
    seeds 0 / 1 gave 27.77 / 28.32)."""
    cfg, scene, settings, renderer, intr = setup
    obs = observations(renderer, scene.eval_poses, intr, gt_samples=4)
    backbone = dataclasses.replace(settings.train.backbone, iters=400)
    settings = dataclasses.replace(settings, train=dataclasses.replace(settings.train, backbone=backbone))
    model = trained(settings, scene, obs, ["backbone"])
    value, _ = view_psnr(model, renderer, held_out_poses(scene), intr, gt_samples=4)
    print(f"held-out PSNR against a 4x4-supersampled ground truth after 400 iterations: {value:.2f} dB")
    assert value >= 28.0


@pytest.fixture(scope="module")
def one_sided(setup):
    """Full NVF trained on the scene's one-sided initial views: the backbone at the cpu budget, the
    variance and visibility heads with METHOD 10's 500 iterations at lr 1e-3 (converged as in the
    paper; the cpu budget's 30 iterations at 1e-2 collapse every variance to the floor with 3 views,
    docs/BUDGETS.md)."""
    cfg, scene, settings, renderer, intr = setup
    obs = observations(renderer, scene.init_poses, intr)
    heads = {stage: dataclasses.replace(getattr(settings.train, stage), iters=500, lr=1e-3) for stage in HEAD_STAGES}
    settings = dataclasses.replace(settings, train=dataclasses.replace(settings.train, **heads))
    return obs, trained(settings, scene, obs, ["backbone", "variance", "visibility"])


def test_visibility_labels_agree_with_line_of_sight(setup, one_sided):
    """(M17-M18) Labels from the trained density vs the renderer's exact visibility: a point near the
    surface is visible if some training camera has it in its image and an unoccluded line of sight
    to it (open3d ray cast from the camera centre; the limit of a depth test at infinite resolution;
    a 64-px depth test with a 0.03 tolerance calls 46% of these points visible instead of 36%).
    Agreement >= 0.80 (measured 0.835; 0.828 on another day). METHOD's 0.90 is not reached here: the 32
    label samples step over thin walls (the exact mesh density gives 0.868 with 32 samples, 0.980 with
    200, tests/test_visibility.py), and three 64-px views leave a fog in front of the surface (median
    transmittance 0.47 from a camera that sees the point; 0.844 after 1500 backbone iterations, 0.841
    with 200 label samples), docs/BUDGETS.md."""
    cfg, scene, settings, renderer, intr = setup
    obs, model = one_sided
    points, faces = scene.mesh.sample(4000, return_index=True, seed=0)
    points = torch.tensor(points + 0.01 * scene.mesh.face_normals[faces], dtype=torch.float32)  # just outside
    with torch.no_grad():
        labels = visibility_labels(model.density, points, obs.c2w, intr, settings.train) > 0.5
    truth = renderer.line_of_sight(points, obs.c2w, intr)
    accuracy = (labels == truth).float().mean().item()
    print(f"visibility label accuracy vs line of sight: {accuracy:.3f} ({truth.float().mean():.2f} visible)")
    assert accuracy >= 0.80


def seen_and_unseen_views(setup, one_sided) -> tuple[torch.Tensor, torch.Tensor]:
    """Two views of the seen side (20 degrees either side of the initial views' mean direction) and two of the
    unseen side (opposite), each ``[2, 4, 4]`` camera-to-world."""
    cfg, scene, settings, renderer, intr = setup
    obs, model = one_sided
    seen_dir = obs.c2w[:, :3, 3].mean(0) - scene.tight_box.mean(0)
    azimuth = math.degrees(math.atan2(seen_dir[1], seen_dir[0]))
    radius = float(torch.linalg.norm(seen_dir))

    def views(offsets: tuple[float, float]) -> torch.Tensor:
        return torch.cat([ring(scene, 3, 30.0, azimuth + offset, radius)[:1] for offset in offsets])

    return views((-20.0, 20.0)), views((160.0, 200.0))


def seen_unseen_gap(setup, one_sided, entropy) -> float:
    """Mean NVF view entropy of two views of the unseen side minus two views of the seen side."""
    cfg = setup[0]
    seen, unseen = seen_and_unseen_views(setup, one_sided)
    plan = Intrinsics.from_fov(int(cfg.planner.resolution), int(cfg.planner.resolution))
    scorer = NVFEntropyScorer(entropy, float(entropy.d0))  # NVF's scorer (nvf.methods.NVF.scorer)
    s = score_poses(one_sided[1], scorer, matrix_to_pose(seen), plan, 4096)
    u = score_poses(one_sided[1], scorer, matrix_to_pose(unseen), plan, 4096)
    return float(u.mean() - s.mean())


def unknown_weight(setup, one_sided, c2w: torch.Tensor) -> float:
    """Mean over the rays of views ``c2w [V, 4, 4]`` of the unknown component's weight
    ``pi_un = sum_i w_bar_i (1 - v_i)`` (M9) at the planner's resolution."""
    cfg, settings, model = setup[0], setup[2], one_sided[1]
    plan = Intrinsics.from_fov(int(cfg.planner.resolution), int(cfg.planner.resolution))
    dirs = camera_directions(plan, c2w.device)
    means = []
    with torch.no_grad():
        for pose in c2w:
            origins, directions = rays_from_camera_dirs(pose, dirs)
            result = model.render(origins, directions, heads=frozenset({"rgb", "variance", "visibility"}), train=False)
            n_samples, n_rays = result.alpha.shape[0], origins.shape[0]
            mixture, _ = ray_mixture(
                result.alpha,
                result.rgb_s,
                result.variance,
                result.visibility,
                result.samples.ray_idx,
                n_rays,
                settings.entropy,
            )
            means.append(mixture.weights[n_samples : n_samples + n_rays].mean())  # the unknown components
    return float(torch.stack(means).mean())


def test_unseen_side_has_higher_entropy(setup, one_sided):
    """(M7-M16) Views of the unseen side score higher than views of the seen side."""
    full = seen_unseen_gap(setup, one_sided, setup[2].entropy)
    print(f"unseen - seen view entropy, NVF: {full:.3f}")
    assert full > 0.0


def test_visibility_puts_the_unknown_component_on_the_unseen_side(setup, one_sided):
    """(METHOD 11, M9) What the visibility field adds to the score, and w/o Vis. (``v = 1``, so ``pi_un = 0``)
    removes: the unknown component weighs more in views of the unseen side than of the seen side (measured at
    one thread, seeds 0 / 2 / 4 of ``trained``: seen 0.080 / 0.094 / 0.082, unseen 0.146 / 0.148 / 0.149).

    Whether that widens NVF's seen/unseen entropy gap beyond w/o Vis.'s is not stable at this budget: the gap's
    difference NVF minus w/o Vis. over seeds 0-5 was +0.13, +0.25, -0.28, +0.25, -0.10, +0.24 nats at one
    thread, and -0.04 at seed 0 on another machine (the w/o Vis. gap alone ranges 0.72-1.17 with the seed). That
    is the cpu budget's finding on decisions (NVF and w/o Vis. rank candidates alike), so no test asserts it."""
    seen, unseen = seen_and_unseen_views(setup, one_sided)
    seen_weight, unseen_weight = unknown_weight(setup, one_sided, seen), unknown_weight(setup, one_sided, unseen)
    print(f"unknown component weight: seen side {seen_weight:.3f}, unseen side {unseen_weight:.3f}")
    assert unseen_weight > 1.3 * seen_weight
