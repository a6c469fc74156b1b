"""Scene registry: meshes in the Z-up scene frame, boxes, constants and view rigs (PROTOCOL.md 2).

Scenes: the ten paper scenes (mesh-backed), ``default`` (embedded procedural object) and
``<name>_proxy`` for the seven NeRF-synthetic objects (procedural analogues, pipeline.procedural).

Asset lookup under the assets directory (argument, else ``NVF_ASSETS``, else ``<repo>/data/assets``;
the Hydra key is ``paths.assets``): the first of ``<name>/<name>.blend``, ``.glb``, ``.gltf``, ``.ply``,
``.obj`` that exists (a .blend is preferred over a mesh), then the development file names
``room/room_nvf_gt_yup.obj`` (+ .mtl; Y-up, mapped by (x, y, z) -> (x, -z, y)),
``hotdog/hotdog_nvf_geom_heuristic_colors.ply`` and ``hubble/hubble_nasaA_zup_m.glb``. Hubble's asset is
fitted uniformly into the tight box (PROTOCOL 2.2); every other asset must already be in the Z-up scene
frame: its bounds must match the PROTOCOL 2.1 tight box to 5% of its diagonal (a Y-up export fails).

A ``.blend`` is read by Blender (``pipeline.scenes.blender.export_blend``): the scene's mesh is its
render-visible triangles, each coloured with its material's base colour; the Blender backend renders the
file itself, the pyrender backend those flat-coloured triangles.
"""

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import trimesh
from jaxtyping import Float
from PIL import Image
from torch import Tensor

from nvf.cameras import Intrinsics, look_at
from pipeline.repo import REPO
from pipeline.scenes import procedural

Vec = Sequence[float | int] | np.ndarray  # a point or vector; beartype rejects ints as floats

NERF_OBJECTS = ("chair", "drums", "ficus", "lego", "materials", "mic", "ship")
PAPER_SCENES = ("chair", "drums", "ficus", "hotdog", "lego", "materials", "mic", "ship", "hubble", "room")
SCENE_NAMES = (*PAPER_SCENES, "default", *(f"{name}_proxy" for name in NERF_OBJECTS))
ASSET_EXTENSIONS = ("blend", "glb", "gltf", "ply", "obj")
FIXED_MESH_FILES = {
    "room": "room/room_nvf_gt_yup.obj",
    "hotdog": "hotdog/hotdog_nvf_geom_heuristic_colors.ply",
    "hubble": "hubble/hubble_nasaA_zup_m.glb",
}
S = 0.16665  # PROTOCOL 2.3: the reference's scale unit s; k = 6 s
K = 6 * S


class SceneError(Exception):
    """A scene cannot be built (unknown name, missing, unreadable or degenerate asset); one-line message."""


@dataclass(frozen=True, eq=False)
class Scene:
    """One benchmark scene (PROTOCOL.md 2): mesh in the Z-up scene frame, boxes, views and constants.

    ``asset`` is the file the ground truth comes from (None for proxies and the procedural default);
    ``asset_to_scene`` the similarity that placed its triangles in the scene frame (for a .blend, the
    Blender backend moves the cameras by its inverse instead)."""

    name: str
    source: str  # blend | mesh | proxy | procedural
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
    n_init: int
    asset: Path | None = None
    asset_to_scene: Float[np.ndarray, "4 4"] | None = None


@dataclass(frozen=True)
class _Spec:
    """PROTOCOL 2.1 boxes and constants of one scene; ``views`` names its view construction."""

    object_aabb: tuple[Vec, Vec]  # (min, max) corners
    camera_box: tuple[Vec, Vec]
    tight_box: tuple[Vec, Vec]
    views: str  # hubble | lego | hotdog | room | rule (PROTOCOL 2.5)
    n_init: int = 3
    density_threshold: float = 1e-4
    d0: float = 1.0
    cr_threshold: float = 0.01
    collision_free: bool = False


