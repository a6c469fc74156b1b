"""The Blender ground-truth backend (pipeline.scenes.blender): .blend scenes, Cycles images against the
shared ray cast and pyrender, determinism, the light rig of mesh scenes, and bad input.

Every .blend here is built by the test with Blender's own Python (no downloaded asset); tests that need
Blender skip, saying how to install it, where ``paths.blender_python`` does not exist.
"""

import dataclasses
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from hydra import compose, initialize_config_dir
from PIL import Image
from scipy.ndimage import binary_erosion

from nvf.cameras import Intrinsics, look_at
from pipeline.config.validation import ConfigError, validate
from pipeline.episode.runner import run_episode
from pipeline.records.lock import RunLock
from pipeline.records.store import RunRecord
from pipeline.repo import CONF, REPO
from pipeline.scenes.__main__ import main as scenes_main
from pipeline.scenes.blender import (
    BlenderError,
    BlenderProcess,
    BlenderRenderer,
    BlenderTimeout,
    blender_python,
    missing_python,
)
from pipeline.scenes.blender_worker import linear_to_srgb
from pipeline.scenes.loading import load_scene, scene_config
from pipeline.scenes.mesh_renderer import GroundTruthRenderer
from pipeline.scenes.scene import SceneError

PYTHON = blender_python()
needs_blender = pytest.mark.skipif(missing_python(PYTHON) is not None, reason=str(missing_python(PYTHON)))
SCENE = "chair"  # a paper scene whose tight box the test .blend fills
INTR = Intrinsics.from_fov(64, 64)
BODY, CUBE = (0.8, 0.3, 0.1), (0.1, 0.4, 0.8)  # linear base colours

# Run by Blender's Python: an ellipsoid filling the tight box and a cube in its corner, each with a material
# (Principled or emission-only), optionally a sun, a world and a scale; saved with save_as_mainfile.
BUILD = r"""
import json, sys
import bpy, bmesh
from mathutils import Matrix
spec = json.loads(sys.argv[1])
bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
lo, hi = spec["box"]
centre = [(a + b) / 2 for a, b in zip(lo, hi)]
half = [(b - a) / 2 for a, b in zip(lo, hi)]

def material(name, rgb):
    m = bpy.data.materials.new(name)
    nodes, links = m.node_tree.nodes, m.node_tree.links
    output = next(n for n in nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    if spec["emission"]:
        nodes.remove(next(n for n in nodes if n.bl_idname == "ShaderNodeBsdfPrincipled"))
        emit = nodes.new("ShaderNodeEmission")
        emit.inputs["Color"].default_value = (*rgb, 1.0)
        emit.inputs["Strength"].default_value = 1.0
        links.new(emit.outputs[0], output.inputs["Surface"])
    else:
        bsdf = next(n for n in nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
        bsdf.inputs["Base Color"].default_value = (*rgb, 1.0)
    return m

def add(name, build, matrix, rgb):
    mesh = bpy.data.meshes.new(name)
    bm = bmesh.new()
    build(bm)
    bm.to_mesh(mesh)
    bm.free()
    mesh.materials.append(material(name, rgb))
    obj = bpy.data.objects.new(name, mesh)
    obj.matrix_world = Matrix.Scale(spec["scale"], 4) @ matrix
    scene.collection.objects.link(obj)

if spec["meshes"]:
    body = Matrix.Translation(centre) @ Matrix.Diagonal((*half, 1.0))
    add("body", lambda bm: bmesh.ops.create_uvsphere(bm, u_segments=32, v_segments=16, radius=1.0), body, spec["body"])
    corner = [c + 0.75 * h for c, h in zip(centre, half)]
    cube = Matrix.Translation(corner) @ Matrix.Diagonal((*[0.3 * h for h in half], 1.0))
    add("cube", lambda bm: bmesh.ops.create_cube(bm, size=1.0), cube, spec["cube"])
if spec["sun"]:
    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    sun.data.energy = 3.0
    sun.rotation_euler = (0.6, 0.2, 0.8)
    scene.collection.objects.link(sun)
world = bpy.data.worlds.new("world")
background = next(n for n in world.node_tree.nodes if n.bl_idname == "ShaderNodeBackground")
background.inputs["Strength"].default_value = spec["world"]
scene.world = world
if spec["emission"]:
    scene.view_settings.view_transform = "Standard"
bpy.ops.wm.save_as_mainfile(filepath=spec["path"])
"""


