"""Ground-truth renderer: RGB, depth, hit mask and per-pixel face ids of a mesh, headless (PROTOCOL.md 1, 4.3).

``GroundTruthRenderer`` is the pyrender backend (``render.backend=pyrender``): RGB and depth from
pyrender (unlit, ``RenderFlags.FLAT``: the RGB is the object colour, black where the mesh is missed).
Face ids, visibility and occupancy come from ``MeshRays``, open3d ray casting of the exact pixel-centre
rays of ``nvf.cameras.pixel_rays``, so they do not depend on rasterisation or multisampling; the Blender
backend (``pipeline.scenes.blender``) shares it.

pyrender is imported lazily, after ``PYOPENGL_PLATFORM`` is chosen (osmesa on CPU, egl on CUDA).
Importing ``triton`` *after* pyrender with OSMesa segfaults on the CPU machine kind (two LLVM copies
clash), while importing it *before* pyrender works; torchvision, lpips and torch._dynamo
import triton, so ``_import_pyrender`` imports triton first whenever it is installed.
"""

import importlib
import importlib.util
import math
import os
import sys
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
import trimesh
from jaxtyping import Bool, Float, Int
from PIL import Image
from torch import Tensor

from nvf.cameras import Intrinsics, pixel_rays
from nvf.device import resolve_device
from nvf.visibility import frustum_mask

BACKENDS = ("auto", "osmesa", "egl")


@dataclass
class GTView:
    """One ground-truth view (PROTOCOL.md 1): black background, depth along the camera's -z axis."""

    rgb: Float[np.ndarray, "H W 3"]  # float32 in [0, 1]
    depth: Float[np.ndarray, "H W"]  # float32, 0 where the mesh is missed
    mask: Bool[np.ndarray, "H W"]
    face_id: Int[np.ndarray, "H W"]  # int64, -1 where the mesh is missed


def resolve_backend(backend: str) -> str:
    """``osmesa`` or ``egl``: an explicit argument wins, then an existing ``PYOPENGL_PLATFORM``, then CUDA."""
    if backend not in BACKENDS:
        raise ValueError(f"renderer backend must be one of {BACKENDS}, got {backend!r}")
    if backend != "auto":
        return backend
    return os.environ.get("PYOPENGL_PLATFORM") or ("egl" if resolve_device("auto").type == "cuda" else "osmesa")


def _import_pyrender(platform: str):
    """Import pyrender for ``platform``; PyOpenGL fixes its platform at first import, so it cannot change later."""
    current = os.environ.get("PYOPENGL_PLATFORM")
    if "OpenGL" in sys.modules and current != platform:
        raise RuntimeError(
            f"PyOpenGL is already loaded for platform {current!r}; cannot switch the renderer to {platform!r} "
            "in this process (set PYOPENGL_PLATFORM before anything imports pyrender/OpenGL)"
        )
    os.environ["PYOPENGL_PLATFORM"] = platform
    if importlib.util.find_spec("triton") is not None:
        importlib.import_module("triton")  # before pyrender: see the module docstring (LLVM clash under OSMesa)
    return importlib.import_module("pyrender")


@dataclass
class CornerColors:
    """A mesh's base colour per triangle corner (sRGB values in [0, 1]), or per-corner UVs into a texture."""

    colors: Float[np.ndarray, "C 4"] | None
    uv: Float[np.ndarray, "C 2"] | None
    texture: Image.Image | None  # scaled by ``factor``
    factor: Float[np.ndarray, "4"]


def corner_colors(part: trimesh.Trimesh) -> CornerColors:
    """Vertex/face colours or a base-colour texture of ``part``, unrolled to its triangles' corners
    (``C = 3 F``, in face order), as both ground-truth backends draw them."""
    visual: Any = part.visual  # trimesh's visual kinds (texture, vertex, face) have their own attributes: read by kind
    colors = uv = texture = None
    factor = np.ones(4)
    if visual.kind == "texture" and getattr(visual.material, "baseColorTexture", None) is not None:
        uv = visual.uv[part.faces].reshape(-1, 2).astype(np.float32)
        texture = visual.material.baseColorTexture
        if visual.material.baseColorFactor is not None:
            factor = np.asarray(visual.material.baseColorFactor, dtype=np.float64) / 255.0
    elif visual.kind == "vertex":
        colors = visual.vertex_colors[part.faces].reshape(-1, 4)
    elif visual.kind == "face":
        colors = np.repeat(visual.face_colors, 3, axis=0)
    else:
        colors = np.repeat(visual.to_color().face_colors, 3, axis=0) if visual.defined else None
    if colors is not None:
        colors = colors.astype(np.float32) / 255.0
    return CornerColors(colors=colors, uv=uv, texture=texture, factor=factor)


