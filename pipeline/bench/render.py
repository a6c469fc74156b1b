"""``python -m pipeline.bench render [--res N] [--views K] [--assets DIR] [--scenes ...]``: GT render time per view.

For each scene (default: ``default`` and ``room``) and resolution (the cpu budget's, 128 by default,
and the paper's 512, PROTOCOL.md 1), times over the first K evaluation views, reported as medians:
RGB + depth with pyrender and face ids with open3d ray casting, separately. Writes
``results/bench/render.json`` and prints a table.
"""

import argparse
import platform
import statistics
import sys
import time
from pathlib import Path

from nvf.cameras import Intrinsics
from pipeline.bench._report import write_report
from pipeline.scenes.render import GroundTruthRenderer
from pipeline.repo import RESULTS
from pipeline.scenes.scene import SceneError, load_scene

PAPER_RESOLUTION = 512


def _median_seconds(fn, poses) -> float:
    fn(poses[0])  # warm-up: context creation, shader compilation, texture upload
    times = []
    for pose in poses:
        start = time.perf_counter()
        fn(pose)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main(argv: list[str]) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.bench render", description=__doc__.splitlines()[0])
    parser.add_argument("--res", type=int, default=128, help="cpu-budget resolution (the paper's 512 is always run)")
    parser.add_argument("--views", type=int, default=8, help="evaluation views timed per scene and resolution")
    parser.add_argument("--scenes", nargs="+", default=["default", "room"])
    parser.add_argument("--assets", type=Path, default=None, help="assets directory (default: NVF_ASSETS)")
    parser.add_argument("--out", type=Path, default=RESULTS / "bench" / "render.json")
    args = parser.parse_args(argv)
    if args.res < 8 or not 1 <= args.views <= 20:
        print("error: --res must be >= 8 and --views in 1..20", file=sys.stderr)
        raise SystemExit(2)
    rows = []
    for name in args.scenes:
        try:
            scene = load_scene(name, args.assets)
        except SceneError as exc:
            print(f"error: {exc}", file=sys.stderr)
            raise SystemExit(2) from None
        poses = [p.numpy().astype("float64") for p in scene.eval_poses[: args.views]]
        with GroundTruthRenderer(scene.mesh) as renderer:
            for res in sorted({args.res, PAPER_RESOLUTION}):
                intr = Intrinsics.from_fov(res, res)
                rows.append({
                    "scene": name, "faces": len(scene.mesh.faces), "resolution": res, "views": len(poses),
                    "rgb_depth_ms": 1e3 * _median_seconds(lambda p: renderer.render_rgb_depth(p, intr), poses),
                    "face_id_ms": 1e3 * _median_seconds(lambda p: renderer.face_ids(p, intr), poses),
                    "backend": renderer.backend,
                })
    report = {"benchmark": "render", "statistic": "median ms per view", "machine": platform.platform(),
              "processor": platform.processor(), "rows": rows}
    write_report(report, args.out)
    print(f"{'scene':<10}{'faces':>8}{'res':>6}{'rgb+depth ms':>15}{'face ids ms':>14}  backend")
    for r in rows:
        print(f"{r['scene']:<10}{r['faces']:>8}{r['resolution']:>6}{r['rgb_depth_ms']:>15.1f}{r['face_id_ms']:>14.1f}"
              f"  {r['backend']}")
    print(f"wrote {args.out}")
