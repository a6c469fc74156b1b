"""Scenes (PROTOCOL.md 2): each declared once, in ``conf/scene/<name>.yaml`` (``SceneConfig`` in the schema):
kind, boxes, constants, view rigs (``pipeline.scenes.views``), and where its mesh comes from. ``load_scene``
builds the ``Scene`` an episode observes.

Where the mesh comes from (``source``):

- ``procedural``: ``pipeline.scenes.procedural``'s ``recipe``, used as built (the embedded ``default`` scene);
- ``proxy``: a procedural analogue (``recipe``) fitted uniformly into the tight box (PROTOCOL 2.2);
- ``mesh``: under the assets directory (``paths.assets``; default ``NVF_ASSETS``, else ``<repo>/data/assets``),
  the first file that exists of ``<name>/<name>.<glb|gltf|ply|obj>`` (in the Z-up scene frame), then the
  yaml's ``files`` (each ``up: z`` or ``up: y``, a Y-up file rotated by (x, y, z) -> (x, -z, y)). With
  ``fit_tight_box`` the mesh is scaled uniformly into the tight box (Hubble); otherwise its bounds must
  match the tight box to 5% of its diagonal (a Y-up export fails this check, with one line naming the fix).
"""

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import trimesh
from jaxtyping import Float
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from omegaconf import DictConfig, OmegaConf
from torch import Tensor

from pipeline.config.catalog import declared
from pipeline.config.schema import register_configs
from pipeline.repo import CONF, REPO
from pipeline.scenes import procedural
from pipeline.scenes.meshes import SceneError, read_mesh
from pipeline.scenes.views import rig_views

MESH_EXTENSIONS = ("glb", "gltf", "ply", "obj")
SOURCES = ("mesh", "proxy", "procedural")
FIT_TOLERANCE = 0.05  # of the tight box's diagonal
Y_UP_TO_Z_UP = np.array([[1, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]], dtype=float)  # (x, y, z) -> (x, -z, y)

__all__ = ["Scene", "SceneError", "default_assets_dir", "find_mesh", "load_scene", "scene_config", "scene_names"]


@dataclass(frozen=True, eq=False)
class Scene:
    """One benchmark scene (PROTOCOL.md 2): mesh in the Z-up scene frame, boxes, views and constants."""

    name: str
    source: str  # mesh | proxy | procedural
    mesh: trimesh.Trimesh
    object_aabb: Float[Tensor, "2 3"]
    camera_box: Float[Tensor, "2 3"]
    tight_box: Float[Tensor, "2 3"]
    init_poses: Float[Tensor, "n 4 4"]  # c2w, OpenGL axes
    eval_poses: Float[Tensor, "20 4 4"]
    density_threshold: float  # tau (M28)
    d0: float  # M13
    cr_threshold: float  # C.R. distance (PROTOCOL 4.2)
    collision_free: bool  # M29 candidate sampler (Room)

    @property
    def n_init(self) -> int:
        return int(self.init_poses.shape[0])


def default_assets_dir() -> Path:
    """``NVF_ASSETS`` if set, else ``<repo>/data/assets`` (the default of ``paths.assets``)."""
    return Path(os.environ.get("NVF_ASSETS", REPO / "data" / "assets"))


def _mesh_candidates(cfg: Mapping[str, Any], assets: Path) -> list[tuple[Path, str]]:
    """``(path, up axis)`` in lookup order: ``<name>/<name>.<ext>`` (Z-up), then the declared files."""
    name = cfg["name"]
    own = [(assets / name / f"{name}.{ext}", "z") for ext in MESH_EXTENSIONS]
    return own + [(assets / f["path"], f.get("up", "z")) for f in cfg.get("files") or ()]


def find_mesh(cfg: Mapping[str, Any], assets: Path) -> tuple[Path, str]:
    """The mesh file of a ``source: mesh`` scene and its up axis (lookup rule in the module docstring), or a
    one-line ``SceneError`` naming the files expected."""
    candidates = _mesh_candidates(cfg, assets)
    for path, up in candidates:
        if path.is_file():
            return path, up
    expected = " or ".join(str(p) for p, _ in candidates)
    proxy = f"; or use scene '{cfg['name']}_proxy' (a procedural analogue)" if f"{cfg['name']}_proxy" in scene_names() else ""
    raise SceneError(
        f"scene '{cfg['name']}': mesh not found, expected {expected}; set paths.assets or NVF_ASSETS to the assets "
        f"directory (the README's 'Scenes and assets' says where each scene's file comes from){proxy}"
    )


