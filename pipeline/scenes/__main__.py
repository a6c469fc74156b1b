"""``python -m pipeline.scenes show SCENE``: draw a scene's views (``pipeline.scenes.show``)."""

import argparse
import os
import sys
from pathlib import Path

from pipeline.config.validation import compose_config
from pipeline.repo import RESULTS
from pipeline.scenes.blender import blender_python
from pipeline.scenes.ground_truth import open_renderer
from pipeline.scenes.scene import SCENE_NAMES, SceneError, load_scene
from pipeline.scenes.show import show


def main(argv: list[str] | None = None) -> None:
    """``show SCENE [--assets DIR] [--out DIR] [--res N] [KEY=VALUE ...]``: the overrides are the run config's
    (e.g. ``render.backend=blender render.samples=32``, ``paths.blender_python=...``). Bad input is one line on
    stderr and exit status 2."""
    parser = argparse.ArgumentParser(prog="python -m pipeline.scenes", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    show_parser = sub.add_parser("show", help="write a PNG grid of a scene's views and a top view")
    show_parser.add_argument("scene", help=f"one of: {', '.join(SCENE_NAMES)}")
    show_parser.add_argument("overrides", nargs="*", metavar="KEY=VALUE",
                             help="config overrides, e.g. render.backend=blender render.samples=32")
    show_parser.add_argument("--assets", type=Path, default=None, help="assets directory (default: paths.assets)")
    show_parser.add_argument("--out", type=Path, default=RESULTS / "figures" / "scenes")
    show_parser.add_argument("--res", type=int, default=128, help="view resolution in pixels")
    args = parser.parse_args(argv)
    if args.res < 8:
        print(f"error: --res must be at least 8, got {args.res}", file=sys.stderr)
        raise SystemExit(2)
    cfg = compose_config(args.overrides)
    assets = args.assets or Path(cfg.paths.assets)
    try:
        scene = load_scene(args.scene, assets, blender_python(cfg.paths.blender_python))
        with open_renderer(scene, cfg, threads=os.cpu_count()) as renderer:
            path = show(scene, renderer, args.out, args.res)
    except SceneError as exc:
        print(f"error: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    print(path)


if __name__ == "__main__":
    main()
