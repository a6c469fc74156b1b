"""Ground-truth renderer vs nvf.cameras rays: depth, camera convention, flat colours, masks, face ids and
supersampling (PROTOCOL 1)."""

import numpy as np
import pytest
import torch
import trimesh

from nvf.cameras import Intrinsics, look_at, pixel_rays, project
from pipeline.scenes.mesh_renderer import GroundTruthRenderer, resolve_backend

INTR = Intrinsics.from_fov(96, 80)  # non-square on purpose: width and height must not be swapped


def _slab_depth(c2w: torch.Tensor, lo: np.ndarray, hi: np.ndarray, intr: Intrinsics = INTR) -> np.ndarray:
    """Analytic camera z-depth of an axis-aligned box along the pixel-centre rays (0 = miss)."""
    origins, dirs = (x.double().numpy() for x in pixel_rays(c2w, intr))
    with np.errstate(divide="ignore", invalid="ignore"):
        t0, t1 = (lo - origins) / dirs, (hi - origins) / dirs
    t_near = np.minimum(t0, t1).max(axis=1)
    t_far = np.maximum(t0, t1).min(axis=1)
    hit = (t_far >= t_near) & (t_far > 0)
    axis = -c2w[:3, 2].double().numpy()
    depth = np.where(hit, t_near * (dirs @ axis), 0.0)
    return depth.reshape(intr.height, intr.width)


@pytest.fixture(scope="module")
def cube_renderer():
    cube = trimesh.creation.box(bounds=np.array([[-0.5, -0.4, -0.3], [0.5, 0.4, 0.3]]))
    cube.visual.face_colors = np.array([200, 100, 50, 255], dtype=np.uint8)
    with GroundTruthRenderer(cube) as renderer:
        yield renderer


@pytest.mark.parametrize("position", [(2.0, -1.5, 1.2), (0.3, 0.2, 2.5), (-1.8, 0.4, -0.9)])
def test_depth_matches_analytic_box(cube_renderer, position):
    c2w = look_at(torch.tensor(position), torch.tensor([0.1, -0.05, 0.0]))
    view = cube_renderer.render(c2w, INTR)
    expected = _slab_depth(c2w, np.array([-0.5, -0.4, -0.3]), np.array([0.5, 0.4, 0.3]))
    both = view.mask & (expected > 0)
    assert both.sum() > 300
    np.testing.assert_allclose(view.depth[both], expected[both], rtol=1e-3, atol=1e-3)
    assert (view.mask == (expected > 0)).mean() > 0.99
    assert view.depth.dtype == np.float32 and np.all(view.depth[~view.mask] == 0)


def test_flat_colour_black_background_and_face_ids(cube_renderer):
    c2w = look_at(torch.tensor([1.5, 1.2, 1.0]), torch.tensor([0.0, 0.0, 0.0]))
    view = cube_renderer.render(c2w, INTR)
    assert view.rgb.shape == (80, 96, 3) and view.rgb.dtype == np.float32
    np.testing.assert_allclose(
        view.rgb[view.mask],
        np.broadcast_to([200 / 255, 100 / 255, 50 / 255], view.rgb[view.mask].shape),
        atol=1.5 / 255,
    )
    assert np.all(view.rgb[~view.mask] == 0)
    hit = view.face_id >= 0
    assert view.face_id.dtype == np.int64 and (hit == view.mask).mean() > 0.99
    # every visible face points towards the camera
    mesh = cube_renderer.mesh
    ids = view.face_id[hit]
    to_camera = c2w[:3, 3].numpy() - mesh.triangles_center[ids]
    assert np.all(np.einsum("ij,ij->i", mesh.face_normals[ids], to_camera) > 0)


