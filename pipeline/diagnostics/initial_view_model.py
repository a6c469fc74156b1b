"""The model of an episode's first planning step, trained on its own: ``InitialViewModel`` (a full NVF model
trained on the scene's initial views, or on a recorded episode's state), from the configured scene (``load``) and
its ground-truth views (``observations``). The benchmarks and the visibility diagnostic start from it."""

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from jaxtyping import Float
from torch import Tensor

from nvf.cameras import Intrinsics, matrix_to_pose
from nvf.config import STAGES
from nvf.device import resolve_device
from nvf.model import SceneModel
from nvf.observations import Observations
from nvf.planning import candidate_poses
from nvf.seeding import seeded_generator
from nvf.training import train_model
from pipeline.cli import fail
from pipeline.config.typed_run import Run
from pipeline.episode.settings import EpisodeSettings
from pipeline.scenes.blender import blender_python
from pipeline.scenes.ground_truth import Renderer
from pipeline.scenes.loading import load_scene
from pipeline.scenes.mesh_renderer import GroundTruthRenderer
from pipeline.scenes.scene import Scene, SceneError

CPU = torch.device("cpu")


def load(cfg: Run) -> Scene:
    """The configured scene; a missing mesh exits with one line (status 2)."""
    try:
        return load_scene(cfg.scene, Path(cfg.paths.assets), blender_python(cfg.paths.blender_python))
    except SceneError as err:
        fail(str(err))


def observations(
    renderer: Renderer,
    poses: Float[Tensor, "n 4 4"],
    intr: Intrinsics,
    gt_samples: int = 1,
    device: torch.device = CPU,
) -> Observations:
    """Ground-truth RGBA views at ``poses`` (RGB black where the mask is empty), each pixel the mean of
    ``gt_samples^2`` sub-pixel samples (``render_rgba``; Blender's: 1, Cycles' own samples), on ``device``."""
    images = np.stack([renderer.render_rgba(c2w, intr, gt_samples) for c2w in poses])
    return Observations(torch.from_numpy(images).to(device), poses.to(device, torch.float32), intr)


@dataclass
class InitialViewModel:
    """A full NVF model (all three stages, at the budget) trained on the scene's initial views (and
    ``extra_poses`` after them: a later state of an episode): the model of an episode's first planning
    step, shared by the ``plan`` benchmark and the visibility diagnostic (``pipeline.diagnostics.visibility_report``).
    ``pipeline.bench._models.train_side_by_side`` trains one per precision in lockstep."""

    cfg: Run
    scene: Scene
    settings: EpisodeSettings
    renderer: GroundTruthRenderer
    obs: Observations
    model: SceneModel
    train_seconds: float

    @staticmethod
    def train(
        cfg: Run, model_cls: type[SceneModel] = SceneModel, extra_poses: Float[Tensor, "k 4 4"] | None = None
    ) -> "InitialViewModel":
        scene = load(cfg)
        s = EpisodeSettings.of(cfg, scene)
        size = int(cfg.budget.image_size)
        renderer = GroundTruthRenderer(scene.mesh)
        poses = (
            scene.init_poses if extra_poses is None else torch.cat([scene.init_poses, extra_poses.to(scene.init_poses)])
        )
        device = resolve_device(str(cfg.device))
        obs = observations(renderer, poses, Intrinsics.from_fov(size, size), device=device)
        torch.manual_seed(int(cfg.seed))
        model = model_cls(scene.object_aabb, s.field, s.sampler).to(device)
        generator = torch.Generator(device).manual_seed(int(cfg.seed))
        stats = train_model(model, obs, s.train, STAGES, s.entropy, generator)
        return InitialViewModel(cfg, scene, s, renderer, obs, model, stats.seconds)

    def candidates(self, step: int) -> Float[Tensor, "m 7"]:
        """The candidate poses the planner would draw at ``step`` (METHOD 13, M28/M29 filters), from
        the last observed view."""
        s, device = self.settings, self.model.aabb.device
        current = matrix_to_pose(self.obs.c2w[-1].to(torch.float32))
        return candidate_poses(
            self.model,
            s.planner,
            self.scene.camera_box.to(device),
            current,
            s.tau,
            s.collision_free,
            seeded_generator(int(self.cfg.seed), step, "candidates", device),
            line_of_sight=self.renderer.unoccluded,
        )
