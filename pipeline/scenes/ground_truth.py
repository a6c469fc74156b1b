"""The ground-truth renderer a run's config asks for (``render.backend``), and what its run record says
about it: which backend, which asset file, and for Blender the samples, device and version; whether a record
was made on the scene as built now."""

import os
from collections.abc import Mapping
from pathlib import Path

import torch

from pipeline.config.structured_configs import RenderConfig
from pipeline.scenes.blender import BlenderRenderer, missing_python
from pipeline.scenes.mesh_renderer import GroundTruthRenderer
from pipeline.scenes.scene import Scene, SceneError

Renderer = GroundTruthRenderer | BlenderRenderer


def renderer_problem(render: RenderConfig, python: Path) -> str | None:
    """Why ``render`` cannot run here (one line: the Blender backend without Blender's Python ``python``),
    or None."""
    if render.backend != "blender":
        return None
    reason = missing_python(python)
    return None if reason is None else f"render.backend=blender: {reason}"


def open_renderer(scene: Scene, render: RenderConfig, python: Path, threads: int | None = None) -> Renderer:
    """pyrender's ``GroundTruthRenderer`` or a ``BlenderRenderer`` (one Blender worker run by ``python``,
    ``render.samples`` samples per pixel, ``threads`` render threads, default torch's thread count,
    ``render.timeout`` seconds per view); close it when done. ``SceneError`` (``renderer_problem``) when the
    backend cannot run here."""
    problem = renderer_problem(render, python)
    if problem is not None:
        raise SceneError(problem)
    if render.backend == "blender":
        threads = threads or torch.get_num_threads()
        return BlenderRenderer(scene, int(render.samples), python, threads=threads, timeout=float(render.timeout))
    return GroundTruthRenderer(scene.mesh)


def ground_truth_info(scene: Scene, renderer: Renderer, assets: Path) -> dict:
    """The run record's ``ground_truth``: backend, asset (relative to ``assets`` where it lies under it, through
    its links or with them followed, else its absolute path: a file of the same name elsewhere is another asset)
    and, for Blender, samples per pixel, Cycles device and Blender version."""
    asset = None
    if scene.asset is not None:
        asset = scene.asset.resolve().as_posix()
        for file, folder in (
            (Path(os.path.abspath(scene.asset)), Path(os.path.abspath(assets))),  # links kept
            (scene.asset.resolve(), Path(assets).resolve()),
        ):
            if file.is_relative_to(folder):
                asset = file.relative_to(folder).as_posix()
                break
    if isinstance(renderer, BlenderRenderer):
        return {
            "backend": "blender",
            "asset": asset,
            "samples": renderer.samples,
            "device": renderer.device,
            "blender": renderer.version,
        }
    return {"backend": "pyrender", "asset": asset}


def built_differently(info: Mapping, scene: Scene) -> str | None:
    """How the scene a record's run.json (``info``) was made on differs from ``scene`` as built now: its
    ``scene_source`` (mesh, blend, proxy, procedural) or, where the record names it, its ``ground_truth.asset``
    (a path relative to the assets directory, or an absolute path; older records may name a file alone). A mesh
    record that predates ``ground_truth`` was built from one of its scene's declared ``files`` (the lookup of
    ``<name>/<name>.<ext>`` came later), so a build from another file differs. None when they agree."""
    source = info.get("scene_source")
    if source is not None and source != scene.source:
        return f"scene source ({source} in the record, {scene.source} now)"
    ground_truth = info.get("ground_truth")
    recorded = ground_truth.get("asset") if isinstance(ground_truth, Mapping) else None
    now = None if scene.asset is None else scene.asset.as_posix()
    if recorded is not None and (now is None or not ("/" + now).endswith("/" + str(recorded))):
        return f"scene asset ({recorded} in the record, {now} now)"
    declared = scene.declared_files
    if recorded is None and source == "mesh" and now is not None and declared:
        if not any(("/" + now).endswith("/" + path) for path in declared):
            return (
                f"scene asset (the record predates ground_truth.asset: it was built from the scene's declared file "
                f"{' or '.join(declared)}; {now} now)"
            )
    return None