def _as_opaque_primitive(pyrender, part: trimesh.Trimesh):
    """One unlit, double-sided pyrender primitive per part: vertex/face colours or a base-colour texture."""
    positions = part.vertices[part.faces].reshape(-1, 3).astype(np.float32)
    corners = corner_colors(part)
    material = pyrender.MetallicRoughnessMaterial(
        baseColorFactor=corners.factor, baseColorTexture=corners.texture, alphaMode="OPAQUE", doubleSided=True
    )
    return pyrender.Primitive(
        positions=positions, color_0=corners.colors, texcoord_0=corners.uv, material=material, mode=4
    )


def base_color_texture_mesh(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Textured meshes with a non-PBR material get a PBR copy so the base-colour texture is found."""
    visual: Any = mesh.visual  # trimesh's visual kinds (texture, vertex, face) have their own attributes: read by kind
    if visual.kind == "texture" and not isinstance(visual.material, trimesh.visual.material.PBRMaterial):
        mesh = mesh.copy()
        copied: Any = mesh.visual
        copied.material = visual.material.to_pbr()
    return mesh


def as_pose(c2w: Float[Tensor, "4 4"] | Float[np.ndarray, "4 4"]) -> Float[np.ndarray, "4 4"]:
    """A c2w pose as a float64 numpy array."""
    pose = c2w.detach().cpu().numpy() if isinstance(c2w, Tensor) else np.asarray(c2w)
    return pose.astype(np.float64)


class MeshRays:
    """Exact open3d ray casting on a mesh's triangles: face ids, visibility, occupancy, and the depth and
    hit mask of a view. Both ground-truth backends (pyrender here, Blender in ``pipeline.scenes.blender``)
    answer these from it, so geometry metrics, coverage and Vis. do not depend on the backend."""

    def __init__(self, mesh: trimesh.Trimesh) -> None:
        import open3d as o3d  # after pyrender's platform is set (GroundTruthRenderer); open3d-cpu is headless

        self.mesh = mesh
        self._bounds = np.asarray(mesh.bounds, dtype=np.float64)
        self._o3d = o3d
        self._raycaster = o3d.t.geometry.RaycastingScene()
        self._raycaster.add_triangles(
            self._tensor(np.ascontiguousarray(mesh.vertices, dtype=np.float32)),
            self._tensor(np.ascontiguousarray(mesh.faces, dtype=np.uint32)),
        )

    def _tensor(self, array: np.ndarray):
        """``array`` as an open3d tensor (a copy, its dtype, on the CPU)."""
        # open3d's generated stubs list dtype and device without their defaults (None: the array's, the CPU)
        return self._o3d.core.Tensor(array)  # type: ignore[call-overload]

    def cast_rays(
        self, origins: Float[np.ndarray, "N 3"], dirs: Float[np.ndarray, "N 3"]
    ) -> tuple[Float[np.ndarray, " N"], Int[np.ndarray, " N"]]:
        """Exact ray casting (open3d): hit distance along ``dirs`` (inf = miss) and face id (-1 = miss)."""
        rays = np.concatenate([origins, dirs], axis=-1).astype(np.float32)
        hits = self._raycaster.cast_rays(self._tensor(rays))
        t_hit = hits["t_hit"].numpy()
        ids = hits["primitive_ids"].numpy().astype(np.int64)
        ids[~np.isfinite(t_hit)] = -1
        return t_hit, ids

    def line_of_sight(
        self, points: Float[Tensor, "N 3"], c2w: Float[Tensor, "M 4 4"], intr: Intrinsics, margin: float = 0.0
    ) -> Bool[Tensor, " N"]:
        """Exact visibility of ``points`` from the cameras ``c2w``: some camera has the point in its
        image (M17's frustum, no depth limit) and an unoccluded line of sight to it (open3d ray cast
        from the camera centre, 1e-4 tolerance). The limit of a depth test at infinite resolution.
        ``margin``: each segment stops this far (scene units) short of the point, as M17's with
        ``train.label_margin``. On the CPU."""
        visible = torch.zeros(points.shape[0], dtype=torch.bool)
        points = points.detach().cpu().to(torch.float32)
        for pose in c2w.detach().cpu().to(torch.float32):
            origin = pose[:3, 3]
            ends = points
            if margin > 0:
                to_point = points - origin
                length = torch.linalg.norm(to_point, dim=-1, keepdim=True)
                ends = origin + to_point * ((length - margin).clamp(min=0.0) / length.clamp(min=1e-12))
            visible |= frustum_mask(points, pose, intr, math.inf) & self.unoccluded(origin, ends)
        return visible

    def unoccluded(self, origin: Float[Tensor, "3"], points: Float[Tensor, "N 3"]) -> Bool[Tensor, " N"]:
        """Whether the segment from ``origin`` to each point crosses no face (open3d ray cast, 1e-4
        tolerance; a point at the origin is unoccluded). On ``points``' device."""
        device = points.device
        origin = origin.detach().cpu().to(torch.float32)
        to_point = points.detach().cpu().to(torch.float32) - origin
        distance = torch.linalg.norm(to_point, dim=-1)
        dirs = to_point / distance.clamp(min=1e-12)[:, None]
        t_hit, _ = self.cast_rays(origin.expand_as(to_point).numpy(), dirs.numpy())
        return (torch.from_numpy(t_hit >= distance.numpy() - 1e-4) | (distance == 0)).to(device)

    def inside(self, points: Float[Tensor, "N 3"]) -> Bool[Tensor, " N"]:
        """Whether each point lies inside the mesh (open3d's occupancy query, which assumes a
        watertight mesh: near an open edge a point can be misjudged). On ``points``' device."""
        query = self._tensor(points.detach().cpu().to(torch.float32).numpy())
        return torch.from_numpy(self._raycaster.compute_occupancy(query).numpy() > 0.5).to(points.device)

    def face_ids(self, c2w: Float[np.ndarray, "4 4"], intr: Intrinsics) -> Int[np.ndarray, "H W"]:
        """Face hit by each pixel-centre ray (``nvf.cameras.pixel_rays``), -1 = miss (PROTOCOL.md 4.3)."""
        origins, dirs = pixel_rays(torch.from_numpy(c2w.astype(np.float32)), intr)
        return self.cast_rays(origins.numpy(), dirs.numpy())[1].reshape(intr.height, intr.width)

    def ray_cast_view(
        self, c2w: Float[np.ndarray, "4 4"], intr: Intrinsics
    ) -> tuple[Float[np.ndarray, "H W"], Bool[np.ndarray, "H W"], Int[np.ndarray, "H W"]]:
        """Depth along the camera's -z axis (0 = miss), hit mask and face ids of the pixel-centre rays."""
        origins, dirs = pixel_rays(torch.from_numpy(c2w.astype(np.float32)), intr)
        t_hit, ids = self.cast_rays(origins.numpy(), dirs.numpy())
        forward = -c2w[:3, 2].astype(np.float32)
        hit = ids >= 0
        depth = np.where(hit, t_hit * (dirs.numpy() @ forward), 0.0).astype(np.float32)
        shape = (intr.height, intr.width)
        return depth.reshape(shape), hit.reshape(shape), ids.reshape(shape)

    def close(self) -> None:
        """Release what the backend holds (nothing for ray casting alone)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class GroundTruthRenderer(MeshRays):
    """Renders one mesh from c2w poses (OpenGL axes, PROTOCOL.md 1) with pixel-centre rays: RGB and depth
    from pyrender, face ids and visibility from ``MeshRays``.

    Keeps one offscreen context (recreated when the image size changes); call ``close()`` (or use it
    as a context manager) to release it.
    """

    def __init__(self, mesh: trimesh.Trimesh, backend: str = "auto") -> None:
        self.backend = resolve_backend(backend)
        self._pyrender = _import_pyrender(self.backend)
        super().__init__(mesh)
        pr = self._pyrender
        self._scene = pr.Scene(bg_color=np.zeros(4), ambient_light=np.ones(3))
        self._scene.add(pr.Mesh([_as_opaque_primitive(pr, base_color_texture_mesh(mesh))]))
        self._camera_node = None
        self._renderer = None
        self._size: tuple[int, int] | None = None

    def _clip_range(self, position: np.ndarray) -> tuple[float, float]:
        """Near/far planes enclosing the mesh bounds from ``position``, near as far out as possible.

        The depth buffer's resolution scales with ``near`` (error ~ z^2 / (near * 2^24)), so near is
        95% of the distance to the bounds (at least 1e-3 of their diagonal when inside them).
        """
        lo, hi = self._bounds
        corners = np.array(np.meshgrid(*self._bounds.T, indexing="ij")).reshape(3, -1).T
        far = float(np.linalg.norm(corners - position, axis=1).max()) * 1.01
        outside = float(np.linalg.norm(np.maximum(lo - position, 0.0) + np.maximum(position - hi, 0.0)))
        near = max(1e-3 * float(np.linalg.norm(hi - lo)), 0.95 * outside)
        return near, max(far, 2.0 * near)

    def _offscreen(self, intr: Intrinsics):
        """The offscreen context for this image size; a new size replaces it (pyrender binds meshes to one context)."""
        size = (intr.width, intr.height)
        if self._renderer is not None and self._size != size:
            self.close()
        if self._renderer is None:
            self._renderer, self._size = self._pyrender.OffscreenRenderer(*size), size
        return self._renderer

    def render_rgb_depth(
        self, c2w: Float[np.ndarray, "4 4"], intr: Intrinsics
    ) -> tuple[Float[np.ndarray, "H W 3"], Float[np.ndarray, "H W"]]:
        """Unlit RGB in [0, 1] (black background) and camera z-distance (0 = miss) from pyrender."""
        pr = self._pyrender
        znear, zfar = self._clip_range(c2w[:3, 3])
        camera = pr.IntrinsicsCamera(
            intr.focal, intr.focal, intr.width / 2.0, intr.height / 2.0, znear=znear, zfar=zfar
        )
        if self._camera_node is not None:
            self._scene.remove_node(self._camera_node)
        self._camera_node = self._scene.add(camera, pose=c2w.astype(np.float64))
        color, depth = self._offscreen(intr).render(self._scene, flags=pr.RenderFlags.FLAT)
        return (color[..., :3].astype(np.float32) / 255.0), depth.astype(np.float32)

    def _masked_view(
        self, c2w: Float[Tensor, "4 4"] | Float[np.ndarray, "4 4"], intr: Intrinsics
    ) -> tuple[Float[np.ndarray, "4 4"], Float[np.ndarray, "H W 3"], Float[np.ndarray, "H W"], Bool[np.ndarray, "H W"]]:
        """The float64 pose, RGB (black where nothing is hit), depth and hit mask of the view ``c2w``."""
        pose = as_pose(c2w)
        rgb, depth = self.render_rgb_depth(pose, intr)
        mask = depth > 0
        return pose, np.where(mask[..., None], rgb, 0.0).astype(np.float32), depth, mask

    def render(self, c2w: Float[Tensor, "4 4"] | Float[np.ndarray, "4 4"], intr: Intrinsics) -> GTView:
        """Render RGB, depth, mask and face ids of the mesh seen from ``c2w``."""
        pose, rgb, depth, mask = self._masked_view(c2w, intr)
        return GTView(rgb=rgb, depth=depth, mask=mask, face_id=self.face_ids(pose, intr))

    def render_rgba(
        self, c2w: Float[Tensor, "4 4"] | Float[np.ndarray, "4 4"], intr: Intrinsics, samples_per_side: int = 1
    ) -> Float[np.ndarray, "H W 4"]:
        """RGB (black background) and coverage alpha, each pixel the mean of ``k x k`` sub-pixel samples
        (``k = samples_per_side``; the pixel-centre rays of the same view at ``k`` times the resolution).
        ``k = 1`` is ``render``'s RGB and mask. The paper's ground truth comes from Blender Cycles, which
        filters each pixel over about 1.5 px; an episode's ground truth uses ``k = budget.gt_samples``."""
        if samples_per_side < 1:
            raise ValueError(f"samples_per_side must be >= 1, got {samples_per_side}")
        k = samples_per_side
        _, rgb, _, mask = self._masked_view(c2w, Intrinsics(intr.width * k, intr.height * k, intr.focal * k))
        rgba = np.concatenate([rgb, mask[..., None].astype(np.float32)], axis=-1)
        return rgba.reshape(intr.height, k, intr.width, k, 4).mean(axis=(1, 3), dtype=np.float64).astype(np.float32)

    def close(self) -> None:
        """Release the offscreen context."""
        if self._renderer is not None:
            self._renderer.delete()
            self._renderer, self._size = None, None
