"""The Blender side of the Blender ground-truth backend: a worker process run by Blender's own Python
(``paths.blender_python``, the ``.venv-blender`` that scripts/setup.sh creates with the ``bpy`` wheel).

It imports only bpy, numpy and the standard library: bpy pins numpy 1.26 and cannot share the main
environment (numpy 2), so it runs as ``python -m pipeline.scenes.blender_worker`` with the repository on
``PYTHONPATH`` and talks to ``pipeline.scenes.blender`` over its stdin/stdout. Blender's own console output
goes to stderr. Each message is one JSON line, then the raw bytes of the arrays the line lists
(``write_message`` / ``read_message``, used by both sides). Every reply has ``ok``; a failed command
replies ``ok: false`` with a one-line ``error`` and the worker carries on.

Commands: ``open_blend`` (a .blend: its own materials, lights, world and colour management),
``open_mesh`` (triangles with per-corner colours or a base-colour texture, lit by ``LIGHT_RIG``),
``export`` (the evaluated, render-visible triangles of the open scene and each one's material base
colour) and ``render`` (Cycles, one camera pose, RGBA float32).

Render settings applied to every scene: Cycles on the CPU (or on a GPU where Cycles finds one), a
fixed seed, ``samples`` samples per pixel without adaptive sampling or denoising, the film filter left
as the file's (Blender's default: Blackman-Harris, 1.5 px), a transparent film (black background),
no motion blur, compositor or sequencer, no dither. The image is read back from a 16-bit PNG through
the scene's view transform; RGB is returned premultiplied by the coverage alpha (black background).

``LIGHT_RIG`` lights every scene the project builds (meshes, proxies, the procedural default), fixed
in the scene frame: a uniform white world of strength 0.3 (ambient light from every direction), a key
sun of strength 2.0 from azimuth 45 deg, elevation 60 deg and a fill sun of strength 0.8 from azimuth
225 deg, elevation 15 deg (both 3 deg wide); the "Standard" view transform, so a surface facing the key
shows about its base colour. Base colours are the mesh's vertex/face colours or texture (sRGB) through a
Principled BSDF with Blender's default roughness and specular.
"""

import json
import math
import os
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

SEED = 0
LIGHT_RIG: dict[str, Any] = {
    "ambient": 0.3,
    "suns": (
        {"name": "key", "strength": 2.0, "azimuth_deg": 45.0, "elevation_deg": 60.0, "angle_deg": 3.0},
        {"name": "fill", "strength": 0.8, "azimuth_deg": 225.0, "elevation_deg": 15.0, "angle_deg": 3.0},
    ),
}
MESH_TYPES = {"MESH", "CURVE", "SURFACE", "META", "FONT"}
GPU_KINDS = ("OPTIX", "CUDA", "HIP", "ONEAPI", "METAL")


# ----------------------------------------------------------------------------------------------
# messages (both sides)


def write_message(stream, header: dict, arrays: dict[str, np.ndarray] | None = None) -> None:
    """One JSON line naming ``arrays`` (name, dtype, shape), then their bytes in that order."""
    arrays = {k: np.ascontiguousarray(v) for k, v in (arrays or {}).items()}
    specs = [{"name": k, "dtype": v.dtype.str, "shape": list(v.shape)} for k, v in arrays.items()]
    stream.write(json.dumps({**header, "arrays": specs}).encode() + b"\n")
    for value in arrays.values():
        stream.write(value.data.cast("B"))
    stream.flush()


def _read_exact(stream, size: int) -> bytes:
    chunks, left = [], size
    while left:
        chunk = stream.read(left)
        if not chunk:
            raise EOFError("the other side closed the pipe mid-message")
        chunks.append(chunk)
        left -= len(chunk)
    return b"".join(chunks)