SPECS: dict[str, _Spec] = {
    "hubble": _Spec(((-1, -1.1, -1.1), (1, 1.1, 1.8)), ((-2.5, -2.75, -2.75), (2.5, 2.75, 4.5)),
                    ((-0.922, -1.003, -1.036), (0.922, 1.057, 1.752)), "hubble", density_threshold=1e-3),
    "lego": _Spec(((-0.7, -1.2, -0.345), (0.7, 1.2, 1.1)), ((-1.75, -3.0, -0.345), (1.75, 3.0, 3.2675)),
                  ((-0.638, -1.140, -0.345), (0.634, 1.149, 1.002)), "lego"),
    "hotdog": _Spec(((-1.3, -1.4, -0.189875), (1.3, 1.2, 0.5)), ((-2.8, -2.9, -0.189875), (2.8, 2.7, 3.5)),
                    ((-1.198, -1.286, -0.190), (1.198, 1.110, 0.312)), "hotdog", n_init=5),
    "room": _Spec(((-12.4, -4.5, -0.22), (4.1, 6.6, 5.2)), ((-12.4, -4.5, -0.22), (4.1, 6.6, 5.2)),
                  ((-12.4, -4.4, -0.216), (4.0, 6.53, 5.159)), "room", n_init=10, d0=6.0, cr_threshold=0.1,
                  collision_free=True),
    "chair": _Spec(((-0.8, -0.8, -0.994077), (0.8, 0.8, 1.1)), ((-2.5, -2.5, -0.994077), (2.5, 2.5, 5.6)),
                   ((-0.721, -0.695, -0.994), (0.658, 0.706, 1.050)), "rule"),
    "drums": _Spec(((-1.2, -0.8, -0.491643), (1.2, 1.0, 1.0)), ((-3.0, -2.0, -0.491643), (3.0, 2.5, 3.237464)),
                   ((-1.126, -0.746, -0.492), (1.122, 0.962, 0.938)), "rule"),
    "ficus": _Spec(((-0.4, -0.9, -1.033538), (0.6, 0.6, 1.2)), ((-1.0, -2.25, -1.033538), (1.5, 1.5, 4.550307)),
                   ((-0.378, -0.858, -1.034), (0.556, 0.578, 1.140)), "rule"),
    "materials": _Spec(((-1.2, -0.8, -0.231944), (1.2, 1.0, 0.3)), ((-2.7, -2.3, -0.231944), (2.7, 2.5, 3.3)),
                       ((-1.123, -0.759, -0.232), (1.072, 0.985, 0.199)), "rule"),
    "mic": _Spec(((-1.3, -1.0, -0.741353), (0.8, 1.2, 1.2)), ((-3.0, -2.7, -0.741353), (2.5, 2.9, 5.7)),
                 ((-1.251, -0.909, -0.741), (0.767, 1.082, 1.151)), "rule"),
    "ship": _Spec(((-1.35, -1.35, -0.549358), (1.45, 1.45, 0.73)), ((-3.05, -3.05, -0.119358), (3.15, 3.15, 4.03)),
                  ((-1.277, -1.300, -0.549), (1.371, 1.348, 0.729)), "rule"),
}


# ----------------------------------------------------------------------------------------------
# views (PROTOCOL 2.3-2.5)


def _look(position: Vec, target: Vec) -> Float[Tensor, "4 4"]:
    return look_at(torch.tensor(position, dtype=torch.float64), torch.tensor(target, dtype=torch.float64))


def _dir(theta_deg: float | int, phi_deg: float | int) -> np.ndarray:
    """``dir(theta, phi) = (sin phi cos theta, sin phi sin theta, cos phi)``, phi from +z (PROTOCOL 2.4)."""
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return np.array([math.sin(p) * math.cos(t), math.sin(p) * math.sin(t), math.cos(p)])


def ring_views(
    centre: Vec, centre_target: Vec, radius: float, thetas_deg: Vec,
    targets: Sequence[Vec],
) -> Float[Tensor, "n 4 4"]:
    """Views at ``P0 (r cos theta_i, r sin theta_i, 0, 1)^T`` looking at ``targets[i]`` (PROTOCOL 2.3)."""
    p0 = _look(centre, centre_target).to(torch.float64)
    poses = []
    for theta, target in zip(thetas_deg, targets, strict=True):
        t = math.radians(theta)
        offset = torch.tensor([radius * math.cos(t), radius * math.sin(t), 0.0, 1.0], dtype=torch.float64)
        poses.append(_look((p0 @ offset)[:3].tolist(), target))
    return torch.stack(poses)