def test_supersampled_rgba_is_the_mean_of_sub_pixel_samples(cube_renderer):
    """``render_rgba(k)``: coverage alpha = the fraction of the pixel's k x k sub-pixel rays that hit
    (analytic box), colour premultiplied over black; ``k = 1`` is ``render``'s RGB and mask."""
    c2w = look_at(torch.tensor([1.5, 1.2, 1.0]), torch.tensor([0.0, 0.0, 0.0]))
    one = cube_renderer.render(c2w, INTR)
    np.testing.assert_array_equal(
        cube_renderer.render_rgba(c2w, INTR, 1), np.concatenate([one.rgb, one.mask[..., None]], axis=-1)
    )
    rgba = cube_renderer.render_rgba(c2w, INTR, 4)
    assert rgba.shape == (80, 96, 4) and rgba.dtype == np.float32
    fine = Intrinsics(INTR.width * 4, INTR.height * 4, INTR.focal * 4)
    hits = _slab_depth(c2w, np.array([-0.5, -0.4, -0.3]), np.array([0.5, 0.4, 0.3]), fine) > 0
    coverage = hits.reshape(80, 4, 96, 4).mean(axis=(1, 3))
    assert np.abs(rgba[..., 3] - coverage).mean() < 5e-4  # a 1% zoom of the sub-pixel grid gives 1.3e-3
    edge = (rgba[..., 3] > 0.1) & (rgba[..., 3] < 0.9)
    assert edge.sum() > 30
    colour = np.array([200, 100, 50]) / 255
    np.testing.assert_allclose(rgba[edge, :3] / rgba[edge, 3:], np.broadcast_to(colour, (edge.sum(), 3)), atol=2e-2)
    with pytest.raises(ValueError, match="samples_per_side"):
        cube_renderer.render_rgba(c2w, INTR, 0)


def test_camera_convention_matches_project():
    """A red cube right of and a blue cube above the target land where nvf.cameras.project puts them."""
    red = trimesh.creation.box(extents=(0.2, 0.2, 0.2))
    red.apply_translation([0.8, 0.0, 0.0])
    red.visual.face_colors = [255, 0, 0, 255]
    blue = trimesh.creation.box(extents=(0.2, 0.2, 0.2))
    blue.apply_translation([0.0, 0.0, 0.7])
    blue.visual.face_colors = [0, 0, 255, 255]
    c2w = look_at(torch.tensor([0.0, -3.0, 0.0]), torch.tensor([0.0, 0.0, 0.0]))  # image right = +x, up = +z
    with GroundTruthRenderer(trimesh.util.concatenate([red, blue])) as renderer:
        view = renderer.render(c2w.numpy(), INTR)  # numpy poses are accepted too
    uv, depth = project(torch.tensor([[0.8, 0.0, 0.0], [0.0, 0.0, 0.7]]), c2w, INTR)
    for channel, (u, v) in zip((0, 2), uv.numpy(), strict=True):
        rows, cols = np.nonzero(view.rgb[..., channel] > 0.9)
        assert abs(cols.mean() + 0.5 - u) < 1.0 and abs(rows.mean() + 0.5 - v) < 1.0
    assert uv[0, 0] > INTR.width / 2 and uv[1, 1] < INTR.height / 2 and torch.all(depth > 0)


def test_line_of_sight_is_exact_occlusion_and_frustum(cube_renderer):
    """A point just outside the cube's +z face is visible from a camera above it, hidden behind the
    cube from a camera below it, and outside the image of a camera looking away."""
    points = torch.tensor([[0.0, 0.0, 0.31], [0.2, -0.1, 0.31]])
    above = look_at(torch.tensor([0.0, 0.0, 2.0]), torch.zeros(3))
    below = look_at(torch.tensor([0.0, 0.0, -2.0]), torch.zeros(3))
    away = look_at(torch.tensor([0.0, 0.0, 2.0]), torch.tensor([0.0, 0.0, 4.0]))
    assert cube_renderer.line_of_sight(points, above[None], INTR).all()
    assert not cube_renderer.line_of_sight(points, below[None], INTR).any()
    assert not cube_renderer.line_of_sight(points, away[None], INTR).any()
    assert cube_renderer.line_of_sight(points, torch.stack([below, away, above]), INTR).all()


