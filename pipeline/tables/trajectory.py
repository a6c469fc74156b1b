"""Where a run put its cameras (``trajectory.png`` beside its records): the scene's outline from above and from
the side, its initial views and the view chosen at each step as camera glyphs, the chosen ones numbered by the
step that chose them. The outline is the scene's surface (sampled points, darker where denser); a scene whose
asset cannot be read here is drawn as its tight box, and the figure says so.

The scene code (torch, trimesh) is imported when an outline is built, so loading ``pipeline.tables`` stays light.
"""

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np
from jaxtyping import Float
from matplotlib.figure import Figure
from matplotlib.patches import Polygon, Rectangle
from scipy.spatial.transform import Rotation

from pipeline.config.settings_beyond_groups import GROUPS, NamedConfigs
from pipeline.records.images import save_figure
from pipeline.tables.escape import plot_text
from pipeline.tables.load import effective_config

SURFACE_POINTS = 40000  # sampled on the mesh for its outline
BINS = 120  # outline resolution along the longer side of a view
FACE_ON = 0.8  # |normal . viewing axis| above which a room's surface is left out of its outline
INITIAL_COLOR = "#9ecae1"
PNG_COLORS = 64  # trajectory.png is stored with a palette of this many colours (a few times smaller)
VIEWS = (("from above", (0, 1), ("x", "y")), ("from the side", (0, 2), ("x", "z")))


@dataclass(frozen=True)
class SceneOutline:
    """What a trajectory is drawn on: ``points`` on the scene's surface ([N, 3], None when its mesh is not
    available: the tight box is drawn) and their surfaces' ``normals``, its boxes, its initial views (c2w,
    OpenGL axes) and where the outline comes from (``note``)."""

    name: str
    kind: str  # object | room
    points: Float[np.ndarray, "n 3"] | None
    normals: Float[np.ndarray, "n 3"] | None
    tight_box: Float[np.ndarray, "2 3"]
    camera_box: Float[np.ndarray, "2 3"]
    init_poses: Float[np.ndarray, "m 4 4"]
    note: str


def outline_of_scene(scene, kind: str) -> SceneOutline:
    """The outline of a built ``pipeline.scenes.scene.Scene`` (a finished run has it at hand)."""
    import trimesh

    points, faces = trimesh.sample.sample_surface(scene.mesh, SURFACE_POINTS, seed=0)
    where = f"the asset {scene.asset.name}" if scene.asset is not None else f"the {scene.source} mesh"
    return SceneOutline(
        scene.name,
        kind,
        np.asarray(points, dtype=np.float64),
        np.asarray(scene.mesh.face_normals[faces]),
        scene.tight_box.double().numpy(),
        scene.camera_box.double().numpy(),
        scene.init_poses.double().numpy(),
        f"outline: {where}",
    )


def recorded_scene(info: Mapping[str, Any], named: NamedConfigs) -> dict:
    """A run record's scene config, keys it predates read from today's config of its named groups
    (``pipeline.tables.load.effective_config``)."""
    today = named.named(tuple(str(info[group]) for group in GROUPS)) or {}
    return effective_config(info.get("config") or {}, today)["scene"]


def outline_of_config(scene_cfg: Mapping[str, Any], assets: Path) -> SceneOutline:
    """The outline of a run record's scene (``recorded_scene``), built again; a scene whose asset is not
    under ``assets`` (or needs a Blender that is not installed) keeps its boxes and views, drawn without
    its surface."""
    from pipeline.scenes.loading import load_scene
    from pipeline.scenes.scene import SceneError
    from pipeline.scenes.views import rig_views

    kind = str(scene_cfg.get("kind", "object"))
    try:
        return outline_of_scene(load_scene(scene_cfg, assets), kind)
    except SceneError:  # no asset here, or no Blender to read it
        tight = np.asarray(scene_cfg["tight_box"], dtype=np.float64)
        init = rig_views(scene_cfg["init_views"], tight, True).double().numpy()
        return SceneOutline(
            str(scene_cfg["name"]),
            kind,
            None,
            None,
            tight,
            np.asarray(scene_cfg["camera_box"], dtype=np.float64),
            init,
            "outline: the tight box (the scene's mesh cannot be read here)",
        )


def chosen_poses(rows: list[dict]) -> tuple[list[int], Float[np.ndarray, "k 4 4"]]:
    """The steps and c2w matrices of the views the rows chose (``selected_pose``: ``[qx, qy, qz, qw, x, y, z]``)."""
    steps, poses = [], []
    for row in rows:
        pose = row.get("selected_pose")
        if isinstance(pose, list) and len(pose) == 7 and all(isinstance(v, (int, float)) for v in pose):
            c2w = np.eye(4)
            c2w[:3, :3] = Rotation.from_quat(pose[:4]).as_matrix()  # scalar last, as nvf.cameras
            c2w[:3, 3] = pose[4:]
            steps.append(int(row["step"]))
            poses.append(c2w)
    return steps, np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)


def _glyph(ax, c2w: Float[np.ndarray, "4 4"], axes: tuple[int, int], size: float, color, zorder: int) -> None:
    """A camera seen along the third axis: a wedge from its centre opening along its view direction (-z of
    its frame), or a ring when it looks along the third axis."""
    centre, look = c2w[:3, 3][list(axes)], -c2w[:3, 2][list(axes)]
    length = float(np.linalg.norm(look))
    if length < 0.3:
        ax.add_patch(Polygon(_ring(centre, 0.3 * size), closed=True, fc=color, ec="black", lw=0.6, zorder=zorder))
        return
    look = look / length
    side = np.array([-look[1], look[0]])
    tip = centre + size * length * look
    wedge = [centre, tip + 0.45 * size * side, tip - 0.45 * size * side]
    ax.add_patch(Polygon(wedge, closed=True, fc=color, ec="black", lw=0.4, alpha=0.85, zorder=zorder))