def lego_layout(
    centre: Vec, semi_axes: Vec, target: Vec,
    top: Vec, top_target: Vec,
) -> Float[Tensor, "20 4 4"]:
    """Lego's 20 evaluation views: phi = 30 (4), 60 (6), 90 (9) deg rings at ``centre + a * dir``, then a top view."""
    angles = [(30.0, 90.0 * j) for j in range(4)] + [(60.0, 60.0 * j) for j in range(6)]
    angles += [(90.0, 40.0 * j) for j in range(9)]
    c, a = np.asarray(centre, float), np.asarray(semi_axes, float)
    poses = [_look(c + a * _dir(theta, phi), target) for phi, theta in angles]
    return torch.stack([*poses, _look(top, top_target)])


def _hubble_views() -> tuple[Tensor, Tensor]:
    init = ring_views((1.7 * K, 1.7 * K, 0.35 * K), (0, 0, 0.35 * K), 0.5 * K, (0, 120, 240),
                      [(0, 0, K * z) for z in (-0.15, 0.35, 0.85)])
    t, a = np.array([0, 0, 2 * S]), np.array([10.4 * S, 10.4 * S, 15 * S])
    poses = [_look(t + a * _dir(theta, phi), t) for theta in range(0, 360, 60) for phi in (45, 90, 135)]
    poses += [_look((0, 0, 13.5 * S), t), _look((0, 0, -9 * S), t)]
    return init, torch.stack(poses)


def _lego_views() -> tuple[Tensor, Tensor]:
    init = ring_views((0, 2.2, 0.35), (0, 0, 0.35), 0.3, (0, 120, 240), [(0, 0, z) for z in (-0.3, 0.15, 0.6)])
    t = (0, 0, 0.35)
    return init, lego_layout(t, (1.5, 2.0, 1.7), t, (0, 0, 1.7), t)


def _hotdog_views() -> tuple[Tensor, Tensor]:
    init = ring_views((0, 0, 1.2), (0, 0, 0), 1.5, [72.0 * i for i in range(5)],
                      [(0, 0, -0.15 + 0.075 * i) for i in range(5)])
    return init, lego_layout((0, -0.088056, 0.4), (1.6, 1.6, 1.3), (0, 0, 0), (0, 0, 1.7), (0, 0, 0.35))


def _straight_down(x: float, y: float, z: float, theta_deg: float) -> Float[Tensor, "4 4"]:
    """Translation times ``R_z(theta)``: camera x axis (cos, sin, 0), camera z axis +z (PROTOCOL 2.4 Room)."""
    t = math.radians(theta_deg)
    c2w = torch.eye(4, dtype=torch.float64)
    c2w[:2, :2] = torch.tensor([[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]], dtype=torch.float64)
    c2w[:3, 3] = torch.tensor([x, y, z], dtype=torch.float64)
    return c2w.to(torch.float32)


def _room_views() -> tuple[Tensor, Tensor]:
    centre, centre_target = (0.7 * K, 2.0 * K, 2.35 * K), (-2, 2, 0.35 * K)
    ring = ring_views(centre, centre_target, 2 * K, [40.0 * i for i in range(9)],
                      [(0, 0, K * (-0.15 + i / 8)) for i in range(9)])
    init = torch.cat([_look(centre, centre_target)[None], ring])
    poses = [_straight_down(4 * math.cos(t), 4 * math.sin(t), 4.0, math.degrees(t))
             for t in (math.radians(72 * i) for i in range(5))]
    poses += [_straight_down(3 * math.cos(t) - 8, 3 * math.sin(t) - 1, 4.0, math.degrees(t))
              for t in (math.radians(36 * i) for i in range(10))]
    poses += [_straight_down(3 * math.cos(t) - 3, 3 * math.sin(t) + 2, 4.0, math.degrees(t))
              for t in (math.radians(72 * i) for i in range(5))]
    return init, torch.stack(poses)


def _r05(x: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(x) / 0.05) * 0.05


def _ceil05(x: np.ndarray) -> np.ndarray:
    return np.ceil(np.asarray(x) / 0.05 - 1e-6) * 0.05