def build_blend(assets: Path, emission=False, scale=1.0, meshes=True, sun=True, world=0.3) -> Path:
    """``<assets>/chair/chair.blend`` built by Blender's Python from ``BUILD``."""
    path = assets / SCENE / f"{SCENE}.blend"
    path.parent.mkdir(parents=True, exist_ok=True)
    spec = {
        "path": str(path),
        "box": [list(v) for v in scene_config(SCENE)["tight_box"]],
        "emission": emission,
        "scale": scale,
        "meshes": meshes,
        "sun": sun and not emission,
        "world": 0.0 if emission else world,
        "body": BODY,
        "cube": CUBE,
    }
    subprocess.run([str(PYTHON), "-c", BUILD, json.dumps(spec)], check=True, capture_output=True, timeout=120)
    return path


def srgb_bytes(rgb) -> list[int]:
    return [int(v) for v in np.round(linear_to_srgb(np.array(rgb)) * 255)]


@pytest.fixture(scope="module")
def lit(tmp_path_factory):
    """The lit chair .blend, its scene and one Blender renderer (16 samples per pixel)."""
    if missing_python(PYTHON):
        pytest.skip(missing_python(PYTHON))
    assets = tmp_path_factory.mktemp("lit")
    build_blend(assets)
    scene = load_scene(SCENE, assets)
    with BlenderRenderer(scene, 16, PYTHON, threads=1) as renderer:
        yield assets, scene, renderer


def test_importing_the_backend_does_not_load_blender():
    assert "bpy" not in sys.modules


@needs_blender
def test_blend_loads_as_a_scene_and_renders(lit):
    """The .blend's render-visible triangles are the scene's mesh, coloured with its materials' base colours;
    Cycles renders it lit (shading varies over one material) with a coverage alpha."""
    assets, scene, renderer = lit
    assert scene.source == "blend" and scene.asset == assets / SCENE / f"{SCENE}.blend"
    assert len(scene.mesh.faces) == 32 * 14 * 2 + 32 * 2 + 12  # UV sphere (quads + pole fans) and a cube
    colors = {tuple(c[:3]) for c in scene.mesh.visual.face_colors.tolist()}
    assert colors == {tuple(srgb_bytes(BODY)), tuple(srgb_bytes(CUBE))}
    np.testing.assert_allclose(scene.mesh.bounds, np.array(scene_config(SCENE)["tight_box"]), atol=1e-5)
    view = renderer.render(scene.eval_poses[0], INTR)
    assert view.rgb.shape == (64, 64, 3) and view.rgb.dtype == np.float32
    far = binary_erosion(~view.mask, iterations=2)  # background 2 px away from any hit
    assert 0.05 < view.mask.mean() < 0.9 and view.rgb[far].max() == 0.0
    body = view.face_id >= 0
    body &= np.isin(view.face_id, np.flatnonzero(scene.mesh.visual.face_colors[:, 0] == srgb_bytes(BODY)[0]))
    luminance = view.rgb[binary_erosion(body, iterations=2)].mean(axis=-1)
    assert luminance.max() - luminance.min() > 0.1  # lit: not one flat colour


@needs_blender
def test_silhouette_matches_the_ray_cast_hit_mask(lit):
    """Cycles' coverage alpha > 0.5 against open3d's pixel-centre hits: IoU >= 0.98 at 64 px in every view
    (measured 0.991-1.0 over the 20 evaluation views)."""
    _, scene, renderer = lit
    for c2w in scene.eval_poses:
        alpha = renderer.render_rgba(c2w, INTR)[..., 3] > 0.5
        _, mask, _ = renderer.ray_cast_view(c2w.double().numpy(), INTR)
        assert (alpha & mask).sum() / (alpha | mask).sum() >= 0.98


@needs_blender
def test_the_same_view_renders_identically_twice(lit):
    """A fixed seed: the same image from one worker twice, and from a second worker."""
    assets, scene, renderer = lit
    first = renderer.render_rgba(scene.eval_poses[3], INTR)
    assert np.array_equal(first, renderer.render_rgba(scene.eval_poses[3], INTR))
    with BlenderRenderer(scene, 16, PYTHON, threads=2) as other:
        assert np.array_equal(first, other.render_rgba(scene.eval_poses[3], INTR))


