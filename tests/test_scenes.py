"""Declared scenes: PROTOCOL.md 2.1-2.5 boxes and views, mesh loading and placement, errors, the show CLI."""

import math
import shutil
import subprocess
import sys

import numpy as np
import pytest
import torch
import trimesh

from pipeline.repo import REPO
from pipeline.scenes.blender import blender_python, missing_python
from pipeline.scenes.loading import find_asset, load_scene, scene_config, scene_names
from pipeline.scenes.scene import SceneError
from pipeline.scenes.views import rule_views

PROXIES = [name for name in scene_names() if name.endswith("_proxy")]
NO_BLENDER = missing_python(blender_python())

# PROTOCOL 2.3: rounded initial views, position -> look-at target
INIT = {
    "hubble": [
        ((1.3463, 2.0533, 0.3500), (0, 0, -0.1500)),
        ((1.8766, 1.5231, 0.7829), (0, 0, 0.3500)),
        ((1.8766, 1.5231, -0.0830), (0, 0, 0.8499)),
    ],
    "lego": [
        ((-0.3000, 2.2000, 0.3500), (0, 0, -0.30)),
        ((0.1500, 2.2000, 0.6098), (0, 0, 0.15)),
        ((0.1500, 2.2000, 0.0902), (0, 0, 0.60)),
    ],
    "hotdog": [
        ((0, -1.5, 1.2), (0, 0, -0.150)),
        ((1.4266, -0.4635, 1.2), (0, 0, -0.075)),
        ((0.8817, 1.2135, 1.2), (0, 0, 0)),
        ((-0.8817, 1.2135, 1.2), (0, 0, 0.075)),
        ((-1.4266, -0.4635, 1.2), (0, 0, 0.150)),
    ],
    "room": [
        ((0.6999, 1.9998, 2.3498), (-2, 2, 0.3500)),
        ((0.7001, 3.9996, 2.3498), (0, 0, -0.1500)),
        ((-0.0651, 3.5318, 3.3827), (0, 0, -0.0250)),
        ((-0.4722, 2.3471, 3.9323), (0, 0, 0.1000)),
        ((-0.3310, 1.0000, 3.7415), (0, 0, 0.2250)),
        ((0.2927, 0.1206, 2.8994), (0, 0, 0.3500)),
        ((1.1069, 0.1206, 1.8001), (0, 0, 0.4750)),
        ((1.7307, 0.9998, 0.9581), (0, 0, 0.5999)),
        ((1.8722, 2.3470, 0.7672), (0, 0, 0.7249)),
        ((1.4651, 3.5317, 1.3168), (0, 0, 0.8499)),
    ],
}

# PROTOCOL 2.5 table: target t, semi-axes a, top view, P0, z_i
RULE = {
    "lego": ((0, 0, 0.35), (1.5, 2.0, 1.7), (0, 0, 1.7), (0, 2.2, 0.35), (-0.3, 0.15, 0.6)),
    "chair": ((-0.05, 0, 0.05), (1.55, 1.6, 2.05), (-0.05, 0, 1.75), (-0.05, 1.75, 0.05), (-0.9, -0.25, 0.45)),
    "drums": ((0, 0.1, 0.2), (2.0, 1.75, 1.75), (0, 0.1, 1.65), (0, 2.0, 0.2), (-0.45, 0.05, 0.5)),
    "ficus": ((0.1, -0.15, 0.05), (1.35, 1.6, 2.1), (0.1, -0.15, 1.85), (0.1, 1.65, 0.05), (-0.95, -0.2, 0.5)),
    "materials": ((-0.05, 0.1, 0), (1.95, 1.75, 1.25), (-0.05, 0.1, 0.9), (-0.05, 2.05, 0), (-0.2, -0.05, 0.05)),
    "mic": ((-0.25, 0.1, 0.2), (1.9, 1.85, 1.95), (-0.25, 0.1, 1.85), (-0.25, 2.15, 0.2), (-0.65, -0.05, 0.6)),
    "ship": ((0.05, 0, 0.1), (2.2, 2.2, 1.65), (0.05, 0, 1.45), (0.05, 2.4, 0.1), (-0.5, -0.05, 0.35)),
}
LEGO_ANGLES = [(30, 90 * j) for j in range(4)] + [(60, 60 * j) for j in range(6)] + [(90, 40 * j) for j in range(9)]


def _dir(theta: float, phi: float) -> np.ndarray:
    t, p = math.radians(theta), math.radians(phi)
    return np.array([math.sin(p) * math.cos(t), math.sin(p) * math.sin(t), math.cos(p)])


