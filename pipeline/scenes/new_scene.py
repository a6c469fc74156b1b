"""A scene from a mesh in one command (``python -m pipeline.scenes new NAME --mesh FILE``): its yaml, with the boxes
PROTOCOL 2.1 derives for a scene of this benchmark's own (the embedded ``default``'s rule), written into a config
directory of the user's, outside the repository.

The tight box is the mesh's bounds (read Z-up, or rotated from Y-up with ``--up y``); the object AABB that box
widened by 10% of its extent on every side; the camera box the object AABB scaled 2.5 times about ``(0, 0,
z_min)`` (the Lego rule); the views from the rule of PROTOCOL 2.5; the constants an object scene's (3 initial
views, τ 1e-4, d0 1.0, C.R. 0.01, the base candidate sampler). The mesh stays where it is: the yaml names it
relative to its assets directory (the folder above the mesh's, when that folder is named after the scene, else
the mesh's own folder), which ``paths.assets`` then points at.
"""

from pathlib import Path

import numpy as np
from omegaconf import OmegaConf

from pipeline.atomic_write import atomic_write_text
from pipeline.scenes.loading import Y_UP_TO_Z_UP, read_asset, scene_names
from pipeline.scenes.scene import SceneError

MARGIN = 0.10  # of the tight box's extent on every side: the object AABB
CAMERA_SCALE = 2.5  # the camera box: the object AABB scaled about (0, 0, z_min), the Lego rule


def derived_boxes(bounds: np.ndarray) -> dict[str, list[list[float]]]:
    """PROTOCOL 2.1's boxes of a mesh with bounds ``[[min], [max]]``: tight, object (10% wider on every side) and
    camera (the object box x 2.5 about ``(0, 0, z_min)``), rounded to 6 decimals."""
    tight = np.asarray(bounds, dtype=np.float64)
    grow = MARGIN * (tight[1] - tight[0])
    box = np.stack([tight[0] - grow, tight[1] + grow])
    pivot = np.array([0.0, 0.0, box[0, 2]])
    camera = pivot + CAMERA_SCALE * (box - pivot)
    return {
        name: np.round(value, 6).tolist()
        for name, value in (("tight_box", tight), ("object_aabb", box), ("camera_box", camera))
    }


def assets_folder(name: str, mesh: Path) -> Path:
    """Where ``paths.assets`` points for ``mesh``: the folder above the mesh's when that folder is named ``name``
    (the ``<name>/<file>`` layout of the benchmark's assets), else the mesh's own folder."""
    return mesh.parent.parent if mesh.parent.name == name else mesh.parent


def scene_yaml(name: str, mesh: Path, up: str, bounds: np.ndarray) -> dict:
    """The yaml of scene ``name`` built from ``mesh`` (its bounds in the scene frame)."""
    return {
        "name": name,
        "kind": "object",
        "source": "mesh",
        "paper_scene": None,
        "nerf_asset": False,
        "rank": 50,
        "experiments": [],
        "files": [{"path": mesh.relative_to(assets_folder(name, mesh)).as_posix(), "up": up}],
        **derived_boxes(bounds),
        "density_threshold": 1.0e-4,
        "d0": 1.0,
        "cr_threshold": 0.01,
        "collision_free": False,
        "init_views": {"rig": "rule"},
        "eval_views": {"rig": "rule"},
    }


def new_scene(name: str, mesh: Path, conf: Path, up: str, blender_python: Path | None = None) -> Path:
    """Write ``conf/scene/<name>.yaml`` for ``mesh`` and return its path; a one-line ``SceneError`` for a name the
    benchmark declares, a yaml that exists, or a mesh that cannot be read."""
    if name in scene_names():
        raise SceneError(f"scene '{name}' is the benchmark's own; name yours otherwise")
    path = conf / "scene" / f"{name}.yaml"
    if path.exists():
        raise SceneError(f"{path} exists; remove it or name the scene otherwise")
    triangles = read_asset(mesh.resolve(), blender_python)
    if up == "y":
        triangles.apply_transform(Y_UP_TO_Z_UP)
    header = (
        f"# {name}: a scene of your own (python -m pipeline.scenes new), from {mesh.name}; boxes by PROTOCOL 2.1's "
        "rule for a scene\n# of this benchmark's own (tight box = the mesh's bounds, object box 10% wider, camera "
        "box x 2.5 about (0, 0, z_min)).\n"
    )
    body = OmegaConf.to_yaml(OmegaConf.create(scene_yaml(name, mesh.resolve(), up, triangles.bounds)))
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, header + body)
    return path