@needs_blender
@pytest.mark.slow
def test_emission_only_blend_matches_pyrender_flat_away_from_edges(tmp_path):
    """Emission-only materials (no light, Standard view): Cycles' image is the base colour, as pyrender's flat
    render of the exported triangles is, away from edges (pixels whose 5x5 neighbourhood shows one material).
    Measured 65.8-68.1 dB over the 20 evaluation views (largest difference 0.38/255: Cycles' 16-bit PNG
    against pyrender's 8 bits); asserted >= 55 dB, above the 54 dB that half an 8-bit step everywhere gives,
    so a colour-space slip (about 20 dB) fails."""
    build_blend(tmp_path, emission=True)
    scene = load_scene(SCENE, tmp_path)
    with BlenderRenderer(scene, 4, PYTHON, threads=1) as blender, GroundTruthRenderer(scene.mesh) as flat:
        for c2w in scene.eval_poses[::4]:
            cycles, view = blender.render(c2w, INTR), flat.render(c2w, INTR)
            ids = view.face_id
            colour = np.where(ids >= 0, scene.mesh.visual.face_colors[ids, 0].astype(int), -1)
            same = np.ones_like(ids, dtype=bool)  # pixels whose 5x5 neighbourhood shows one material (or none)
            for dy in range(-2, 3):
                for dx in range(-2, 3):
                    same &= np.roll(colour, (dy, dx), axis=(0, 1)) == colour
            same[:2], same[-2:], same[:, :2], same[:, -2:] = False, False, False, False
            same &= ids >= 0
            assert same.sum() > 200
            error = float(np.mean((cycles.rgb[same] - view.rgb[same]) ** 2))
            assert 10 * np.log10(1.0 / max(error, 1e-12)) >= 55.0


@needs_blender
def test_mesh_scenes_get_the_light_rig_and_their_colours(tmp_path):
    """A mesh (not a .blend) is rendered under the fixed light rig with its own base colours: a textured
    quad facing the key light shows its texture's two halves in the right places, brighter than the same
    quad turned away from the key."""
    texture = np.zeros((8, 16, 3), np.uint8)
    texture[:, :8] = (200, 30, 30)  # left half red, right half blue
    texture[:, 8:] = (30, 30, 200)
    quad = trimesh.Trimesh(
        vertices=[[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]],
        faces=[[0, 1, 2], [0, 2, 3]],
        process=False,
        visual=trimesh.visual.TextureVisuals(
            uv=[[0, 0], [1, 0], [1, 1], [0, 1]],
            material=trimesh.visual.material.PBRMaterial(baseColorTexture=Image.fromarray(texture)),
        ),
    )
    scene = dataclasses.replace(load_scene("default"), mesh=quad)
    # north of the quad (off the key sun's mirror direction: no highlight), so image x runs along world -x
    above = look_at(torch.tensor([0.0, 1.0, 2.0]), torch.zeros(3))
    below = look_at(torch.tensor([0.0, 1.0, -2.0]), torch.zeros(3))
    with BlenderRenderer(scene, 16, PYTHON, threads=1) as renderer:
        top = renderer.render(above, INTR).rgb
        bottom = renderer.render(below, INTR).rgb
    blue, red = top[32, 22], top[32, 42]
    assert red[0] > 2 * red[2] and blue[2] > 2 * blue[0]
    assert top[28:36, 22:42].mean() > 1.3 * bottom[28:36, 22:42].mean()  # the key sun is above the horizon


def _show(capsys, *args) -> tuple[int, str]:
    with pytest.raises(SystemExit) as exit_info:
        scenes_main(["show", *args])
    return exit_info.value.code, capsys.readouterr().err