def assert_view(c2w: torch.Tensor, position, target, tol: float = 1e-3) -> None:
    """Camera at ``position`` whose -z axis points at ``target`` (to ``tol`` at the target's distance)."""
    c2w = c2w.double().numpy()
    np.testing.assert_allclose(c2w[:3, 3], position, atol=tol)
    np.testing.assert_allclose(c2w[:3, :3].T @ c2w[:3, :3], np.eye(3), atol=1e-5)
    assert np.linalg.det(c2w[:3, :3]) == pytest.approx(1.0, abs=1e-5)
    offset = np.asarray(target, float) - c2w[:3, 3]
    dist = np.linalg.norm(offset)
    np.testing.assert_allclose(-c2w[:3, 2] * dist, offset, atol=tol)
    assert abs(c2w[:3, 0] @ [0, 0, 1]) < 1e-5  # look_at with up +z: no roll


def lego_layout_expected(centre, a, target, top, top_target):
    views = [(np.add(centre, np.multiply(a, _dir(th, ph))), target) for ph, th in LEGO_ANGLES]
    return views + [(top, top_target)]


class _Scenes(dict):
    """The development scenes; Room (room/room.blend) only where Blender is installed, else its tests skip."""

    def __missing__(self, name):
        pytest.skip(f"{name}'s .blend needs Blender: {NO_BLENDER}")


@pytest.fixture(scope="module")
def mesh_scenes(assets_dir):
    names = ("hubble", "hotdog") if NO_BLENDER else ("hubble", "hotdog", "room")
    return _Scenes({name: load_scene(name, assets_dir) for name in names})


def test_paper_scenes_are_declared():
    """The ten paper scenes, their proxies and the embedded scene each have a yaml."""
    paper = {"hubble", "room", "chair", "drums", "ficus", "hotdog", "lego", "materials", "mic", "ship"}
    assert paper | {"default", "lego_proxy"} <= set(scene_names())
    assert {scene_config(name)["paper_scene"] for name in scene_names()} - {None} == paper


@pytest.mark.parametrize("name", scene_names())
def test_every_declared_scene_is_complete(name):
    """Each yaml composes, its object box holds its tight box (to PROTOCOL 2.1's rounding, 1e-3), its camera
    box is not empty and its view rigs build."""
    cfg = scene_config(name)
    tight, aabb, cam = (np.asarray(cfg[key]) for key in ("tight_box", "object_aabb", "camera_box"))
    assert np.all(aabb[0] <= tight[0] + 1e-3) and np.all(aabb[1] >= tight[1] - 1e-3)
    assert np.all(cam[1] > cam[0])
    from pipeline.scenes.views import rig_views

    assert rig_views(cfg["eval_views"], tight, False).shape == (20, 4, 4)
    assert rig_views(cfg["init_views"], tight, True).shape[0] in (3, 5, 10)


@pytest.mark.parametrize("name", ["hubble", "hotdog", "room"])
def test_initial_views_mesh_scenes(mesh_scenes, name):
    scene = mesh_scenes[name]
    assert scene.init_poses.shape == (scene.n_init, 4, 4) and scene.init_poses.dtype == torch.float32
    for pose, (position, target) in zip(scene.init_poses, INIT[name], strict=True):
        assert_view(pose, position, target)


def test_lego_proxy_views_and_boxes():
    scene = load_scene("lego_proxy", None)
    assert scene.source == "proxy" and scene.n_init == 3
    for pose, (position, target) in zip(scene.init_poses, INIT["lego"], strict=True):
        assert_view(pose, position, target)
    t = (0, 0, 0.35)
    for pose, (position, target) in zip(
        scene.eval_poses, lego_layout_expected(t, (1.5, 2.0, 1.7), t, (0, 0, 1.7), t), strict=True
    ):
        assert_view(pose, position, target)
    torch.testing.assert_close(scene.camera_box, torch.tensor([[-1.75, -3.0, -0.345], [1.75, 3.0, 3.2675]]))
    torch.testing.assert_close(scene.object_aabb, torch.tensor([[-0.7, -1.2, -0.345], [0.7, 1.2, 1.1]]))


