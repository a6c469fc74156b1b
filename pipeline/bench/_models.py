"""What the benchmarks share: a model that counts its samples (``CountingModel``), models trained side by side
from the same initial weights (``same_initial_models``, ``train_in_lockstep``; ``train_side_by_side``: the model
of an episode's first planning step, ``pipeline.diagnostics.initial_view_model.InitialViewModel``, per
precision), held-out PSNR (``held_out_poses``, ``view_psnr``) and the precisions compared."""

import dataclasses
import math
from collections.abc import Callable

import numpy as np
import torch
from jaxtyping import Float
from torch import Tensor

from nvf.cameras import Intrinsics, look_at
from nvf.config import STAGES, Precision
from nvf.device import resolve_device
from nvf.field import FieldOutput
from nvf.model import RenderResult, SceneModel
from nvf.precision import PRECISIONS, supported_precisions, unsupported_reason
from nvf.rendering import Samples
from nvf.training import train_model
from pipeline.bench._paired import IterationClock, Turn, lockstep
from pipeline.cli import fail
from pipeline.config.typed_run import Run
from pipeline.diagnostics.initial_view_model import CPU, InitialViewModel, load, observations
from pipeline.episode.evaluation import RENDER_CHUNK
from pipeline.episode.settings import EpisodeSettings
from pipeline.metrics.image import off_edge_psnr, psnr
from pipeline.scenes.ground_truth import Renderer
from pipeline.scenes.mesh_renderer import GroundTruthRenderer
from pipeline.scenes.scene import Scene

HELD_OUT_VIEWS = 5


RGB = frozenset({"rgb"})


class CountingModel(SceneModel):
    """A ``SceneModel`` counting the kept samples of every ``render`` call, and the marched samples its
    skipping pass evaluated."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.samples = 0
        self.marched = 0

    def _skip(self, samples: Samples, *args, **kwargs) -> tuple[Samples, FieldOutput | None, Tensor | None]:
        self.marched += samples.num_samples
        return super()._skip(samples, *args, **kwargs)

    def render(self, *args, **kwargs) -> RenderResult:
        result = super().render(*args, **kwargs)
        self.samples += result.samples.num_samples
        return result


def report_settings(
    cfg: Run,
    s: EpisodeSettings,
    training_views: int,
    image_size: object,
    precisions: object,
    overrides: list[str],
) -> dict[str, object]:
    """The settings every bench report names first: budget, scene, field, the training views and their
    image size, torch threads, the precisions compared and the command-line overrides."""
    return {
        "budget": cfg.budget.name,
        "scene": cfg.scene.name,
        "field_kind": s.field.kind,
        "field_backend": s.field.backend,
        "log2_hashmap_size": s.field.log2_hashmap_size,
        "training_views": training_views,
        "image_size": image_size,
        "torch_threads": torch.get_num_threads(),
        "precisions": precisions,
        "overrides": overrides,
    }


def same_initial_models(
    cfg: Run, scene: Scene, s: EpisodeSettings, names: list[str], model_cls: type[CountingModel]
) -> dict[str, CountingModel]:
    """One fresh model per name, all with the initial weights of ``torch.manual_seed(cfg.seed)``, on the
    run's device (``device``)."""
    models = {}
    for name in names:
        torch.manual_seed(int(cfg.seed))
        models[name] = model_cls(scene.object_aabb, s.field, s.sampler).to(resolve_device(str(cfg.device)))
    return models


def train_in_lockstep(
    models: dict[str, CountingModel], iterations: int, train: Callable[[str, CountingModel, IterationClock], None]
) -> dict[str, IterationClock]:
    """``train(name, model, progress)`` for every model side by side (``pipeline.bench._paired.lockstep``):
    the trainings take turns iteration by iteration. Returns each one's clock (its own turns only)."""
    clocks: dict[str, IterationClock] = {}

    def job(name: str) -> Callable[[Turn], None]:
        def run(turn: Turn) -> None:
            model = models[name]
            clocks[name] = IterationClock(lambda: (model.samples, model.marched), iterations, name, turn)
            train(name, model, clocks[name])
            clocks[name].bar.close()

        return run

    lockstep({name: job(name) for name in models})
    return clocks


