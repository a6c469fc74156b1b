"""Building scenes (PROTOCOL.md 2): each is declared once, in ``conf/scene/<name>.yaml`` (``SceneConfig`` in the
schema): kind, boxes, constants, view rigs (``pipeline.scenes.views``), and where its mesh comes from.
``load_scene`` builds the ``Scene`` an episode observes.

Where the mesh comes from (``source``):

- ``procedural``: ``pipeline.scenes.procedural``'s ``recipe``, used as built (the embedded ``default`` scene);
- ``proxy``: a procedural analogue (``recipe``) fitted uniformly into the tight box (PROTOCOL 2.2);
- ``mesh``: under the assets directory (``paths.assets``; default ``NVF_ASSETS``, else ``<repo>/data/assets``),
  the first file that exists of ``<name>/<name>.<blend|glb|gltf|ply|obj>`` (a .blend preferred; in the Z-up
  scene frame), then the yaml's ``files`` (each ``up: z`` or ``up: y``, a Y-up file rotated by (x, y, z) ->
  (x, -z, y)). With ``fit_tight_box`` the asset is scaled uniformly into the tight box (Hubble); otherwise
  its bounds must match the tight box to 5% of its diagonal (a Y-up export fails this check, with one line
  naming the fix). ``scene.asset`` names one file instead of the lookup (e.g. Room's metric OBJ where the
  assets also hold ``room/room.blend``).

A ``.blend`` is read by Blender (``pipeline.scenes.blender.export_blend``): the scene's mesh is its
render-visible triangles, each coloured with its material's base colour; the Blender backend renders the
file itself, the pyrender backend those flat-coloured triangles.
"""

import os
import posixpath
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import trimesh
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from torch import Tensor

from pipeline.config.catalog import declared
from pipeline.config.plain_containers import as_dict
from pipeline.config.structured_configs import SceneConfig, register_configs
from pipeline.records.schema import SceneSource
from pipeline.repo import CONF, REPO
from pipeline.scenes import procedural
from pipeline.scenes.blender import BlenderError, export_blend
from pipeline.scenes.blender import blender_python as default_python
from pipeline.scenes.meshes import read_mesh
from pipeline.scenes.scene import Scene, SceneError
from pipeline.scenes.views import rig_views

ASSET_EXTENSIONS = ("blend", "glb", "gltf", "ply", "obj")
SOURCES = ("mesh", "proxy", "procedural")  # declared; a mesh scene whose asset is a .blend is built as "blend"
FIT_TOLERANCE = 0.05  # of the tight box's diagonal
Y_UP_TO_Z_UP = np.array(
    [[1, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]], dtype=float
)  # (x, y, z) -> (x, -z, y)

__all__ = ["default_assets_dir", "find_asset", "load_scene", "read_asset", "scene_config", "scene_names"]


def default_assets_dir() -> Path:
    """``NVF_ASSETS`` if set, else ``<repo>/data/assets`` (the default of ``paths.assets``)."""
    return Path(os.environ.get("NVF_ASSETS", REPO / "data" / "assets"))


def _mesh_candidates(cfg: Mapping[str, Any], assets: Path) -> list[tuple[Path, str]]:
    """``(path, up axis)`` in lookup order: ``<name>/<name>.<ext>`` (Z-up), then the declared files; or the one
    file ``asset`` names (the up axis of the declared file of that path, else Z-up)."""
    name = cfg["name"]
    declared_files = [(posixpath.normpath(f["path"]), f.get("up", "z")) for f in cfg.get("files") or ()]
    if cfg.get("asset"):
        up = dict(declared_files).get(posixpath.normpath(cfg["asset"]), "z")  # a path written with ./ is the same file
        return [(assets / cfg["asset"], up)]
    own = [(assets / name / f"{name}.{ext}", "z") for ext in ASSET_EXTENSIONS]
    return own + [(assets / path, up) for path, up in declared_files]


def find_asset(cfg: Mapping[str, Any], assets: Path) -> tuple[Path, str]:
    """The asset file of a ``source: mesh`` scene and its up axis (lookup rule in the module docstring), or a
    one-line ``SceneError`` naming the files expected."""
    candidates = _mesh_candidates(cfg, assets)
    for path, up in candidates:
        if path.is_file():
            return path, up
    expected = " or ".join(str(p) for p, _ in candidates)
    proxy = (
        f"; or use scene '{cfg['name']}_proxy' (a procedural analogue)"
        if f"{cfg['name']}_proxy" in scene_names()
        else ""
    )
    named = " (scene.asset names it; null it for the lookup)" if cfg.get("asset") else ""
    raise SceneError(
        f"scene '{cfg['name']}': asset not found, expected {expected}{named}; set paths.assets or NVF_ASSETS to the "
        f"assets directory (the README's 'Scenes and assets' says where each scene's file comes from){proxy}"
    )


def _placed(cfg: Mapping[str, Any], mesh: trimesh.Trimesh, up: str, tight: np.ndarray, path: Path) -> np.ndarray:
    """Put an asset's triangles into the scene frame (PROTOCOL 2.2), in place: a Y-up file rotated,
    ``fit_tight_box`` scenes scaled uniformly into the tight box (bounding-box centre at its centre), the
    others checked against it. Returns the 4x4 transform applied."""
    transform = np.eye(4)
    if up == "y":
        transform = Y_UP_TO_Z_UP
        mesh.apply_transform(transform)
    if cfg.get("fit_tight_box", False):
        scale = float(np.min((tight[1] - tight[0]) / mesh.extents))
        mesh.apply_scale(scale)
        offset = (tight[0] + tight[1]) / 2.0 - mesh.bounds.mean(axis=0)
        mesh.apply_translation(offset)
        fit = np.diag([scale, scale, scale, 1.0])
        fit[:3, 3] = offset
        return fit @ transform
    mismatch = float(np.abs(mesh.bounds - tight).max())
    if mismatch > FIT_TOLERANCE * float(np.linalg.norm(tight[1] - tight[0])):
        fix = (
            "move and scale its objects into that box in Blender (Z-up, the scene frame), or hide helper objects "
            "from rendering"
            if path.suffix == ".blend"
            else "export it Z-up in the scene frame (Blender glTF: untick +Y Up)"
        )
        raise SceneError(
            f"scene '{cfg['name']}': {path} has bounds {np.round(mesh.bounds, 3).tolist()} but the scene's tight box "
            f"is {tight.tolist()}; {fix}; or, for a scene of your own, declare its boxes from the mesh: python -m "
            f"pipeline.scenes new NAME --mesh {path}"
        )
    return transform