def rule_parameters(tight_box: Float[np.ndarray, "2 3"]) -> dict[str, np.ndarray]:
    """PROTOCOL 2.5 rule: target ``t``, semi-axes ``a``, ``top`` view, centre ``P0`` and ring targets ``z``."""
    lo, hi = tight_box
    c, h = (lo + hi) / 2.0, (hi - lo) / 2.0
    return {
        "t": _r05(c),
        "a": _ceil05(h + np.array([0.85, 0.85, 1.0])),
        "top": _r05(np.array([c[0], c[1], hi[2] + 0.7])),
        "P0": _r05(np.array([c[0], c[1] + h[1] + 1.05, c[2]])),
        "z": _r05(lo[2] + np.array([0.04, 0.375, 0.71]) * 2.0 * h[2]),
    }


def rule_views(tight_box: Float[np.ndarray, "2 3"]) -> tuple[Float[Tensor, "3 4 4"], Float[Tensor, "20 4 4"]]:
    """Initial and evaluation views by analogy with Lego from a tight box (PROTOCOL 2.5)."""
    p = rule_parameters(tight_box)
    t = p["t"]
    init = ring_views(p["P0"], t, 0.3, (0, 120, 240), [(t[0], t[1], z) for z in p["z"]])
    return init, lego_layout(t, p["a"], t, p["top"], t)


_VIEWS = {"hubble": _hubble_views, "lego": _lego_views, "hotdog": _hotdog_views, "room": _room_views}


# ----------------------------------------------------------------------------------------------
# meshes


def default_assets_dir() -> Path:
    """``NVF_ASSETS`` if set, else ``<repo>/data/assets`` (the default of ``paths.assets``)."""
    return Path(os.environ.get("NVF_ASSETS", REPO / "data" / "assets"))


def _one_line(text: object) -> str:
    return " ".join(str(text).split())


def _has_texture(part: trimesh.Trimesh) -> bool:
    material = getattr(part.visual, "material", None)
    return part.visual.kind == "texture" and (
        getattr(material, "baseColorTexture", None) is not None or getattr(material, "image", None) is not None
    )


def _texture_tile(part: trimesh.Trimesh, width: int) -> tuple[np.ndarray, np.ndarray]:
    """A part's base-colour image (factor baked in, repetition of UVs outside [0, 1] unrolled) and UVs in [0, 1]."""
    material = part.visual.material
    if not isinstance(material, trimesh.visual.material.PBRMaterial):
        material = material.to_pbr()
    image = np.asarray(material.baseColorTexture.convert("RGB"), dtype=np.float32)
    if material.baseColorFactor is not None:
        image = image * (np.asarray(material.baseColorFactor[:3], dtype=np.float32) / 255.0)
    uv = np.asarray(part.visual.uv, dtype=np.float64)
    start = np.floor(uv.min(axis=0))
    tiles = np.maximum(np.ceil(uv.max(axis=0) - start), 1).astype(int)
    tiled = np.tile(image, (tiles[1], tiles[0], 1))
    height = max(1, min(width, round(tiled.shape[0] * width / tiled.shape[1])))
    resized = Image.fromarray(np.clip(tiled, 0, 255).astype(np.uint8)).resize((width, height), Image.BILINEAR)
    return np.asarray(resized), (uv - start) / tiles


def _atlas(parts: list[trimesh.Trimesh], width: int = 1024) -> trimesh.Trimesh:
    """One textured mesh from textured parts: their images stacked vertically in one atlas, UVs remapped.

    (trimesh's own packing garbles these textures and cannot handle repeating UVs.)
    """
    tiles = [_texture_tile(p, width) for p in parts]
    total = sum(image.shape[0] for image, _ in tiles)
    atlas, uvs, top = np.zeros((total, width, 3), dtype=np.uint8), [], 0
    for image, uv in tiles:
        h = image.shape[0]
        atlas[top:top + h] = image
        uvs.append(np.stack([uv[:, 0], (total - top - h + uv[:, 1] * h) / total], axis=1))  # v measured from the bottom
        top += h
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
    material = trimesh.visual.material.PBRMaterial(baseColorTexture=Image.fromarray(atlas), doubleSided=True)
    return trimesh.Trimesh(
        vertices=np.concatenate([p.vertices for p in parts]),
        faces=np.concatenate([p.faces + o for p, o in zip(parts, offsets, strict=True)]),
        visual=trimesh.visual.TextureVisuals(uv=np.concatenate(uvs), material=material), process=False,
    )


