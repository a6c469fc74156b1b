"""A picture of a scene before a long run: its initial and evaluation views rendered by a ground-truth
renderer (either backend), and a top view with the boxes and the camera positions."""

import io
import math
from pathlib import Path

import numpy as np
import torch
from trimesh.visual import ColorVisuals, TextureVisuals

from nvf.cameras import Intrinsics
from pipeline.scenes.scene import Scene


def _top_view(scene: Scene, renderer, res: int) -> tuple[np.ndarray, tuple[float, float, float, float]]:
    """Orthographic top view (rays straight down from just above the highest camera), lightly height-shaded."""
    poses = torch.cat([scene.init_poses, scene.eval_poses]).double().numpy()
    points = np.concatenate([scene.camera_box.double().numpy(), scene.tight_box.double().numpy(), poses[:, :3, 3]])
    lo, hi = points.min(0), points.max(0)
    margin = 0.05 * float(np.max(hi[:2] - lo[:2]))
    lo, hi = lo - margin, hi + margin
    width = int(res * (hi[0] - lo[0]) / max(hi[1] - lo[1], hi[0] - lo[0]) * 2)
    height = int(res * (hi[1] - lo[1]) / max(hi[1] - lo[1], hi[0] - lo[0]) * 2)
    xs = np.linspace(lo[0], hi[0], width)
    ys = np.linspace(hi[1], lo[1], height)
    gx, gy = np.meshgrid(xs, ys)
    start = poses[:, 2, 3].max() + 1e-3
    origins = np.stack([gx, gy, np.full_like(gx, start)], -1).reshape(-1, 3)
    dirs = np.broadcast_to(np.array([0.0, 0.0, -1.0]), origins.shape)
    t_hit, ids = renderer.cast_rays(origins, dirs)
    mesh = scene.mesh
    if isinstance(mesh.visual, TextureVisuals):
        colors = mesh.visual.to_color().vertex_colors[mesh.faces, :3].mean(axis=1) / 255.0
    else:
        assert isinstance(mesh.visual, ColorVisuals), "a scene mesh has texture or colours (pipeline.scenes.meshes)"
        colors = mesh.visual.face_colors[:, :3] / 255.0
    image = np.ones((len(ids), 3))
    hit = ids >= 0
    z = start - t_hit[hit]
    tight = scene.tight_box.double().numpy()
    shade = 0.55 + 0.45 * np.clip((z - tight[0, 2]) / (tight[1, 2] - tight[0, 2]), 0.0, 1.0)
    image[hit] = colors[ids[hit]] * shade[:, None]
    return image.reshape(height, width, 3), (lo[0], hi[0], lo[1], hi[1])


def show(scene: Scene, renderer, out_dir: Path, res: int) -> Path:
    """PNG grid of the initial and evaluation views (``renderer``: pyrender's or Blender's, see
    ``pipeline.scenes.ground_truth``) plus a top view with boxes and camera positions, written atomically as
    ``<scene>.png`` (pyrender) or ``<scene>_blender.png``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    from pipeline.atomic_write import atomic_write_bytes
    from pipeline.scenes.blender import BlenderRenderer

    intr = Intrinsics.from_fov(res, res)
    init = [renderer.render(p, intr).rgb for p in scene.init_poses]
    evals = [renderer.render(p, intr).rgb for p in scene.eval_poses]
    top, extent = _top_view(scene, renderer, res)
    blender = isinstance(renderer, BlenderRenderer)
    backend = f"Blender Cycles {renderer.samples} spp" if blender else "pyrender flat"
    cols, init_rows = 5, math.ceil(len(init) / 5)
    rows = init_rows + 4
    fig = plt.figure(figsize=(2.0 * cols + 6.5, 2.0 * rows + 0.4))
    grid = fig.add_gridspec(rows, cols + 3)
    for i, image in enumerate(init + evals):
        row, col = divmod(i, cols) if i < len(init) else (init_rows + (i - len(init)) // cols, (i - len(init)) % cols)
        ax = fig.add_subplot(grid[row, col])
        ax.imshow(image)
        ax.set_title(
            f"init {i}" if i < len(init) else f"eval {i - len(init)}",
            fontsize=8,
            color="tab:red" if i < len(init) else "tab:blue",
        )
        ax.axis("off")
    ax = fig.add_subplot(grid[:, cols:])
    ax.imshow(top, extent=extent)
    cam, tight = scene.camera_box.numpy(), scene.tight_box.numpy()
    (cx, cy), (cw, ch) = cam[0, :2], cam[1, :2] - cam[0, :2]
    (tx, ty), (tw, th) = tight[0, :2], tight[1, :2] - tight[0, :2]
    ax.add_patch(Rectangle((cx, cy), cw, ch, fill=False, ec="k", lw=1.2, label="camera box"))
    ax.add_patch(Rectangle((tx, ty), tw, th, fill=False, ec="gray", ls="--", label="tight box"))
    arrow = 0.06 * float(np.max(cam[1, :2] - cam[0, :2]))
    for poses, color, label in ((scene.eval_poses, "tab:blue", "eval"), (scene.init_poses, "tab:red", "init")):
        p = poses.double().numpy()
        ax.scatter(p[:, 0, 3], p[:, 1, 3], s=18, c=color, label=f"{label} cameras", zorder=3)
        view = -p[:, :2, 2]
        ax.quiver(
            p[:, 0, 3],
            p[:, 1, 3],
            arrow * view[:, 0],
            arrow * view[:, 1],
            color=color,
            angles="xy",
            scale_units="xy",
            scale=1,
            width=0.004,
            zorder=3,
        )
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.legend(fontsize=7, loc="upper right")
    ax.set_title(f"{scene.name} ({scene.source}; views: {backend}): top view, z-shaded", fontsize=9)
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=80)
    plt.close(fig)
    path = out_dir / f"{scene.name}{'_blender' if blender else ''}.png"
    atomic_write_bytes(path, buffer.getvalue())
    return path