def read_message(stream) -> tuple[dict, dict[str, np.ndarray]]:
    """The next message: its header and its arrays; ``EOFError`` when the stream has ended."""
    line = stream.readline()
    if not line:
        raise EOFError("the other side closed the pipe")
    header = json.loads(line)
    arrays = {}
    for spec in header.pop("arrays", []):
        dtype = np.dtype(spec["dtype"])
        count = int(np.prod(spec["shape"], dtype=np.int64))
        arrays[spec["name"]] = np.frombuffer(_read_exact(stream, count * dtype.itemsize), dtype).reshape(spec["shape"])
    return header, arrays


def one_line(text: object) -> str:
    return " ".join(str(text).split())


# ----------------------------------------------------------------------------------------------
# colour


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """The sRGB transfer function's inverse (IEC 61966-2-1), elementwise on values in [0, 1]."""
    c = np.clip(c, 0.0, 1.0)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c: np.ndarray) -> np.ndarray:
    """The sRGB transfer function (IEC 61966-2-1), elementwise, clipped to [0, 1]."""
    c = np.clip(c, 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)


# ----------------------------------------------------------------------------------------------
# the worker (needs bpy)


class Worker:
    """One Blender session: the open scene, its camera and a scratch directory for rendered frames."""

    def __init__(self, bpy):
        self.bpy = bpy
        self.scratch = tempfile.TemporaryDirectory(prefix="nvf-blender-")
        self.camera = None
        self.device = "CPU"

    # -- scenes

    def open_blend(self, header: dict, arrays: dict) -> tuple[dict, dict]:
        path = Path(header["path"])
        if not path.is_file():
            raise FileNotFoundError(f"{path} does not exist")
        self.bpy.ops.wm.open_mainfile(filepath=str(path), load_ui=False)
        return self._configure(header, standard_view=False), {}

    def open_mesh(self, header: dict, arrays: dict) -> tuple[dict, dict]:
        bpy = self.bpy
        bpy.ops.wm.read_factory_settings(use_empty=True)
        scene = bpy.context.scene
        vertices, faces = arrays["vertices"].astype(np.float32), arrays["faces"].astype(np.int32)
        mesh = bpy.data.meshes.new("asset")
        mesh.vertices.add(len(vertices))
        mesh.vertices.foreach_set("co", vertices.ravel())
        mesh.loops.add(faces.size)
        mesh.loops.foreach_set("vertex_index", faces.ravel())
        mesh.polygons.add(len(faces))
        mesh.polygons.foreach_set("loop_start", np.arange(0, faces.size, 3, dtype=np.int32))
        mesh.update(calc_edges=True)
        material = bpy.data.materials.new("base")
        nodes, links = material.node_tree.nodes, material.node_tree.links
        bsdf = next(n for n in nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
        if "corner_colors" in arrays:
            colors = np.concatenate([srgb_to_linear(arrays["corner_colors"][:, :3]), np.ones((faces.size, 1))], axis=1)
            attribute = mesh.color_attributes.new("base", "FLOAT_COLOR", "CORNER")
            attribute.data.foreach_set("color", colors.astype(np.float32).ravel())
            source = nodes.new("ShaderNodeVertexColor")
            source.layer_name = "base"
        else:
            uv = mesh.uv_layers.new(name="uv")
            uv.data.foreach_set("uv", arrays["corner_uv"].astype(np.float32).ravel())
            texture = arrays["texture"]
            image = bpy.data.images.new("base", texture.shape[1], texture.shape[0], alpha=False)
            rgba = np.concatenate([texture[..., :3] / 255.0, np.ones(texture.shape[:2] + (1,))], axis=-1)
            image.pixels.foreach_set(rgba[::-1].astype(np.float32).ravel())  # Blender's rows run bottom-up
            image.pack()
            source = nodes.new("ShaderNodeTexImage")
            source.image = image
        links.new(source.outputs["Color"], bsdf.inputs["Base Color"])
        mesh.materials.append(material)
        obj = bpy.data.objects.new("asset", mesh)
        scene.collection.objects.link(obj)
        self._light_rig(scene)
        return self._configure(header, standard_view=True), {}

    def _light_rig(self, scene) -> None:
        """``LIGHT_RIG`` (module docstring): a white world and two suns, fixed in the scene frame."""
        bpy = self.bpy
        from mathutils import Vector

        world = bpy.data.worlds.new("ambient")
        background = next(n for n in world.node_tree.nodes if n.bl_idname == "ShaderNodeBackground")
        background.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
        background.inputs["Strength"].default_value = LIGHT_RIG["ambient"]
        scene.world = world
        for sun in LIGHT_RIG["suns"]:
            light = bpy.data.lights.new(sun["name"], "SUN")
            light.energy = sun["strength"]
            light.angle = math.radians(sun["angle_deg"])
            az, el = math.radians(sun["azimuth_deg"]), math.radians(sun["elevation_deg"])
            towards = Vector((math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)))
            obj = bpy.data.objects.new(sun["name"], light)
            obj.rotation_mode = "QUATERNION"
            obj.rotation_quaternion = towards.to_track_quat("Z", "Y")  # a sun shines along its -Z
            scene.collection.objects.link(obj)

    def _configure(self, header: dict, standard_view: bool) -> dict:
        """The render settings of the module docstring and the project's camera; returns the device used."""
        bpy = self.bpy
        scene = bpy.context.scene
        render, cycles = scene.render, scene.cycles
        render.engine = "CYCLES"
        cycles.samples = int(header["samples"])
        cycles.use_adaptive_sampling = False
        cycles.use_denoising = False
        cycles.seed = SEED
        cycles.use_animated_seed = False
        render.film_transparent = True
        render.use_motion_blur = False
        render.use_border = False
        render.use_compositing = False
        render.use_sequencer = False
        render.dither_intensity = 0.0
        render.resolution_percentage = 100
        render.pixel_aspect_x = render.pixel_aspect_y = 1.0
        render.use_persistent_data = True
        if header.get("threads"):
            render.threads_mode = "FIXED"
            render.threads = int(header["threads"])
        settings = render.image_settings
        settings.file_format, settings.color_mode, settings.color_depth = "PNG", "RGBA", "16"
        settings.compression = 0
        if standard_view:
            scene.display_settings.display_device = "sRGB"
            scene.view_settings.view_transform = "Standard"
            scene.view_settings.look = "None"
            scene.view_settings.exposure = 0.0
            scene.view_settings.gamma = 1.0
        data = bpy.data.cameras.new("nvf_camera")
        data.type, data.sensor_fit, data.sensor_width = "PERSP", "HORIZONTAL", 36.0
        data.dof.use_dof = False
        self.camera = bpy.data.objects.new("nvf_camera", data)
        scene.collection.objects.link(self.camera)
        scene.camera = self.camera
        self.device = self._device(scene)
        return {"device": self.device, "blender": bpy.app.version_string}

    def _device(self, scene) -> str:
        """``GPU (<kind>: names)`` when Cycles finds a GPU, else ``CPU``."""
        preferences = self.bpy.context.preferences.addons["cycles"].preferences
        for kind in GPU_KINDS:
            try:
                preferences.compute_device_type = kind
            except TypeError:  # not built into this Blender
                continue
            preferences.get_devices()
            gpus = [d for d in preferences.devices if d.type == kind]
            if gpus:
                for d in preferences.devices:
                    d.use = d.type == kind
                scene.cycles.device = "GPU"
                return f"GPU ({kind}: {', '.join(d.name for d in gpus)})"
        scene.cycles.device = "CPU"
        return "CPU"

    # -- geometry

    def _viewport_as_render(self, scene) -> None:
        """Make the depsgraph's (viewport) evaluation what Cycles renders: render visibility, instancers
        and modifier levels; the evaluated triangles are then the rendered ones."""
        for collection in self.bpy.data.collections:
            collection.hide_viewport = collection.hide_render
        layers = [self.bpy.context.view_layer.layer_collection]
        while layers:
            layer = layers.pop()
            layer.hide_viewport = False  # the eye icon: a viewport-only hide
            layers.extend(layer.children)
        in_layer = set(self.bpy.context.view_layer.objects)
        for obj in scene.objects:
            obj.hide_viewport = obj.hide_render
            if obj in in_layer:
                obj.hide_set(False)
            obj.show_instancer_for_viewport = obj.show_instancer_for_render
            for modifier in obj.modifiers:
                modifier.show_viewport = modifier.show_render
                if hasattr(modifier, "render_levels") and hasattr(modifier, "levels"):
                    modifier.levels = modifier.render_levels

    def export(self, header: dict, arrays: dict) -> tuple[dict, dict]:
        """World-space triangles of every render-visible, camera-visible object (instances included) and
        each triangle's material base colour (display sRGB, RGBA in [0, 1])."""
        bpy = self.bpy
        scene = bpy.context.scene
        self._viewport_as_render(scene)
        depsgraph = bpy.context.evaluated_depsgraph_get()
        depsgraph.update()
        vertices, faces, colors, count, objects = [], [], [], 0, 0
        for instance in depsgraph.object_instances:
            obj = instance.instance_object if instance.is_instance else instance.object
            original = obj.original
            if obj.type not in MESH_TYPES or not (instance.is_instance or instance.show_self):
                continue
            if not original.visible_camera or original.is_holdout or original.is_shadow_catcher:
                continue
            mesh = obj.to_mesh()
            try:
                mesh.calc_loop_triangles()
                n, v = len(mesh.loop_triangles), len(mesh.vertices)
                if n == 0:
                    continue
                co = np.empty(v * 3, np.float32)
                mesh.vertices.foreach_get("co", co)
                tris = np.empty(n * 3, np.int32)
                mesh.loop_triangles.foreach_get("vertices", tris)
                slots = np.empty(n, np.int32)
                mesh.loop_triangles.foreach_get("material_index", slots)
                world = np.array(instance.matrix_world, dtype=np.float64)
                vertices.append(co.reshape(-1, 3).astype(np.float64) @ world[:3, :3].T + world[:3, 3])
                faces.append(tris.reshape(-1, 3).astype(np.int64) + count)
                palette = np.array([_material_color(s.material) for s in obj.material_slots] or [_material_color(None)])
                colors.append(palette[np.clip(slots, 0, len(palette) - 1)])
                count += v
                objects += 1
            finally:
                obj.to_mesh_clear()
        if not faces:
            return {"objects": 0}, {}
        out = {
            "vertices": np.concatenate(vertices),
            "faces": np.concatenate(faces),
            "face_colors": np.concatenate(colors).astype(np.float32),
        }
        return {"objects": objects}, out

    # -- images

    def render(self, header: dict, arrays: dict) -> tuple[dict, dict]:
        """RGBA [H, W, 4] float32 of camera ``c2w`` (OpenGL axes, the asset's frame): RGB premultiplied."""
        bpy = self.bpy
        from mathutils import Matrix

        if self.camera is None:
            raise RuntimeError("no scene is open (open_blend or open_mesh first)")
        scene = bpy.context.scene
        width, height, focal = int(header["width"]), int(header["height"]), float(header["focal"])
        self.camera.matrix_world = Matrix(
            arrays["c2w"].astype(np.float64).tolist()
        )  # Blender cameras look down -Z, +Y up
        data = self.camera.data
        data.lens = focal / width * data.sensor_width
        data.clip_start, data.clip_end = float(header["near"]), float(header["far"])
        scene.render.resolution_x, scene.render.resolution_y = width, height
        path = Path(self.scratch.name) / "frame.png"
        path.unlink(missing_ok=True)
        scene.render.filepath = str(path)
        result = bpy.ops.render.render(write_still=True)
        if "FINISHED" not in result or not path.is_file():
            raise RuntimeError(f"Cycles did not render the view (render operator returned {sorted(result)})")
        image = bpy.data.images.load(str(path))
        try:
            image.colorspace_settings.name = "Non-Color"  # the PNG already went through the view transform
            pixels = np.empty(width * height * 4, np.float32)
            image.pixels.foreach_get(pixels)
        finally:
            bpy.data.images.remove(image)
            path.unlink(missing_ok=True)
        rgba = pixels.reshape(height, width, 4)[::-1]
        rgba = np.concatenate([rgba[..., :3] * rgba[..., 3:], rgba[..., 3:]], axis=-1)
        return {}, {"rgba": np.ascontiguousarray(rgba, dtype=np.float32)}