def _to_colors(part: trimesh.Trimesh) -> trimesh.Trimesh:
    """Per-face colours from an untextured material's main colour, per-vertex ones sampled from a texture."""
    part = part.copy()
    if part.visual.kind == "texture" and not _has_texture(part):
        part.visual = trimesh.visual.ColorVisuals(part, face_colors=part.visual.material.main_color)
    elif part.visual.kind == "texture":
        part.visual = part.visual.to_color()
    return part


def read_mesh(path: Path) -> trimesh.Trimesh:
    """One coloured triangle mesh from a glb/gltf/obj(+mtl)/ply file; scene graphs are flattened.

    Textures are kept when every part has one; otherwise every part gets colours. Raises
    ``SceneError`` for unreadable, empty or degenerate (non-finite, zero-area) meshes.
    """
    try:
        loaded = trimesh.load(path, process=False)
    except Exception as exc:  # trimesh raises many kinds for bad files
        raise SceneError(f"cannot read mesh {path}: {type(exc).__name__}: {_one_line(exc)}") from None
    parts = loaded.dump() if isinstance(loaded, trimesh.Scene) else [loaded]
    parts = [p for p in parts if isinstance(p, trimesh.Trimesh) and len(p.faces) > 0]
    if not parts:
        raise SceneError(f"mesh {path} contains no triangles")
    if len(parts) == 1:
        mesh = parts[0]
    elif all(_has_texture(p) for p in parts):
        mesh = _atlas(parts)
    else:
        mesh = trimesh.util.concatenate([_to_colors(p) for p in parts])
    if not np.isfinite(mesh.vertices).all():
        raise SceneError(f"mesh {path} has non-finite (NaN/inf) vertex coordinates")
    if not mesh.area > 0.0 or not np.all(mesh.extents > 0.0):
        raise SceneError(f"mesh {path} is degenerate (zero area or flat bounding box)")
    return mesh


def _asset_candidates(name: str, assets: Path) -> list[Path]:
    fixed = [assets / FIXED_MESH_FILES[name]] if name in FIXED_MESH_FILES else []
    return [assets / name / f"{name}.{ext}" for ext in ASSET_EXTENSIONS] + fixed


def find_asset(name: str, assets: Path) -> Path:
    """The asset file of paper scene ``name`` (lookup rule in the module docstring) or a one-line ``SceneError``."""
    candidates = _asset_candidates(name, assets)
    for path in candidates:
        if path.is_file():
            return path
    expected = " or ".join(str(p) for p in candidates)
    hint = ""
    if name in NERF_OBJECTS:
        hint = (f"; or use scene '{name}_proxy' (procedural analogue); the README says where {name}.blend comes "
                f"from; a glTF export of it (File > Export > glTF 2.0, Include > Transform > +Y Up unticked) "
                f"works too, saved as {assets / name / (name + '.glb')}")
    raise SceneError(f"scene '{name}': asset not found, expected {expected}; set paths.assets or NVF_ASSETS to the "
                     f"assets directory{hint}")


def _placed(name: str, mesh: trimesh.Trimesh, tight: np.ndarray, path: Path) -> np.ndarray:
    """Put a paper scene's asset into the scene frame (PROTOCOL 2.2), in place; returns the 4x4 transform applied."""
    transform = np.eye(4)
    if name == "room" and path.name == Path(FIXED_MESH_FILES["room"]).name:  # Y-up -> Z-up: (x, y, z) -> (x, -z, y)
        transform = np.array([[1, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]], dtype=float)
        mesh.apply_transform(transform)
    if name == "hubble":  # uniform scale into the tight box, bounding-box centre at its centre
        scale = float(np.min((tight[1] - tight[0]) / mesh.extents))
        mesh.apply_scale(scale)
        offset = (tight[0] + tight[1]) / 2.0 - mesh.bounds.mean(axis=0)
        mesh.apply_translation(offset)
        transform = np.diag([scale, scale, scale, 1.0])
        transform[:3, 3] = offset
        return transform
    mismatch = float(np.abs(mesh.bounds - tight).max())
    if mismatch > 0.05 * float(np.linalg.norm(tight[1] - tight[0])):
        fix = ("move and scale its objects into that box in Blender (Z-up, the NeRF-synthetic frame), or hide helper "
               "objects from rendering" if path.suffix == ".blend" else "export it Z-up in the scene frame (Blender "
               "glTF: untick +Y Up)")
        raise SceneError(f"scene '{name}': {path} has bounds {np.round(mesh.bounds, 3).tolist()} but the "
                         f"PROTOCOL 2.1 tight box is {tight.tolist()}; {fix}")
    return transform