def _ring(centre: Float[np.ndarray, "2"], radius: float) -> np.ndarray:
    angles = np.linspace(0.0, 2.0 * math.pi, 16, endpoint=False)
    return centre + radius * np.stack([np.cos(angles), np.sin(angles)], -1)


def _surface(ax, outline: SceneOutline, axes: tuple[int, int], lo, hi) -> None:
    """The outline's points projected on ``axes`` as a grey density image (log count); in a room, without the
    surfaces seen face-on (floor and ceiling from above, the far wall from the side), which would cover it."""
    points, normals = outline.points, outline.normals
    assert points is not None and normals is not None, "drawn only for an outline with its surface"
    if outline.kind == "room":
        third = 3 - sum(axes)
        points = points[np.abs(normals[:, third]) < FACE_ON]
    span = hi - lo
    bins = (max(8, int(BINS * span[0] / span.max())), max(8, int(BINS * span[1] / span.max())))
    counts, _, _ = np.histogram2d(
        points[:, axes[0]], points[:, axes[1]], bins=bins, range=[[lo[0], hi[0]], [lo[1], hi[1]]]
    )
    shade = np.log1p(counts.T) / max(np.log1p(counts.max()), 1e-9)
    image = np.where(shade > 0, 0.85 - 0.55 * shade, 1.0)
    ax.imshow(
        image,
        origin="lower",
        extent=(lo[0], hi[0], lo[1], hi[1]),
        cmap="gray",
        vmin=0.0,
        vmax=1.0,
        interpolation="nearest",
        zorder=0,
    )


def trajectory_figure(outline: SceneOutline, rows: list[dict], title: str, out_path: Path) -> Path:
    """``trajectory.png``: the run's initial and chosen views over ``outline``, from above (x-y) and from the
    side (x-z), written atomically at ``out_path``."""
    steps, chosen = chosen_poses(rows)
    cameras = np.concatenate([outline.init_poses[:, :3, 3], chosen[:, :3, 3], outline.tight_box])
    lo, hi = cameras.min(0), cameras.max(0)
    margin = 0.08 * float((hi - lo).max())
    lo, hi = lo - margin, hi + margin
    size = (0.035 if outline.kind == "room" else 0.06) * float((hi - lo).max())  # a camera glyph's length
    fig = Figure(figsize=(11, 5.2), dpi=80)
    fig.subplots_adjust(left=0.06, right=0.99, bottom=0.1, top=0.85, wspace=0.18)
    panels = fig.subplots(1, 2, width_ratios=[hi[0] - lo[0] + hi[1] - lo[1], hi[0] - lo[0] + hi[2] - lo[2]])
    cmap = matplotlib.colormaps["plasma"]
    for ax, (name, axes, labels) in zip(panels, VIEWS, strict=True):
        plane_lo, plane_hi = lo[list(axes)], hi[list(axes)]
        if outline.points is not None:
            _surface(ax, outline, axes, plane_lo, plane_hi)
        box = outline.tight_box[:, list(axes)]
        ax.add_patch(Rectangle(box[0], *(box[1] - box[0]), fill=False, ec="0.35", ls="--", lw=0.8, zorder=1))
        for c2w in outline.init_poses:
            _glyph(ax, c2w, axes, size, INITIAL_COLOR, zorder=2)
        if len(chosen):
            path = chosen[:, :3, 3][:, list(axes)]
            ax.plot(path[:, 0], path[:, 1], color="0.3", lw=0.5, alpha=0.5, zorder=2)
        for k, (step, c2w) in enumerate(zip(steps, chosen, strict=True)):
            color = cmap(0.85 * k / max(len(chosen) - 1, 1))
            _glyph(ax, c2w, axes, size, color, zorder=3)
            centre = c2w[:3, 3][list(axes)]
            ax.annotate(str(step), centre, xytext=(3, 3), textcoords="offset points", fontsize=7, zorder=4)
        ax.set_xlim(plane_lo[0], plane_hi[0])
        ax.set_ylim(plane_lo[1], plane_hi[1])
        ax.set_aspect("equal")
        ax.set_xlabel(f"{labels[0]} (scene units)")
        ax.set_ylabel(f"{labels[1]} (scene units)")
        ax.set_title(name, fontsize=10)
    legend = [
        Polygon([[0, 0]], fc=INITIAL_COLOR, ec="black", label=f"initial views ({len(outline.init_poses)})"),
        Polygon([[0, 0]], fc=cmap(0.4), ec="black", label=f"chosen views, numbered by step ({len(chosen)})"),
        Rectangle((0, 0), 1, 1, fill=False, ec="0.35", ls="--", label="tight box"),
    ]
    panels[0].legend(handles=legend, loc="upper left", fontsize=7, framealpha=0.85)
    fig.suptitle(
        f"{plot_text(title)}\n{outline.note}; a wedge opens along its camera's view direction, a disc looks "
        "along the third axis",
        fontsize=10,
    )
    save_figure(fig, Path(out_path), colors=PNG_COLORS)
    return Path(out_path)
