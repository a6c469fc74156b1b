"""Procedural meshes: deterministic, coloured, modest, fitted into tight boxes, with self-occlusion (PROTOCOL 2.2)."""

import numpy as np
import pytest
import torch
import trimesh

from nvf.cameras import Intrinsics, look_at
from pipeline.scenes.procedural import PROXIES, default_object, fit_into_box


@pytest.mark.parametrize("name", [*PROXIES, "default"])
def test_meshes_are_deterministic_coloured_and_modest(name):
    build = default_object if name == "default" else PROXIES[name]
    first, second = build(), build()
    np.testing.assert_array_equal(first.vertices, second.vertices)
    np.testing.assert_array_equal(first.faces, second.faces)
    assert 200 <= len(first.faces) <= 50_000
    assert first.visual.kind == "face"
    np.testing.assert_array_equal(first.visual.face_colors, second.visual.face_colors)
    assert len(np.unique(first.visual.face_colors, axis=0)) >= 3
    assert np.isfinite(first.vertices).all() and first.area > 0 and first.bounds[0, 2] == pytest.approx(0.0)


def test_fit_into_box_is_uniform_centred_on_the_floor():
    mesh = trimesh.creation.box(bounds=np.array([[0.0, 0.0, 0.0], [2.0, 1.0, 4.0]]))
    box = np.array([[-1.0, -3.0, 0.5], [3.0, 1.0, 2.5]])
    fitted = fit_into_box(mesh, box)
    np.testing.assert_allclose(fitted.extents, [1.0, 0.5, 2.0])  # scale min(4/2, 4/1, 2/4) = 0.5
    np.testing.assert_allclose(fitted.bounds, [[0.5, -1.25, 0.5], [1.5, -0.75, 2.5]])
    np.testing.assert_allclose(mesh.bounds, [[0, 0, 0], [2, 1, 4]])  # input untouched


def test_proxy_keeps_thin_structures():
    """Drums' cymbals and ficus' branches stay thin after fitting (what makes those scenes hard)."""
    drums = fit_into_box(PROXIES["drums"](), np.array([[-1.126, -0.746, -0.492], [1.122, 0.962, 0.938]]))
    cymbal = drums.visual.face_colors[:, :3].tolist().count([205, 165, 60])
    assert cymbal > 100
    ficus = PROXIES["ficus"]()
    leaves = np.isin(ficus.visual.face_colors[:, 1], np.arange(110, 170)) & (ficus.visual.face_colors[:, 0] < 70)
    assert leaves.sum() > 1000  # dense canopy of small two-triangle leaves


def test_default_object_self_occludes():
    """The ball under the arch is hidden from straight above and seen through the arch from the side."""
    from pipeline.scenes.mesh_renderer import GroundTruthRenderer

    mesh = default_object()
    yellow = np.all(mesh.visual.face_colors[:, :3] == [240, 200, 30], axis=1)
    intr = Intrinsics.from_fov(96, 96)
    with GroundTruthRenderer(mesh) as renderer:
        xs, ys = np.meshgrid(np.linspace(0.2, 0.5, 40), np.linspace(-0.45, -0.15, 40))
        origins = np.stack([xs, ys, np.full_like(xs, 2.0)], -1).reshape(-1, 3)
        _, top_ids = renderer.cast_rays(origins, np.broadcast_to([0.0, 0.0, -1.0], origins.shape))
        side = renderer.face_ids(
            look_at(torch.tensor([0.35, -1.6, 0.15]), torch.tensor([0.35, -0.3, 0.15])).numpy(), intr
        )
    assert not yellow[top_ids[top_ids >= 0]].any()
    assert yellow[side[side >= 0]].sum() > 20