def read_asset(path: Path, blender_python: Path | None = None) -> trimesh.Trimesh:
    """The coloured triangles of an asset: a .blend through Blender (``export_blend``), else ``read_mesh``."""
    if path.suffix != ".blend":
        return read_mesh(path)
    from pipeline.scenes.blender import BlenderError, blender_python as default_python, export_blend

    try:
        mesh = export_blend(path, blender_python or default_python())
    except BlenderError as exc:
        raise SceneError(f"cannot read {path}: {exc}") from None
    if not np.isfinite(mesh.vertices).all() or not mesh.area > 0.0 or not np.all(mesh.extents > 0.0):
        raise SceneError(f"{path} is degenerate (non-finite vertices, zero area or a flat bounding box)")
    return mesh


# ----------------------------------------------------------------------------------------------
# registry


def _lego_rule_camera_box(aabb: np.ndarray) -> np.ndarray:
    """Object AABB x 2.5 about (0, 0, z_min) (PROTOCOL 2.1, camera-box rule of lego)."""
    anchor = np.array([0.0, 0.0, aabb[0, 2]])
    return anchor + 2.5 * (aabb - anchor)


def _tensor(x) -> Tensor:
    return torch.tensor(np.array(x, dtype=np.float64), dtype=torch.float32)


def _default_scene() -> Scene:
    mesh = procedural.default_object()
    tight = np.asarray(mesh.bounds, dtype=np.float64)
    aabb = tight + np.array([-0.1, 0.1])[:, None] * (tight[1] - tight[0])
    init, evals = rule_views(tight)
    return Scene(name="default", source="procedural", mesh=mesh, object_aabb=_tensor(aabb),
                 camera_box=_tensor(_lego_rule_camera_box(aabb)), tight_box=_tensor(tight), init_poses=init,
                 eval_poses=evals, density_threshold=1e-4, d0=1.0, cr_threshold=0.01, collision_free=False, n_init=3)


def load_scene(name: str, assets_dir: Path | None = None, blender_python: Path | None = None) -> Scene:
    """Build scene ``name`` (one of ``SCENE_NAMES``); paper scenes read their asset from ``assets_dir``
    (a .blend with Blender's Python ``blender_python``, default ``pipeline.scenes.blender.blender_python()``)."""
    if name not in SCENE_NAMES:
        raise SceneError(f"unknown scene '{name}'; choose one of: {', '.join(SCENE_NAMES)}")
    if name == "default":
        return _default_scene()
    base = name.removesuffix("_proxy")
    spec = SPECS[base]
    tight = np.array(spec.tight_box, dtype=np.float64)
    path = transform = None
    if name.endswith("_proxy"):
        mesh, source = procedural.build_proxy(base, tight), "proxy"
    else:
        path = find_asset(base, Path(assets_dir) if assets_dir is not None else default_assets_dir())
        mesh = read_asset(path, blender_python)
        transform = _placed(base, mesh, tight, path)
        source = "blend" if path.suffix == ".blend" else "mesh"
    init, evals = _VIEWS[spec.views]() if spec.views in _VIEWS else rule_views(tight)
    return Scene(name=name, source=source, mesh=mesh, object_aabb=_tensor(spec.object_aabb),
                 camera_box=_tensor(spec.camera_box), tight_box=_tensor(tight), init_poses=init, eval_poses=evals,
                 density_threshold=spec.density_threshold, d0=spec.d0, cr_threshold=spec.cr_threshold,
                 collision_free=spec.collision_free, n_init=spec.n_init, asset=path, asset_to_scene=transform)