def test_hubble_eval_views(mesh_scenes):
    s = 0.16665
    t, a = (0, 0, 0.3333), (1.7332, 1.7332, 2.4998)
    expected = [(np.add(t, np.multiply(a, _dir(th, ph))), t) for th in range(0, 360, 60) for ph in (45, 90, 135)]
    expected += [((0, 0, 2.2498), t), ((0, 0, -1.4999), t)]
    for pose, (position, target) in zip(mesh_scenes["hubble"].eval_poses, expected, strict=True):
        assert_view(pose, position, target)
    assert mesh_scenes["hubble"].density_threshold == 1e-3 and 6 * s == pytest.approx(0.9999)


def test_hotdog_eval_views(mesh_scenes):
    views = lego_layout_expected((0, -0.088056, 0.4), (1.6, 1.6, 1.3), (0, 0, 0), (0, 0, 1.7), (0, 0, 0.35))
    for pose, (position, target) in zip(mesh_scenes["hotdog"].eval_poses, views, strict=True):
        assert_view(pose, position, target)
    assert mesh_scenes["hotdog"].n_init == 5


def test_room_eval_views_straight_down(mesh_scenes):
    scene = mesh_scenes["room"]
    centres = [(0, 0, 4, 72)] * 5 + [(-8, -1, 3, 36)] * 10 + [(-3, 2, 3, 72)] * 5
    index = [*range(5), *range(10), *range(5)]
    for pose, (cx, cy, r, step), i in zip(scene.eval_poses.double(), centres, index, strict=True):
        theta = math.radians(step * i)
        np.testing.assert_allclose(pose[:3, 3], (cx + r * math.cos(theta), cy + r * math.sin(theta), 4), atol=1e-5)
        np.testing.assert_allclose(pose[:3, 0], (math.cos(theta), math.sin(theta), 0), atol=1e-6)
        np.testing.assert_allclose(pose[:3, 2], (0, 0, 1), atol=1e-6)
    assert scene.collision_free and scene.d0 == 6.0 and scene.cr_threshold == 0.1 and scene.n_init == 10
    torch.testing.assert_close(scene.camera_box, scene.object_aabb)


@pytest.mark.parametrize("name", list(RULE))
def test_rule_views_table(name):
    """PROTOCOL 2.5: the rule applied to each tight box gives the table's values (lego: its own views)."""
    t, a, top, p0, z = RULE[name]
    box = load_scene(f"{name}_proxy", None).tight_box.double().numpy()
    init, evals = rule_views(box)
    offsets = [(-0.3, 0, 0), (0.15, 0, 0.2598), (0.15, 0, -0.2598)]
    for pose, offset, zi in zip(init, offsets, z, strict=True):
        assert_view(pose, np.add(p0, offset), (t[0], t[1], zi))
    for pose, (position, target) in zip(evals, lego_layout_expected(t, a, t, top, t), strict=True):
        assert_view(pose, position, target)


@pytest.mark.parametrize("name", PROXIES)
def test_proxies_fit_tight_box(name):
    scene = load_scene(name, None)
    box = scene.tight_box.double().numpy()
    lo, hi = scene.mesh.bounds
    assert np.all(lo >= box[0] - 1e-6) and np.all(hi <= box[1] + 1e-6)
    assert lo[2] == pytest.approx(box[0, 2], abs=1e-6)
    np.testing.assert_allclose((lo + hi)[:2] / 2, (box[0] + box[1])[:2] / 2, atol=1e-6)
    assert np.isclose(hi - lo, box[1] - box[0], atol=1e-6).any()  # touches the box along one axis
    assert scene.eval_poses.shape == (20, 4, 4) and scene.init_poses.shape == (3, 4, 4)


def test_mesh_placement(mesh_scenes):
    hotdog, hubble = mesh_scenes["hotdog"], mesh_scenes["hubble"]
    np.testing.assert_allclose(hotdog.mesh.bounds, hotdog.tight_box.double().numpy(), atol=2e-3)
    assert len(hotdog.mesh.faces) == 66000 and len(hubble.mesh.faces) == 5128
    box = hubble.tight_box.double().numpy()
    np.testing.assert_allclose(hubble.mesh.bounds.mean(0), (box[0] + box[1]) / 2, atol=1e-5)
    np.testing.assert_allclose((box[0] + box[1]) / 2, (0, 0.0271, 0.3581), atol=1e-4)
    assert np.isclose(hubble.mesh.extents, box[1] - box[0], atol=1e-5).any()
    assert hubble.mesh.visual.kind == "texture"
    assert hotdog.source == hubble.source == "mesh"
    # the tight box's x extent over the model's 11.64 m (PROTOCOL 2.2's uniform fit)
    assert hubble.asset.name == "hubble_nasaA_zup_m.glb" and hubble.asset_to_scene[0, 0] == pytest.approx(
        0.1584, abs=1e-4
    )