def _linked_color(socket) -> np.ndarray | None:
    """Display-sRGB RGB of what feeds a colour socket: an image's mean, or an RGB node's value."""
    if not socket.is_linked:
        return None
    node = socket.links[0].from_node
    if node.bl_idname == "ShaderNodeTexImage" and node.image is not None and node.image.size[0] > 0:
        pixels = np.empty(node.image.size[0] * node.image.size[1] * node.image.channels, np.float32)
        node.image.pixels.foreach_get(pixels)
        mean = pixels.reshape(-1, node.image.channels)[:, :3].mean(axis=0)
        return linear_to_srgb(mean) if node.image.is_float else mean  # byte images hold sRGB values
    if node.bl_idname == "ShaderNodeRGB":
        return linear_to_srgb(np.array(node.outputs[0].default_value[:3]))
    return None


def _shader_color(node, depth: int = 0) -> np.ndarray | None:
    """Display-sRGB base colour of a surface shader node (Principled, Diffuse, Emission, ...; mixes averaged)."""
    if node is None or depth > 8:
        return None
    if node.bl_idname in ("ShaderNodeMixShader", "ShaderNodeAddShader"):
        shaded = [
            _shader_color(s.links[0].from_node, depth + 1) for s in node.inputs if s.is_linked and s.type == "SHADER"
        ]
        parts = [p for p in shaded if p is not None]
        return np.mean(parts, axis=0) if parts else None
    for name in ("Base Color", "Color"):
        socket = node.inputs.get(name)
        if socket is not None and socket.type == "RGBA":
            linked = _linked_color(socket)
            return linked if linked is not None else linear_to_srgb(np.array(socket.default_value[:3]))
    return None


