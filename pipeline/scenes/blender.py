"""The Blender ground-truth backend (``render.backend=blender``): RGB rendered with Cycles, as the paper
renders its ground truth, in a worker process (``pipeline.scenes.blender_worker``) run by Blender's own
Python (``paths.blender_python``; scripts/setup.sh creates ``.venv-blender`` with the ``bpy`` wheel).

One ``BlenderRenderer`` is one worker process; an episode keeps one for all its views. Each request (a
view, opening a scene) must be answered within ``render.timeout`` seconds: a worker that does not answer is
killed and the request fails with ``BlenderTimeout`` (one line), so a hung Blender never hangs a run. A scene with a
``.blend`` asset is rendered from that file (its materials, lights, world and colour management);
every other scene (meshes, proxies, the procedural default) from its triangles and base colours under
the worker's fixed ``LIGHT_RIG``. Depth, hit mask and face ids come from the same open3d ray cast as the
pyrender backend (``MeshRays``), so geometry, coverage and Vis. are identical across backends.
``export_blend`` reads a .blend's render-visible triangles and material base colours for scene loading.

Importing this module loads neither bpy nor Blender; only starting a worker does.
"""

import os
import subprocess
import tempfile
import threading
import weakref
from pathlib import Path

import numpy as np
import trimesh
from jaxtyping import Float
from torch import Tensor

from nvf.cameras import Intrinsics
from pipeline.config.structured_configs import RenderConfig
from pipeline.repo import REPO
from pipeline.scenes.blender_worker import one_line, read_message, write_message
from pipeline.scenes.mesh_renderer import GTView, MeshRays, as_pose, base_color_texture_mesh, corner_colors
from pipeline.scenes.scene import Scene, SceneError

DEFAULT_PYTHON = ".venv-blender/bin/python"
DEFAULT_TIMEOUT = RenderConfig.timeout  # seconds per request
INSTALL = "install it with `make blender` (scripts/setup.sh blender: .venv-blender with bpy==5.0.1)"


class BlenderError(SceneError):
    """Blender is missing, or its worker failed (a file it cannot open, Cycles failing); one-line message."""


class BlenderTimeout(RuntimeError):
    """Blender's worker did not answer a request in time and was killed; one-line message. Not a ``SceneError``:
    the scene and its settings may be fine (a loaded machine), so a run that meets it is left to resume."""


def blender_python(path: str | Path | None = None) -> Path:
    """Blender's Python: ``path`` (``paths.blender_python``; relative paths from the repository root), else
    ``NVF_BLENDER_PYTHON``, else the repository's ``.venv-blender/bin/python``."""
    chosen = Path(path or os.environ.get("NVF_BLENDER_PYTHON") or DEFAULT_PYTHON)
    return chosen if chosen.is_absolute() else REPO / chosen


def missing_python(python: Path) -> str | None:
    """The one-line reason ``python`` cannot run the Blender backend (None when it exists)."""
    if python.is_file():
        return None
    return (
        f"Blender's Python not found at {python}: {INSTALL}, or point paths.blender_python "
        "(NVF_BLENDER_PYTHON) at a Python 3.11 with bpy installed"
    )


def _stop(process: subprocess.Popen, log) -> None:
    """End a worker: close its input (it exits at end of input), then wait, then kill."""
    try:
        if process.stdin:
            process.stdin.close()
        process.wait(timeout=10)
    except (OSError, subprocess.TimeoutExpired):
        process.kill()
        process.wait()
    log.close()