def test_room_blend_is_preferred_over_its_mesh(mesh_scenes, assets_dir):
    """room/room.blend is found before the development mesh; its render-visible triangles (the pillows' and
    cushions' subdivision at render level: 40,260 where the mesh has 20,100) fill the tight box in the
    scene frame, coloured by the room's five materials."""
    room = mesh_scenes["room"]
    assert room.source == "blend" and room.asset == assets_dir / "room" / "room.blend"
    np.testing.assert_allclose(room.mesh.bounds, room.tight_box.double().numpy(), atol=2e-3)
    assert len(room.mesh.faces) == 40260 and room.mesh.visual.kind == "face"
    assert len(np.unique(room.mesh.visual.face_colors, axis=0)) == 5
    np.testing.assert_array_equal(room.asset_to_scene, np.eye(4))


def test_room_development_mesh_is_mapped_to_z_up(assets_dir, tmp_path):
    """Without a .blend, Room's development mesh (Y-up) is used, rotated into the Z-up scene frame."""
    (tmp_path / "room").mkdir()
    for name in ("room_nvf_gt_yup.obj", "room_nvf_gt_yup.mtl"):
        shutil.copy(assets_dir / "room" / name, tmp_path / "room" / name)
    assert find_asset(scene_config("room"), tmp_path)[0].name == "room_nvf_gt_yup.obj"
    room = load_scene("room", tmp_path)
    np.testing.assert_allclose(room.mesh.bounds, room.tight_box.double().numpy(), atol=2e-3)
    assert room.source == "mesh" and len(room.mesh.faces) == 20100 and room.mesh.visual.kind == "face"
    assert len(np.unique(room.mesh.visual.face_colors, axis=0)) == 5 and room.asset_to_scene[2, 1] == 1.0
    (tmp_path / "room" / "room.blend").write_bytes(b"")
    assert find_asset(scene_config("room"), tmp_path)[0].name == "room.blend"  # a .blend is preferred


def test_scene_asset_names_the_one_file_a_scene_is_built_from(assets_dir, tmp_path):
    """``scene.asset`` picks Room's metric OBJ where the lookup would prefer room.blend (its up axis that of
    the declared file of that path: Y-up), and a named file that is missing is one line naming it."""
    (tmp_path / "room").mkdir()
    for name in ("room_nvf_gt_yup.obj", "room_nvf_gt_yup.mtl"):
        shutil.copy(assets_dir / "room" / name, tmp_path / "room" / name)
    (tmp_path / "room" / "room.blend").write_bytes(b"")
    named = scene_config("room") | {"asset": "room/room_nvf_gt_yup.obj"}
    assert find_asset(named, tmp_path) == (tmp_path / "room" / "room_nvf_gt_yup.obj", "y")
    room = load_scene(named, tmp_path)
    assert room.source == "mesh" and len(room.mesh.faces) == 20100 and room.asset_to_scene[2, 1] == 1.0
    with pytest.raises(SceneError, match=r"expected .*room/other.obj \(scene.asset names it") as info:
        load_scene(scene_config("room") | {"asset": "room/other.obj"}, tmp_path)
    assert "\n" not in str(info.value)
    with pytest.raises(SceneError, match="scene.asset names a file but source='procedural'"):
        load_scene(scene_config("default") | {"asset": "room/room_nvf_gt_yup.obj"}, tmp_path)


def test_default_scene():
    scene = load_scene("default", None)
    assert scene.source == "procedural" and scene.mesh.visual.kind == "face"
    tight = scene.tight_box.double().numpy()
    np.testing.assert_allclose(tight, scene.mesh.bounds, atol=1e-6)
    aabb = scene.object_aabb.double().numpy()
    assert np.all(aabb[0] < tight[0]) and np.all(aabb[1] > tight[1])
    np.testing.assert_allclose(scene.camera_box[1, 2] - aabb[0, 2], 2.5 * (aabb[1, 2] - aabb[0, 2]), rtol=1e-5)
    positions = torch.cat([scene.init_poses, scene.eval_poses])[:, :3, 3].numpy()
    cam = scene.camera_box.numpy()
    assert np.all(positions >= cam[0] - 1e-4) and np.all(positions <= cam[1] + 1e-4)


