"""The ground-truth renderer a run's config asks for (``render.backend``), and what its run record says
about it: which backend, which asset file, and for Blender the samples, device and version."""

from pathlib import Path

import torch
from omegaconf import DictConfig

from pipeline.scenes.blender import BlenderRenderer, blender_python
from pipeline.scenes.render import GroundTruthRenderer
from pipeline.scenes.scene import Scene

Renderer = GroundTruthRenderer | BlenderRenderer


def open_renderer(scene: Scene, cfg: DictConfig, threads: int | None = None) -> Renderer:
    """pyrender's ``GroundTruthRenderer`` or a ``BlenderRenderer`` (one Blender worker, ``render.samples``
    samples per pixel, ``threads`` render threads, default torch's thread count, ``render.timeout`` seconds
    per view); close it when done."""
    if cfg.render.backend == "blender":
        python = blender_python(cfg.paths.blender_python)
        threads = threads or torch.get_num_threads()
        return BlenderRenderer(
            scene, int(cfg.render.samples), python, threads=threads, timeout=float(cfg.render.timeout)
        )
    return GroundTruthRenderer(scene.mesh)


def ground_truth_info(scene: Scene, renderer: Renderer, assets: Path) -> dict:
    """The run record's ``ground_truth``: backend, asset (relative to ``assets`` where it lies under it) and,
    for Blender, samples per pixel, Cycles device and Blender version."""
    asset = None
    if scene.asset is not None:
        try:
            asset = scene.asset.resolve().relative_to(Path(assets).resolve()).as_posix()
        except ValueError:
            asset = scene.asset.name
    if isinstance(renderer, BlenderRenderer):
        return {
            "backend": "blender",
            "asset": asset,
            "samples": renderer.samples,
            "device": renderer.device,
            "blender": renderer.version,
        }
    return {"backend": "pyrender", "asset": asset}
