"""``python -m pipeline.bench render [--res N ...] [--views K] [--samples S] [--scenes ...] [--backends ...]``:
ground-truth render time per view, both backends side by side in one run.

For each scene (default: ``default``, ``hotdog`` and ``room``) and resolution (default 64, the cpu budget's,
128 and the paper's 512, PROTOCOL.md 1), times over the first K evaluation views, reported as medians after
one warm-up view: the RGBA of the pyrender backend (flat, one sample per pixel: ``render_rgba`` with
``budget.gt_samples=1``), the RGBA of the Blender backend (Cycles at S samples per pixel, as many render
threads as cores) and the shared open3d ray cast (depth, mask, face ids), which both backends add to the
RGB; also the Blender worker's start (Blender and the scene; its BVH, built on the first view, is in the
warm-up). ``--backends pyrender`` leaves Blender out. The machine's load average at the start and end is
recorded (other jobs on the cores slow both backends). Writes ``results/bench/render.json`` and prints a table.
"""

import contextlib
import os
import platform
import statistics
import time
from pathlib import Path

from nvf.cameras import Intrinsics
from pipeline.bench._report import report_path, write_report
from pipeline.cli import ArgumentParser, bounded, description, fail
from pipeline.config.structured_configs import RenderConfig
from pipeline.config.validation import compose_run
from pipeline.scenes.blender import BlenderRenderer, blender_python
from pipeline.scenes.loading import load_scene
from pipeline.scenes.mesh_renderer import GroundTruthRenderer
from pipeline.scenes.scene import SceneError

MAX_RES = 4096  # pixels per side (the paper's evaluation views are 512)
MAX_SAMPLES = 4096  # Cycles samples per pixel (the benchmark's default is 64)


def _median_seconds(fn, poses) -> float:
    fn(poses[0])  # warm-up: context creation, shader compilation, texture upload, Cycles' BVH and kernels
    times = []
    for pose in poses:
        start = time.perf_counter()
        fn(pose)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main(argv: list[str]) -> None:
    parser = ArgumentParser(prog="python -m pipeline.bench render", description=description(__doc__))
    parser.add_argument("--res", type=int, nargs="+", default=[64, 128, 512], help="resolutions (pixels per side)")
    parser.add_argument("--views", type=int, default=4, help="evaluation views timed per scene and resolution")
    parser.add_argument("--samples", type=int, default=RenderConfig.samples, help="Cycles samples per pixel")
    parser.add_argument("--scenes", nargs="+", default=["default", "hotdog", "room"])
    parser.add_argument("overrides", nargs="*", metavar="KEY=VALUE", help="config overrides, e.g. paths.assets=DIR")
    parser.add_argument("--backends", nargs="+", choices=["pyrender", "blender"], default=["pyrender", "blender"])
    parser.add_argument(
        "--out", type=Path, default=None, help="JSON report path (default: ${paths.results}/bench/render.json)"
    )
    args = parser.parse_args(argv)
    for res in args.res:
        bounded("--res", res, 8, MAX_RES)
    bounded("--views", args.views, 1, 20, "the scene's evaluation views")
    bounded("--samples", args.samples, 1, MAX_SAMPLES)
    cfg = compose_run(args.overrides)
    args.out = report_path(args.out, cfg.paths.results, "render")  # checked before any work
    python, threads = blender_python(cfg.paths.blender_python), os.cpu_count() or 1
    use_blender, rows, version, load_start = "blender" in args.backends, [], None, os.getloadavg()
    try:
        for name in args.scenes:
            scene = load_scene(name, Path(cfg.paths.assets), python)
            poses = [p.numpy().astype("float64") for p in scene.eval_poses[: args.views]]
            with contextlib.ExitStack() as stack:
                flat = stack.enter_context(GroundTruthRenderer(scene.mesh))
                start = time.perf_counter()
                blender = (
                    stack.enter_context(BlenderRenderer(scene, args.samples, python, threads)) if use_blender else None
                )
                start_s = time.perf_counter() - start
                for res in sorted(set(args.res)):
                    intr = Intrinsics.from_fov(res, res)
                    row = {
                        "scene": name,
                        "source": scene.source,
                        "faces": len(scene.mesh.faces),
                        "resolution": res,
                        "views": len(poses),
                        "pyrender_platform": flat.backend,
                    }
                    if "pyrender" in args.backends:
                        row["pyrender_rgba_ms"] = 1e3 * _median_seconds(lambda p: flat.render_rgba(p, intr), poses)  # noqa: B023 - called at once
                    if blender is not None:
                        row["blender_rgba_ms"] = 1e3 * _median_seconds(lambda p: blender.render_rgba(p, intr), poses)  # noqa: B023 - called at once
                        row.update(blender_start_s=start_s, cycles_device=blender.device)
                        version = blender.version
                    if "pyrender_rgba_ms" in row and "blender_rgba_ms" in row:
                        row["blender_over_pyrender"] = row["blender_rgba_ms"] / row["pyrender_rgba_ms"]
                    row["ray_cast_ms"] = 1e3 * _median_seconds(lambda p: flat.ray_cast_view(p, intr), poses)  # noqa: B023 - called at once
                    rows.append(row)
    except SceneError as exc:
        fail(str(exc))
    report = {
        "benchmark": "render",
        "statistic": "median ms per view",
        "machine": platform.platform(),
        "processor": platform.processor(),
        "cores": threads,
        "cycles_samples": args.samples,
        "blender": version,
        "load_average_1_5_15_min": {"start": load_start, "end": os.getloadavg()},
        "rows": rows,
    }
    write_report(report, args.out)
    print(
        f"{'scene':<9}{'faces':>7}{'res':>5}{'pyrender ms':>13}{'Blender ms':>12}{'ratio':>8}{'ray cast ms':>13}"
        f"  (Cycles {args.samples} spp, {threads} threads)"
    )
    nan = float("nan")
    for r in rows:
        print(
            f"{r['scene']:<9}{r['faces']:>7}{r['resolution']:>5}{r.get('pyrender_rgba_ms', nan):>13.1f}"
            f"{r.get('blender_rgba_ms', nan):>12.1f}{r.get('blender_over_pyrender', nan):>8.1f}"
            f"{r['ray_cast_ms']:>13.1f}"
        )
    print(f"wrote {args.out}")
