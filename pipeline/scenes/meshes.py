"""Reading a scene's mesh file: one coloured triangle mesh from glb/gltf/obj(+mtl)/ply, scene graphs
flattened, textures kept when every part has one (packed into one atlas), colours otherwise."""

from pathlib import Path
from typing import Any

import numpy as np
import trimesh
from PIL import Image

from pipeline.scenes.scene import SceneError


def _one_line(text: object) -> str:
    return " ".join(str(text).split())


def _has_texture(part: trimesh.Trimesh) -> bool:
    material = getattr(part.visual, "material", None)
    return getattr(part.visual, "kind", None) == "texture" and (
        getattr(material, "baseColorTexture", None) is not None or getattr(material, "image", None) is not None
    )


def _texture_tile(part: trimesh.Trimesh, width: int) -> tuple[np.ndarray, np.ndarray]:
    """A part's base-colour image (factor baked in, repetition of UVs outside [0, 1] unrolled) and UVs in [0, 1]."""
    visual: Any = part.visual  # trimesh's visual kinds (texture, vertex, face) have their own attributes: read by kind
    material = visual.material
    if not isinstance(material, trimesh.visual.material.PBRMaterial):
        material = material.to_pbr()
    image = np.asarray(material.baseColorTexture.convert("RGB"), dtype=np.float32)
    if material.baseColorFactor is not None:
        image = image * (np.asarray(material.baseColorFactor[:3], dtype=np.float32) / 255.0)
    uv = np.asarray(visual.uv, dtype=np.float64)
    start = np.floor(uv.min(axis=0))
    tiles = np.maximum(np.ceil(uv.max(axis=0) - start), 1).astype(int)
    tiled = np.tile(image, (tiles[1], tiles[0], 1))
    height = max(1, min(width, round(tiled.shape[0] * width / tiled.shape[1])))
    resized = Image.fromarray(np.clip(tiled, 0, 255).astype(np.uint8)).resize(
        (width, height), Image.Resampling.BILINEAR
    )
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
        atlas[top : top + h] = image
        uvs.append(np.stack([uv[:, 0], (total - top - h + uv[:, 1] * h) / total], axis=1))  # v counted from the bottom
        top += h
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
    material = trimesh.visual.material.PBRMaterial(baseColorTexture=Image.fromarray(atlas), doubleSided=True)
    return trimesh.Trimesh(
        vertices=np.concatenate([p.vertices for p in parts]),
        faces=np.concatenate([p.faces + o for p, o in zip(parts, offsets, strict=True)]),
        visual=trimesh.visual.TextureVisuals(uv=np.concatenate(uvs), material=material),
        process=False,
    )


def _to_colors(part: trimesh.Trimesh) -> trimesh.Trimesh:
    """Per-face colours from an untextured material's main colour, per-vertex ones sampled from a texture."""
    part = part.copy()
    visual: Any = part.visual  # trimesh's visual kinds (texture, vertex, face) have their own attributes: read by kind
    if visual.kind == "texture" and not _has_texture(part):
        part.visual = trimesh.visual.ColorVisuals(part, face_colors=visual.material.main_color)
    elif visual.kind == "texture":
        part.visual = visual.to_color()
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
    geometries = loaded.dump() if isinstance(loaded, trimesh.Scene) else [loaded]
    parts = [p for p in geometries if isinstance(p, trimesh.Trimesh) and len(p.faces) > 0]
    if not parts:
        raise SceneError(f"mesh {path} contains no triangles")
    if len(parts) == 1:
        mesh = parts[0]
    elif all(_has_texture(p) for p in parts):
        mesh = _atlas(parts)
    else:
        concatenated = trimesh.util.concatenate([_to_colors(p) for p in parts])
        assert isinstance(concatenated, trimesh.Trimesh), "triangle meshes concatenate to one"
        mesh = concatenated
    if not np.isfinite(mesh.vertices).all():
        raise SceneError(f"mesh {path} has non-finite (NaN/inf) vertex coordinates")
    if not mesh.area > 0.0 or not np.all(mesh.extents > 0.0):
        raise SceneError(f"mesh {path} is degenerate (zero area or flat bounding box)")
    return mesh