@pytest.mark.parametrize("content", [None, b"", b"BLENDER-v300 not really a blend file" * 10])
def test_missing_empty_or_corrupt_blend_is_one_line(tmp_path, capsys, content):
    """No .blend (nor a mesh), an empty one or a corrupt one: one line naming the file, exit 2, no picture."""
    if content is not None:
        if missing_python(PYTHON):
            pytest.skip(missing_python(PYTHON))
        (tmp_path / SCENE).mkdir()
        (tmp_path / SCENE / f"{SCENE}.blend").write_bytes(content)
    code, err = _show(capsys, SCENE, f"paths.assets={tmp_path}", "--out", str(tmp_path / "out"), "--res", "16")
    assert code == 2 and err.count("\n") == 1 and err.startswith("error: ")
    assert f"{SCENE}.blend" in err
    assert ("asset not found" in err) if content is None else ("cannot read" in err)
    assert not (tmp_path / "out").exists()


@needs_blender
@pytest.mark.slow
def test_a_blend_without_meshes_or_out_of_the_box_is_one_line(tmp_path):
    build_blend(tmp_path, meshes=False)
    with pytest.raises(SceneError, match="no render-visible mesh object") as info:
        load_scene(SCENE, tmp_path)
    assert "\n" not in str(info.value)
    build_blend(tmp_path, scale=3.0)
    with pytest.raises(SceneError, match="tight box.*move and scale its objects") as info:
        load_scene(SCENE, tmp_path)
    assert "\n" not in str(info.value)


def test_missing_blender_is_one_line_saying_how_to_install(tmp_path, capsys):
    missing = tmp_path / "no-blender" / "python"
    code, err = _show(
        capsys,
        "default",
        "render.backend=blender",
        f"paths.blender_python={missing}",
        "--out",
        str(tmp_path / "out"),
        "--res",
        "16",
    )
    assert code == 2 and err.count("\n") == 1 and "make blender" in err and str(missing) in err
    assert not (tmp_path / "out").exists()
    with initialize_config_dir(str(CONF), version_base="1.3"):
        cfg = compose(
            "config",
            overrides=[
                "budget=smoke",
                "render.backend=blender",
                f"paths.blender_python={missing}",
                f"paths.outputs={tmp_path / 'runs'}",
            ],
        )
    with pytest.raises(ConfigError, match="render.backend=blender: Blender's Python not found.*make blender"):
        run_episode(validate(cfg))  # refused by the renderer's check before the run's record or lock exists
    assert not (tmp_path / "runs").exists()


def test_blender_takes_cycles_samples_not_supersampling(tmp_path):
    with initialize_config_dir(str(CONF), version_base="1.3"):
        cfg = compose("config", overrides=["budget=smoke", "render.backend=blender", "budget.gt_samples=2"])
    with pytest.raises(ConfigError, match="set budget.gt_samples=1"):
        validate(cfg)


@needs_blender
def test_a_dead_worker_is_one_line(lit):
    """Cycles or Blender failing mid-run (here: its process killed) is a one-line BlenderError, a SceneError."""
    _, scene, _ = lit
    renderer = BlenderRenderer(scene, 1, PYTHON, threads=1)
    renderer._process._process.kill()
    with pytest.raises(BlenderError, match="Blender's worker exited") as info:
        renderer.render_rgba(scene.eval_poses[0], INTR)
    assert "\n" not in str(info.value) and isinstance(info.value, SceneError)
    renderer.close()


@needs_blender
@pytest.mark.slow
def test_a_smoke_episode_on_blender_ground_truth_records_it(tmp_path):
    """Render.backend=blender end to end: the run is done and its record names the backend, samples and asset
    file; the ground truth in its images is Cycles' (lit), not pyrender's."""
    assets = tmp_path / "assets"
    build_blend(assets)
    overrides = [
        "budget=smoke",
        f"scene={SCENE}",
        "method=random",
        "budget.horizon=1",
        f"paths.outputs={tmp_path}",
        f"paths.assets={assets}",
        "render.backend=blender",
        "render.samples=4",
    ]
    with initialize_config_dir(str(CONF), version_base="1.3"):
        cfg = compose("config", overrides=overrides)
    directory = run_episode(validate(cfg)).directory
    assert RunRecord(directory).is_done()
    info = json.loads((directory / "run.json").read_text())
    assert info["scene_source"] == "blend" and info["config"]["render"] == {
        "backend": "blender",
        "samples": 4,
        "timeout": 1800.0,
    }
    assert info["ground_truth"]["backend"] == "blender" and info["ground_truth"]["asset"] == f"{SCENE}/{SCENE}.blend"
    assert info["ground_truth"]["samples"] == 4 and info["ground_truth"]["device"]