def _placed(cfg: Mapping[str, Any], mesh: trimesh.Trimesh, up: str, tight: np.ndarray, path: Path) -> trimesh.Trimesh:
    """Put a mesh into the scene frame (PROTOCOL 2.2): Y-up files rotated, ``fit_tight_box`` scenes scaled
    uniformly into the tight box (bounding-box centre at its centre), the others checked against it."""
    if up == "y":
        mesh.apply_transform(Y_UP_TO_Z_UP)
    if cfg.get("fit_tight_box", False):
        mesh.apply_scale(float(np.min((tight[1] - tight[0]) / mesh.extents)))
        mesh.apply_translation((tight[0] + tight[1]) / 2.0 - mesh.bounds.mean(axis=0))
        return mesh
    mismatch = float(np.abs(mesh.bounds - tight).max())
    if mismatch > FIT_TOLERANCE * float(np.linalg.norm(tight[1] - tight[0])):
        raise SceneError(
            f"scene '{cfg['name']}': mesh {path} has bounds {np.round(mesh.bounds, 3).tolist()} but the scene's tight "
            f"box is {tight.tolist()}; export it Z-up in the scene frame (Blender glTF: untick +Y Up)"
        )
    return mesh


def _box(value: Any, key: str, name: str) -> np.ndarray:
    box = np.asarray(value, dtype=np.float64)
    if box.shape != (2, 3) or not np.isfinite(box).all() or not (box[1] > box[0]).all():
        raise SceneError(f"scene '{name}': {key}={box.tolist()} must be [[min x, y, z], [max x, y, z]] with min < max")
    return box


def _tensor(x: np.ndarray) -> Tensor:
    return torch.tensor(x, dtype=torch.float32)


def _mesh(cfg: Mapping[str, Any], tight: np.ndarray, assets_dir: Path | None) -> trimesh.Trimesh:
    source = cfg["source"]
    if source not in SOURCES:
        raise SceneError(f"scene '{cfg['name']}': source={source!r} is not one of {', '.join(SOURCES)}")
    if source == "mesh":
        path, up = find_mesh(cfg, Path(assets_dir) if assets_dir is not None else default_assets_dir())
        return _placed(cfg, read_mesh(path), up, tight, path)
    recipe = cfg.get("recipe")
    if recipe not in procedural.RECIPES:
        raise SceneError(
            f"scene '{cfg['name']}': recipe={recipe!r} is not one of {', '.join(procedural.RECIPES)} (pipeline.scenes.procedural)"
        )
    mesh = procedural.RECIPES[recipe]()
    return procedural.fit_into_box(mesh, tight) if source == "proxy" else mesh


def scene_names() -> list[str]:
    """The declared scenes (``conf/scene/*.yaml``)."""
    return declared("scene")


def scene_config(name: str) -> dict[str, Any]:
    """The composed ``scene`` node of ``conf/scene/<name>.yaml`` (a one-line ``SceneError`` for an unknown name)."""
    if name not in scene_names():
        raise SceneError(f"unknown scene '{name}'; choose one of: {', '.join(scene_names())} (conf/scene/<name>.yaml)")
    register_configs()
    if GlobalHydra.instance().is_initialized():
        cfg = compose("config", overrides=[f"scene={name}"])
    else:
        with initialize_config_dir(str(CONF), version_base="1.3"):
            cfg = compose("config", overrides=[f"scene={name}"])
    return OmegaConf.to_container(cfg.scene, resolve=True)


def load_scene(scene: str | Mapping[str, Any] | DictConfig, assets_dir: Path | None = None) -> Scene:
    """Build a declared scene: ``scene`` is its name or its composed ``scene`` node (``cfg.scene``); mesh
    scenes read from ``assets_dir`` (default ``default_assets_dir()``). One-line ``SceneError`` on bad input."""
    if isinstance(scene, str):
        cfg = scene_config(scene)
    elif isinstance(scene, DictConfig):
        cfg = OmegaConf.to_container(scene, resolve=True)
    else:
        cfg = dict(scene)
    name = cfg["name"]
    tight = _box(cfg["tight_box"], "tight_box", name)
    mesh = _mesh(cfg, tight, assets_dir)
    try:
        init, evals = rig_views(cfg["init_views"], tight, True), rig_views(cfg["eval_views"], tight, False)
    except (KeyError, TypeError, ValueError) as err:
        raise SceneError(f"scene '{name}': its view rigs (init_views, eval_views) are incomplete: {err}") from None
    return Scene(
        name=name, source=cfg["source"], mesh=mesh,
        object_aabb=_tensor(_box(cfg["object_aabb"], "object_aabb", name)),
        camera_box=_tensor(_box(cfg["camera_box"], "camera_box", name)), tight_box=_tensor(tight),
        init_poses=init, eval_poses=evals, density_threshold=float(cfg["density_threshold"]), d0=float(cfg["d0"]),
        cr_threshold=float(cfg["cr_threshold"]), collision_free=bool(cfg["collision_free"]),
    )  # fmt: skip