def test_missing_mesh_errors(tmp_path):
    with pytest.raises(SceneError) as info:
        load_scene("lego", tmp_path)
    message = str(info.value)
    assert "\n" not in message and "lego.glb" in message and "lego_proxy" in message and "NVF_ASSETS" in message
    assert "paths.assets" in message and "lego.blend" in message and "README" in message
    with pytest.raises(SceneError, match="room.blend.*room_nvf_gt_yup.obj"):
        load_scene("room", tmp_path)
    with pytest.raises(SceneError, match="unknown scene"):
        load_scene("teapot", tmp_path)


def test_user_mesh_lookup_and_bad_meshes(tmp_path):
    box = load_scene("chair_proxy", None)
    (tmp_path / "chair").mkdir()
    box.mesh.export(tmp_path / "chair" / "chair.ply")
    scene = load_scene("chair", tmp_path)
    assert scene.source == "mesh" and len(scene.mesh.faces) == len(box.mesh.faces)
    yup = box.mesh.copy()
    yup.apply_transform(trimesh.transformations.rotation_matrix(-math.pi / 2, (1, 0, 0)))
    (tmp_path / "mic").mkdir()
    yup.export(tmp_path / "mic" / "mic.glb")
    with pytest.raises(SceneError, match="tight box"):
        load_scene("mic", tmp_path)
    (tmp_path / "ship").mkdir()
    (tmp_path / "ship" / "ship.obj").write_text("garbage\n")
    with pytest.raises(SceneError):
        load_scene("ship", tmp_path)
    flat = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]], process=False)
    (tmp_path / "drums").mkdir()
    flat.export(tmp_path / "drums" / "drums.ply")
    with pytest.raises(SceneError, match="degenerate"):
        load_scene("drums", tmp_path)
    nan = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, np.nan, 1]], [[0, 1, 2]], process=False)
    (tmp_path / "ficus").mkdir()
    nan.export(tmp_path / "ficus" / "ficus.ply")
    with pytest.raises(SceneError, match="non-finite"):
        load_scene("ficus", tmp_path)


