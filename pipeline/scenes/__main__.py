"""``python -m pipeline.scenes show SCENE``: draw a scene's views (``pipeline.scenes.show``)."""

import argparse
import sys
from pathlib import Path

from pipeline.repo import RESULTS
from pipeline.scenes.scene import SceneError, load_scene, scene_names
from pipeline.scenes.show import show


def main(argv: list[str] | None = None) -> None:
    """``show SCENE [--assets DIR] [--out DIR] [--res N]``: bad input is one line on stderr and exit status 2."""
    parser = argparse.ArgumentParser(prog="python -m pipeline.scenes", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    show_parser = sub.add_parser("show", help="write a PNG grid of a scene's views and a top view")
    show_parser.add_argument("scene", help=f"one of: {', '.join(scene_names())}")
    show_parser.add_argument("--assets", type=Path, default=None, help="assets directory (default: NVF_ASSETS)")
    show_parser.add_argument("--out", type=Path, default=RESULTS / "figures" / "scenes")
    show_parser.add_argument("--res", type=int, default=128, help="view resolution in pixels")
    args = parser.parse_args(argv)
    if args.res < 8:
        print(f"error: --res must be at least 8, got {args.res}", file=sys.stderr)
        raise SystemExit(2)
    try:
        scene = load_scene(args.scene, args.assets)
    except SceneError as exc:
        print(f"error: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    print(show(scene, args.out, args.res))


if __name__ == "__main__":
    main()