# A stand-in for Blender's Python that talks the worker's protocol and then stops answering (no bpy needed):
# ``silent`` never greets; ``hangs_on_render`` greets, opens any scene and never answers a render.
FAKE_WORKER = """#!{python}
import os, sys, time
sys.path.insert(0, {repo!r})
from pipeline.scenes.blender_worker import read_message, write_message
with open({pid_file!r}, "w") as f:
    f.write(str(os.getpid()))
out = sys.stdout.buffer
if {mode!r} == "hangs_on_render":
    write_message(out, {{"ok": True, "blender": "fake"}})
    while True:
        header, _ = read_message(sys.stdin.buffer)
        if header["cmd"] == "render":
            break
        write_message(out, {{"ok": True, "device": "CPU"}})
time.sleep(600)
"""


def _fake_worker(tmp_path: Path, mode: str) -> tuple[Path, Path]:
    """An executable stand-in for ``paths.blender_python`` and the file it writes its process id to."""
    script, pid_file = tmp_path / f"fake-{mode}", tmp_path / f"fake-{mode}.pid"
    script.write_text(FAKE_WORKER.format(python=sys.executable, repo=str(REPO), pid_file=str(pid_file), mode=mode))
    script.chmod(0o755)
    return script, pid_file


def _gone(pid_file: Path) -> bool:
    """Whether the process whose id ``pid_file`` holds no longer exists (killed and reaped)."""
    try:
        os.kill(int(pid_file.read_text()), 0)
    except ProcessLookupError:
        return True
    return False


def test_a_worker_that_never_answers_is_stopped_after_the_timeout(tmp_path):
    """A Blender worker that never answered hung the run forever. Each request now waits at
    most ``timeout`` seconds; then the worker is killed and the request fails with one line."""
    silent, silent_pid = _fake_worker(tmp_path, "silent")
    start = time.monotonic()
    with pytest.raises(BlenderTimeout, match=r"^Blender's worker did not answer within 1 s \(render.timeout\)") as info:
        BlenderProcess(silent, timeout=1.0)
    assert time.monotonic() - start < 30 and "\n" not in str(info.value) and _gone(silent_pid)
    hangs, hangs_pid = _fake_worker(tmp_path, "hangs_on_render")
    scene = load_scene("default", tmp_path)
    renderer = BlenderRenderer(scene, 1, hangs, timeout=5.0)  # room for its hello on a loaded machine
    with pytest.raises(BlenderTimeout, match="did not answer within 5 s"):
        renderer.render_rgba(scene.eval_poses[0], INTR)
    assert _gone(hangs_pid)
    with pytest.raises(BlenderTimeout):  # and stays stopped
        renderer.render_rgba(scene.eval_poses[0], INTR)
    renderer.close()


def test_a_run_whose_worker_hangs_fails_in_one_line_leaving_no_lock_or_process(tmp_path):
    """End to end: ``python -m pipeline.run`` with a worker that stops answering exits 1 with
    one ``error:`` line naming the timeout; the worker is gone, the run's lock free, the run left to resume."""
    hangs, pid_file = _fake_worker(tmp_path, "hangs_on_render")
    out = tmp_path / "out"
    overrides = [
        "budget=smoke",
        "method=random",
        "budget.horizon=1",
        "render.backend=blender",
        "render.timeout=2",
        f"paths.blender_python={hangs}",
        f"paths.outputs={out}",
    ]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    proc = subprocess.run(
        [sys.executable, "-m", "pipeline.run", *overrides],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    lines = [line for line in proc.stderr.splitlines() if line.strip() and "cpp_extension" not in line]
    assert proc.returncode == 1 and len(lines) == 1, proc.stderr
    assert lines[0].startswith(f"error: run {out / 'default' / 'random-argmax-none' / 'smoke' / 'seed_100'} stopped")
    assert "Blender's worker did not answer within 2 s (render.timeout)" in lines[0] and "to resume" in lines[0]
    assert _gone(pid_file)
    with RunLock(out / "default" / "random-argmax-none" / "smoke" / "seed_100", out):
        pass  # free