def read_asset(path: Path, blender_python: Path | None = None) -> trimesh.Trimesh:
    """The coloured triangles of an asset: a .blend through Blender (``export_blend``), else ``read_mesh``."""
    if path.suffix != ".blend":
        return read_mesh(path)
    try:
        mesh = export_blend(path, blender_python or default_python())
    except BlenderError as exc:
        raise SceneError(f"cannot read {path}: {exc}") from None
    if not np.isfinite(mesh.vertices).all() or not mesh.area > 0.0 or not np.all(mesh.extents > 0.0):
        raise SceneError(f"{path} is degenerate (non-finite vertices, zero area or a flat bounding box)")
    return mesh


def _box(value: Any, key: str, name: str) -> np.ndarray:
    box = np.asarray(value, dtype=np.float64)
    if box.shape != (2, 3) or not np.isfinite(box).all() or not (box[1] > box[0]).all():
        raise SceneError(f"scene '{name}': {key}={box.tolist()} must be [[min x, y, z], [max x, y, z]] with min < max")
    return box


def _tensor(x: np.ndarray) -> Tensor:
    return torch.tensor(x, dtype=torch.float32)


@dataclass(frozen=True)
class _Built:
    """A scene's triangles in the scene frame and where they came from."""

    mesh: trimesh.Trimesh
    source: SceneSource
    asset: Path | None = None
    asset_to_scene: np.ndarray | None = None


def _mesh(cfg: Mapping[str, Any], tight: np.ndarray, assets_dir: Path | None, blender_python: Path | None) -> _Built:
    source = cfg["source"]
    if source not in SOURCES:
        raise SceneError(f"scene '{cfg['name']}': source={source!r} is not one of {', '.join(SOURCES)}")
    if source != "mesh" and cfg.get("asset"):
        raise SceneError(f"scene '{cfg['name']}': scene.asset names a file but source={source!r}; null scene.asset")
    if cfg.get("asset") is not None and not str(cfg["asset"]).strip():
        raise SceneError(f"scene '{cfg['name']}': scene.asset is empty; name a file under paths.assets, or null it")
    if source == "mesh":
        path, up = find_asset(cfg, Path(assets_dir) if assets_dir is not None else default_assets_dir())
        mesh = read_asset(path, blender_python)
        transform = _placed(cfg, mesh, up, tight, path)
        return _Built(mesh, "blend" if path.suffix == ".blend" else "mesh", path, transform)
    recipe = cfg.get("recipe")
    if recipe not in procedural.RECIPES:
        raise SceneError(
            f"scene '{cfg['name']}': recipe={recipe!r} is not one of {', '.join(procedural.RECIPES)} "
            "(pipeline.scenes.procedural)"
        )
    mesh = procedural.RECIPES[recipe]()
    if source == "proxy":
        return _Built(procedural.fit_into_box(mesh, tight), "proxy")
    return _Built(mesh, "procedural")


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
    return as_dict(cfg.scene)


def load_scene(
    scene: str | SceneConfig | Mapping[str, Any], assets_dir: Path | None = None, blender_python: Path | None = None
) -> Scene:
    """Build a declared scene: ``scene`` is its name, its typed config (``Run.scene``) or that config as a
    mapping (a record's ``scene``); mesh
    scenes read their asset from ``assets_dir`` (default ``default_assets_dir()``; a .blend with Blender's
    Python ``blender_python``, default ``pipeline.scenes.blender.blender_python()``). One-line
    ``SceneError`` on bad input."""
    if isinstance(scene, str):
        cfg = scene_config(scene)
    elif isinstance(scene, SceneConfig):
        cfg = asdict(scene)
    else:
        cfg = dict(scene)
    name = cfg["name"]
    tight = _box(cfg["tight_box"], "tight_box", name)
    built = _mesh(cfg, tight, assets_dir, blender_python)
    try:
        init, evals = rig_views(cfg["init_views"], tight, True), rig_views(cfg["eval_views"], tight, False)
    except (KeyError, TypeError, ValueError) as err:
        raise SceneError(f"scene '{name}': its view rigs (init_views, eval_views) are incomplete: {err}") from None
    return Scene(
        name=name,
        source=built.source,
        mesh=built.mesh,
        object_aabb=_tensor(_box(cfg["object_aabb"], "object_aabb", name)),
        camera_box=_tensor(_box(cfg["camera_box"], "camera_box", name)),
        tight_box=_tensor(tight),
        init_poses=init,
        eval_poses=evals,
        density_threshold=float(cfg["density_threshold"]),
        d0=float(cfg["d0"]),
        cr_threshold=float(cfg["cr_threshold"]),
        collision_free=bool(cfg["collision_free"]),
        asset=built.asset,
        asset_to_scene=built.asset_to_scene,
        declared_files=tuple(str(f["path"]) for f in cfg.get("files") or ()),
    )