def test_unoccluded_segments_stop_at_faces_not_beyond_the_point(cube_renderer):
    """M29 with ``planner.los_source=mesh``: a segment is blocked only by a face between its ends."""
    origin = torch.tensor([0.0, 0.0, 2.0])
    points = torch.tensor(
        [
            [0.0, 0.0, 0.31],  # just above the +z face: free
            [0.0, 0.0, -1.0],  # behind the cube: blocked
            [1.5, 0.0, -1.0],  # beside the cube: free
            [0.0, 0.0, 2.0],  # the origin itself: free
        ]
    )
    assert cube_renderer.unoccluded(origin, points).tolist() == [True, False, True, True]


def test_inside_is_the_closed_mesh_interior(cube_renderer):
    """The exact density's support (tests/test_visibility.py): inside the box and not outside it."""
    points = torch.tensor(
        [
            [0.0, 0.0, 0.0],  # centre
            [0.49, 0.39, 0.29],  # near a corner, inside
            [0.0, 0.0, 0.31],  # just above the +z face
            [2.0, 0.0, 0.0],  # far outside
        ]
    )
    assert cube_renderer.inside(points).tolist() == [True, True, False, False]


def test_resolve_backend(monkeypatch):
    assert resolve_backend("egl") == "egl" and resolve_backend("osmesa") == "osmesa"
    monkeypatch.setenv("PYOPENGL_PLATFORM", "osmesa")
    assert resolve_backend("auto") == "osmesa"
    with pytest.raises(ValueError):
        resolve_backend("vulkan")


def test_textured_mesh_renders_its_texture(assets_dir):
    """Hubble's five textured parts share one atlas: the render is grey/gold, not noise (PROTOCOL 2.2)."""
    from pipeline.scenes.loading import load_scene

    scene = load_scene("hubble", assets_dir)
    with GroundTruthRenderer(scene.mesh) as renderer:
        view = renderer.render(scene.eval_poses[0], Intrinsics.from_fov(64, 64))
    colours = view.rgb[view.mask]
    assert view.mask.mean() > 0.05
    saturation = colours.max(axis=1) - colours.min(axis=1)
    assert np.median(saturation) < 0.25 and colours.mean() > 0.1


def test_image_size_can_change(cube_renderer):
    c2w = look_at(torch.tensor([1.5, 1.2, 1.0]), torch.tensor([0.0, 0.0, 0.0]))
    small = cube_renderer.render(c2w, Intrinsics.from_fov(32, 32))
    other = cube_renderer.render(c2w, Intrinsics.from_fov(48, 40))
    again = cube_renderer.render(c2w, Intrinsics.from_fov(32, 32))
    assert other.rgb.shape == (40, 48, 3)
    np.testing.assert_array_equal(small.rgb, again.rgb)


def test_render_bench_and_dispatch(tmp_path, capsys):
    import json

    from pipeline.bench.__main__ import main as bench_main
    from pipeline.scenes.blender import blender_python, missing_python

    out = tmp_path / "render.json"
    backends = ["pyrender"] if missing_python(blender_python()) else ["pyrender", "blender"]
    bench_main(
        [
            "render",
            "--res",
            "16",
            "24",
            "--views",
            "1",
            "--samples",
            "2",
            "--scenes",
            "default",
            "--backends",
            *backends,
            "--out",
            str(out),
        ]
    )
    rows = json.loads(out.read_text())["rows"]
    assert [r["resolution"] for r in rows] == [16, 24] and all(r["ray_cast_ms"] > 0 for r in rows)
    assert all(r[f"{backend}_rgba_ms"] > 0 for r in rows for backend in backends)
    assert all(("blender_over_pyrender" in r) == ("blender" in backends) for r in rows)
    with pytest.raises(SystemExit) as info:
        bench_main(["no_such_bench"])
    assert info.value.code == 2 and "unknown benchmark" in capsys.readouterr().err