class BlenderProcess:
    """One worker process: ``request`` sends a command and returns its reply within ``timeout`` seconds
    (else the worker is killed: ``BlenderTimeout``); ``close`` ends it (also at garbage collection or
    interpreter exit)."""

    def __init__(self, python: Path, timeout: float = DEFAULT_TIMEOUT):
        reason = missing_python(python)
        if reason:
            raise BlenderError(reason)
        self.timeout = float(timeout)
        self._timed_out = threading.Event()
        self._log = tempfile.TemporaryFile()
        env = {**os.environ, "PYTHONPATH": str(REPO)}
        self._process = subprocess.Popen(
            [str(python), "-m", "pipeline.scenes.blender_worker"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self._log,
            env=env,
            cwd=REPO,
        )
        self._finalizer = weakref.finalize(self, _stop, self._process, self._log)
        hello, _ = self._exchange(None, None)
        self.version = str(hello["blender"])

    def _kill(self) -> None:
        """The watchdog's action: the worker took longer than ``timeout``."""
        self._timed_out.set()
        self._process.kill()

    def _died(self) -> BlenderError | BlenderTimeout:
        code = self._process.wait()
        if self._timed_out.is_set():
            return BlenderTimeout(
                f"Blender's worker did not answer within {self.timeout:g} s (render.timeout) and was stopped; "
                "raise render.timeout if the machine renders that slowly"
            )
        self._log.seek(0)
        lines = [line for line in self._log.read().decode(errors="replace").splitlines() if line.strip()]
        last = one_line(lines[-1]) if lines else "no output"
        return BlenderError(f"Blender's worker exited with status {code}: {last}")

    def _reply(self) -> tuple[dict, dict[str, np.ndarray]]:
        try:
            header, arrays = read_message(self._process.stdout)
        except (EOFError, ValueError):
            raise self._died() from None
        if not header.get("ok"):
            raise BlenderError(f"Blender: {header.get('error', 'unknown error')}")
        return header, arrays

    def request(self, header: dict, arrays: dict[str, np.ndarray] | None = None) -> tuple[dict, dict[str, np.ndarray]]:
        """Send one command; its reply's header and arrays, or ``BlenderError`` with the worker's one line
        (``BlenderTimeout`` when no reply came within ``timeout`` seconds)."""
        if not self._finalizer.alive:
            raise BlenderError("Blender's worker was already closed")
        if self._timed_out.is_set():
            raise self._died()
        return self._exchange(header, arrays)

    def _exchange(
        self, header: dict | None, arrays: dict[str, np.ndarray] | None
    ) -> tuple[dict, dict[str, np.ndarray]]:
        """Write ``header`` (none: only read the greeting) and read the reply, both under the watchdog."""
        watchdog = threading.Timer(self.timeout, self._kill)
        watchdog.daemon = True
        watchdog.start()
        try:
            if header is not None:
                try:
                    write_message(self._process.stdin, header, arrays)
                except (BrokenPipeError, OSError):
                    raise self._died() from None
            return self._reply()
        finally:
            watchdog.cancel()

    def close(self) -> None:
        if self._finalizer.alive:
            try:
                write_message(self._process.stdin, {"cmd": "quit"})
            except OSError:
                pass
            self._finalizer()


def export_blend(path: Path, python: Path, timeout: float = DEFAULT_TIMEOUT) -> trimesh.Trimesh:
    """The render-visible triangles of ``path`` in its own frame, each face coloured with its material's
    base colour (``SceneError`` when it holds none, ``BlenderError`` when Blender cannot read it)."""
    process = BlenderProcess(python, timeout)
    try:
        process.request({"cmd": "open_blend", "path": str(path), "samples": 1})
        reply, arrays = process.request({"cmd": "export"})
    finally:
        process.close()
    if not reply["objects"]:
        raise SceneError(
            f"{path} has no render-visible mesh object (a mesh, curve or text that is renderable "
            "and visible to the camera); open it in Blender and check Object > Visibility"
        )
    colors = np.clip(np.round(arrays["face_colors"] * 255.0), 0, 255).astype(np.uint8)
    return trimesh.Trimesh(vertices=arrays["vertices"], faces=arrays["faces"], face_colors=colors, process=False)


def _mesh_arrays(mesh: trimesh.Trimesh) -> dict[str, np.ndarray]:
    """Vertices, faces and per-corner colours (or UVs and the texture, its factor baked in) for the worker."""
    corners = corner_colors(base_color_texture_mesh(mesh))
    arrays = {"vertices": np.asarray(mesh.vertices, np.float64), "faces": np.asarray(mesh.faces, np.int64)}
    if corners.texture is not None:
        assert corners.uv is not None, "a texture comes with its UVs (corner_colors)"
        texture = np.asarray(corners.texture.convert("RGB"), dtype=np.float64) * corners.factor[:3]
        arrays["corner_uv"] = corners.uv
        arrays["texture"] = np.clip(np.round(texture), 0, 255).astype(np.uint8)
    elif corners.colors is not None:
        arrays["corner_colors"] = corners.colors
    else:
        arrays["corner_colors"] = np.full((3 * len(mesh.faces), 4), 0.8, dtype=np.float32)
    return arrays


class BlenderRenderer(MeshRays):
    """The ground-truth renderer's interface (``render_rgba``, ``render``, ``face_ids``, ``cast_rays``,
    ``unoccluded``, ``line_of_sight``, ``inside``, ``close``) with RGB from Cycles at ``samples`` samples
    per pixel in one Blender worker that answers each request within ``timeout`` seconds; the rest from
    ``MeshRays`` on ``scene.mesh``."""

    def __init__(
        self, scene: Scene, samples: int, python: Path, threads: int | None = None, timeout: float = DEFAULT_TIMEOUT
    ):
        super().__init__(scene.mesh)
        self._process = BlenderProcess(python, timeout)
        settings = {"samples": int(samples), "threads": threads}
        try:
            if scene.asset is not None and scene.asset.suffix == ".blend":
                reply, _ = self._process.request({"cmd": "open_blend", "path": str(scene.asset), **settings})
                to_scene = scene.asset_to_scene if scene.asset_to_scene is not None else np.eye(4)
            else:
                reply, _ = self._process.request({"cmd": "open_mesh", **settings}, _mesh_arrays(scene.mesh))
                to_scene = np.eye(4)
        except (BlenderError, BlenderTimeout):
            self._process.close()
            raise
        self.samples = int(samples)
        self.device = str(reply["device"])
        self.version = self._process.version
        self._scale = float(np.cbrt(np.linalg.det(to_scene[:3, :3])))  # a similarity: uniform scale
        self._offset = to_scene[:3, 3].copy()
        self._diagonal = float(np.linalg.norm(self._bounds[1] - self._bounds[0]))

    def render_rgba(
        self, c2w: Float[Tensor, "4 4"] | Float[np.ndarray, "4 4"], intr: Intrinsics, samples_per_side: int = 1
    ) -> Float[np.ndarray, "H W 4"]:
        """Cycles' RGB (premultiplied: black background) and coverage alpha of the view ``c2w``. Cycles
        anti-aliases with its film filter, so there is no sub-pixel supersampling: ``samples_per_side`` must be 1."""
        if samples_per_side != 1:
            raise ValueError(
                f"the Blender backend takes render.samples per pixel, not samples_per_side={samples_per_side}"
            )
        pose = as_pose(c2w)
        in_asset = pose.copy()  # the camera moved into the asset's frame (the inverse of asset_to_scene)
        in_asset[:3, 3] = (pose[:3, 3] - self._offset) / self._scale
        header = {
            "cmd": "render",
            "width": intr.width,
            "height": intr.height,
            "focal": intr.focal,
            "near": 1e-4 * self._diagonal / self._scale,
            "far": 1e3 * self._diagonal / self._scale,
        }
        _, arrays = self._process.request(header, {"c2w": in_asset})
        return arrays["rgba"].copy()

    def render(self, c2w: Float[Tensor, "4 4"] | Float[np.ndarray, "4 4"], intr: Intrinsics) -> GTView:
        """Cycles' RGB (premultiplied) with depth, hit mask and face ids from the pixel-centre ray cast."""
        pose = as_pose(c2w)
        rgb = self.render_rgba(pose, intr)[..., :3]
        depth, mask, face_id = self.ray_cast_view(pose, intr)
        return GTView(rgb=rgb, depth=depth, mask=mask, face_id=face_id)

    def close(self) -> None:
        """End the Blender worker."""
        self._process.close()