def test_show_cli_bad_input(capsys):
    """Bad input: one line on stderr, non-zero exit, no traceback (in a subprocess and in-process)."""
    result = subprocess.run(
        [sys.executable, "-m", "pipeline.scenes", "show", "teapot"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode != 0
    assert len(result.stderr.strip().splitlines()) == 1 and "Traceback" not in result.stderr
    from pipeline.scenes.__main__ import main

    with pytest.raises(SystemExit) as info:
        main(["show", "lego", "paths.assets=/nonexistent"])
    err = capsys.readouterr().err
    assert info.value.code == 2 and len(err.strip().splitlines()) == 1 and "lego_proxy" in err


def test_show_reads_the_scenes_own_overrides_and_bounds_its_resolution(tmp_path, capsys):
    """``scenes show`` ignored ``scene.*`` overrides (``scene.asset``, the boxes) and drew the declared scene; it
    now builds the scene the overrides declare, so a misplaced box is refused as a run refuses it. ``--res
    100000`` asked for 37 GiB of images; the resolution is bounded."""
    from pipeline.scenes.__main__ import main

    with pytest.raises(SystemExit) as info:
        main(["show", "default", "scene.tight_box=[[5,5,5],[6,6,6]]", f"paths.results={tmp_path}"])
    err = capsys.readouterr().err
    assert info.value.code == 2 and err.count("\n") == 1 and "box" in err
    with pytest.raises(SystemExit) as info:
        main(["show", "default", "--res", "100000", f"paths.results={tmp_path}"])
    err = capsys.readouterr().err
    assert info.value.code == 2 and "--res 100000: must be 8..2048" in err
    assert not (tmp_path / "figures").exists()


def test_an_asset_outside_the_assets_folder_is_recorded_by_its_whole_path(tmp_path):
    """``ground_truth.asset`` of a file outside ``paths.assets`` is its absolute path, so a file of the same name in
    another folder is another asset (``built_differently``); one under it (through a link too) is its path
    relative to the folder."""
    import dataclasses

    from pipeline.scenes.ground_truth import built_differently, ground_truth_info
    from pipeline.scenes.mesh_renderer import GroundTruthRenderer

    for folder in ("mine", "other", "assets/hotdog"):
        (tmp_path / folder).mkdir(parents=True)
        (tmp_path / folder / "hotdog.ply").write_bytes(b"ply")
    scene = dataclasses.replace(load_scene("default"), source="mesh", asset=tmp_path / "mine" / "hotdog.ply")
    renderer = GroundTruthRenderer(scene.mesh)
    info = {"scene_source": "mesh", "ground_truth": ground_truth_info(scene, renderer, tmp_path / "assets")}
    assert info["ground_truth"] == {"backend": "pyrender", "asset": (tmp_path / "mine" / "hotdog.ply").as_posix()}
    assert built_differently(info, scene) is None
    other = dataclasses.replace(scene, asset=tmp_path / "other" / "hotdog.ply")
    assert "scene asset" in (built_differently(info, other) or "")
    inside = dataclasses.replace(scene, asset=tmp_path / "assets" / "hotdog" / "hotdog.ply")
    assert ground_truth_info(inside, renderer, tmp_path / "assets")["asset"] == "hotdog/hotdog.ply"
    (tmp_path / "linked").mkdir()  # an assets folder whose scene folder links elsewhere: the path inside it
    (tmp_path / "linked" / "hotdog").symlink_to(tmp_path / "mine")
    linked = dataclasses.replace(scene, asset=tmp_path / "linked" / "hotdog" / "hotdog.ply")
    assert ground_truth_info(linked, renderer, tmp_path / "linked")["asset"] == "hotdog/hotdog.ply"


def test_a_record_predating_its_asset_name_is_held_to_its_scenes_declared_file():
    """A mesh record that predates ``ground_truth.asset`` (every committed NVF record) took any build of its scene
    (a box as hotdog's state); it was built from the scene's declared file, so a build from another is refused."""
    import dataclasses
    from pathlib import Path

    from pipeline.scenes.ground_truth import built_differently

    declared = ("hotdog/hotdog_nvf_geom_heuristic_colors.ply",)
    scene = dataclasses.replace(load_scene("default"), source="mesh", declared_files=declared)
    legacy = {"scene_source": "mesh"}
    box = dataclasses.replace(scene, asset=Path("/assets/hotdog/hotdog.glb"))
    assert "predates ground_truth.asset" in (built_differently(legacy, box) or "")
    assert built_differently(legacy, dataclasses.replace(scene, asset=Path("/assets") / declared[0])) is None
    assert built_differently({"scene_source": "procedural"}, load_scene("default")) is None


def test_a_scene_of_your_own_from_a_mesh_in_one_command(tmp_path, capsys):
    """``scenes new NAME --mesh FILE``: the yaml in your config directory with PROTOCOL 2.1's boxes (tight = the
    mesh's bounds, object 10% wider, camera x 2.5 about (0, 0, z_min)), its picture and the command that runs it;
    the scene then builds through the search path as a declared one does. A name the benchmark declares, or a
    yaml that exists, is one line."""
    import trimesh

    from pipeline.config.validation import compose_run
    from pipeline.scenes.__main__ import main
    from pipeline.scenes.new_scene import derived_boxes

    boxes = derived_boxes(np.array([[-1.0, -2.0, 0.0], [1.0, 2.0, 1.0]]))
    assert boxes["object_aabb"] == [[-1.2, -2.4, -0.1], [1.2, 2.4, 1.1]]
    assert boxes["camera_box"] == [[-3.0, -6.0, -0.1], [3.0, 6.0, 2.9]]
    (tmp_path / "assets" / "cup").mkdir(parents=True)
    mesh = trimesh.creation.icosphere(subdivisions=1, radius=0.4)
    mesh.apply_translation([0.0, 0.0, 0.4])
    mesh.export(tmp_path / "assets" / "cup" / "cup.ply")
    argv = ["new", "cup", "--mesh", str(tmp_path / "assets" / "cup" / "cup.ply"), "--conf", str(tmp_path / "conf")]
    main([*argv, f"paths.results={tmp_path / 'res'}"])
    out = capsys.readouterr().out
    assert "scene=cup" in out and (tmp_path / "res" / "figures" / "scenes" / "cup.png").is_file()
    run = compose_run(
        ["scene=cup", f"hydra.searchpath=[file://{tmp_path / 'conf'}]", f"paths.assets={tmp_path / 'assets'}"]
    )
    scene = load_scene(run.scene, tmp_path / "assets")
    assert scene.source == "mesh" and np.allclose(scene.tight_box.numpy(), mesh.bounds, atol=1e-5)
    for again, says in ((argv, "exists"), (["new", "hubble", *argv[2:]], "the benchmark's own")):
        with pytest.raises(SystemExit) as info:
            main(again)
        err = capsys.readouterr().err
        assert info.value.code == 2 and says in err and err.count("\n") == 1