def train_side_by_side(
    cfg: Run, precisions: list[str]
) -> tuple[dict[str, InitialViewModel], dict[str, IterationClock]]:
    """One ``InitialViewModel`` per ``train.precision``, its model a ``CountingModel``, from the same initial
    weights and seed, all three stages trained in lockstep (``train_in_lockstep``)."""
    scene = load(cfg)
    s = EpisodeSettings.of(cfg, scene)
    size = int(cfg.budget.image_size)
    renderer = GroundTruthRenderer(scene.mesh)
    device = resolve_device(str(cfg.device))
    obs = observations(renderer, scene.init_poses, Intrinsics.from_fov(size, size), device=device)
    models = same_initial_models(cfg, scene, s, precisions, CountingModel)

    def train(name: str, model: CountingModel, progress: IterationClock) -> None:
        generator = torch.Generator(device).manual_seed(int(cfg.seed))
        train_model(
            model,
            obs,
            dataclasses.replace(s.train, precision=Precision(name)),
            STAGES,
            s.entropy,
            generator,
            progress=progress,
        )

    clocks = train_in_lockstep(models, sum(getattr(s.train, stage).iters for stage in STAGES), train)
    setups = {
        name: InitialViewModel(cfg, scene, s, renderer, obs, models[name], clocks[name].wall[-1]) for name in precisions
    }
    return setups, clocks


def held_out_poses(
    scene: Scene, n: int = HELD_OUT_VIEWS, elevation_deg: float = 40.0, azimuth0_deg: float = 17.0
) -> Float[Tensor, "n 4 4"]:
    """Look-at ring around the tight box's centre at the evaluation views' distance (test_integration)."""
    centre = scene.tight_box.mean(0)
    radius = float(torch.linalg.norm(scene.eval_poses[0, :3, 3] - centre))
    phi = math.radians(elevation_deg)
    poses = []
    for i in range(n):
        theta = math.radians(azimuth0_deg + 360.0 * i / n)
        direction = [math.cos(theta) * math.cos(phi), math.sin(theta) * math.cos(phi), math.sin(phi)]
        offset = radius * torch.tensor(direction)
        poses.append(look_at(centre + offset, centre))
    return torch.stack(poses)


def view_psnr(
    model: SceneModel, renderer: Renderer, poses: Float[Tensor, "n 4 4"], intr: Intrinsics, gt_samples: int
) -> tuple[float, float]:
    """PSNR of the model's renders of ``poses`` against the ground truth (``gt_samples^2`` samples per
    pixel; pooled over the views), over all pixels and off the ground truth's edges
    (``pipeline.metrics.image.off_edge_psnr``)."""
    pred = np.stack([model.render_image(c2w, intr, chunk=RENDER_CHUNK)["rgb"].cpu().numpy() for c2w in poses])
    gt = np.stack([renderer.render_rgba(c2w, intr, gt_samples)[..., :3] for c2w in poses])
    return psnr(pred, gt), off_edge_psnr(pred, gt)


def default_precisions(device: torch.device) -> str:
    """``fp32,bf16`` where ``device`` runs bfloat16 natively, else ``fp32``."""
    return "fp32,bf16" if "bf16" in supported_precisions(device) else "fp32"


def parse_precisions(value: str | None, device: torch.device = CPU) -> list[str]:
    """``fp32,bf16`` -> the precisions to compare (the first is the reference of the ratios; ``None``:
    ``default_precisions(device)``); each must be one ``device`` runs natively (one line and exit status 2
    otherwise)."""
    value = default_precisions(device) if value is None else value
    names = [name.strip() for name in value.split(",") if name.strip()]
    for name in names:
        reason = (
            unsupported_reason(name, device)
            if name in PRECISIONS
            else (f"unknown precision; choose from {', '.join(PRECISIONS)}")
        )
        if reason is not None:
            fail(f"--precisions {name}: {reason}")
    if not names or len(set(names)) != len(names):
        fail(f"--precisions {value!r} must name distinct precisions, e.g. fp32,bf16")
    return names