def _material_color(material) -> list[float]:
    """A material's base colour as display sRGB RGBA: its surface shader's colour input, else its viewport colour."""
    color = None
    if material is not None and material.node_tree is not None:
        outputs = [n for n in material.node_tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial"]
        output = next((n for n in outputs if n.is_active_output), outputs[0] if outputs else None)
        surface = output.inputs["Surface"] if output is not None else None
        if surface is not None and surface.is_linked:
            color = _shader_color(surface.links[0].from_node)
    if color is None:
        color = linear_to_srgb(np.array(material.diffuse_color[:3] if material is not None else (0.8, 0.8, 0.8)))
    return [*np.asarray(color, dtype=np.float64).tolist(), 1.0]


def main() -> None:
    """Serve commands on stdin/stdout until ``quit`` or end of input; Blender's own output goes to stderr."""
    commands_in = sys.stdin.buffer
    replies = os.fdopen(os.dup(sys.stdout.fileno()), "wb")
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())  # Blender prints to fd 1: keep it off the protocol
    try:
        import bpy
    except Exception as exc:  # a broken or missing bpy: say so in the greeting
        write_message(replies, {"ok": False, "error": f"cannot import bpy with {sys.executable}: {one_line(exc)}"})
        return
    worker = Worker(bpy)
    write_message(replies, {"ok": True, "blender": bpy.app.version_string})
    handlers = {
        "open_blend": worker.open_blend,
        "open_mesh": worker.open_mesh,
        "export": worker.export,
        "render": worker.render,
    }
    while True:
        try:
            header, arrays = read_message(commands_in)
        except EOFError:
            break
        command = header.get("cmd")
        if command == "quit":
            write_message(replies, {"ok": True})
            break
        try:
            if command not in handlers:
                raise ValueError(f"unknown command {command!r}")
            reply, out = handlers[command](header, arrays)
        except Exception as exc:  # one line back to the caller; the worker stays up
            write_message(replies, {"ok": False, "error": f"{type(exc).__name__}: {one_line(exc)}"})
            continue
        write_message(replies, {"ok": True, **reply}, out)
    worker.scratch.cleanup()


if __name__ == "__main__":
    main()
