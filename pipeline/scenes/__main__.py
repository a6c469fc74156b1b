"""``python -m pipeline.scenes show SCENE [KEY=VALUE ...] [--res N] [--out PATH]``: draw a scene's initial and
evaluation views and a top view with its boxes and cameras (``pipeline.scenes.show``), to check an asset
before a long run.

The overrides are the run config's, the scene's own keys among them (``scene.asset=FILE``,
``scene.tight_box=...``), e.g. ``paths.assets=DIR``, ``render.backend=blender render.samples=32``;
the picture goes to ``${paths.results}/figures/scenes/<scene>.png`` unless ``--out`` names a folder. Bad input
is one line on stderr and exit status 2.
"""

import os
import sys
from pathlib import Path

from pipeline.cli import ArgumentParser, bounded, description, fail, run_command
from pipeline.config.catalog import conf_dirs, option_problem, searchpath_of
from pipeline.config.validation import compose_run
from pipeline.scenes.blender import blender_python
from pipeline.scenes.ground_truth import open_renderer
from pipeline.scenes.loading import load_scene, scene_names
from pipeline.scenes.scene import SceneError
from pipeline.scenes.show import show

MAX_RES = 2048  # a view of the grid: its 30 views at 2048 px are about 1.5 GB of float32 images


def main(argv: list[str] | None = None) -> None:
    parser = ArgumentParser(prog="python -m pipeline.scenes", description=description(__doc__))
    sub = parser.add_subparsers(dest="command", required=True)
    show_parser = sub.add_parser("show", help="write a PNG grid of a scene's views and a top view")
    show_parser.add_argument(
        "scene", help=f"one of: {', '.join(scene_names())}, or your own with hydra.searchpath=[file://DIR]"
    )
    show_parser.add_argument(
        "overrides",
        nargs="*",
        metavar="KEY=VALUE",
        help="config overrides, e.g. paths.assets=DIR render.backend=blender",
    )
    show_parser.add_argument("--out", type=Path, default=None, help="folder (default ${paths.results}/figures/scenes)")
    show_parser.add_argument("--res", type=int, default=128, help=f"view resolution in pixels (8 to {MAX_RES})")
    args, later = parser.parse_known_args(argv)  # overrides after an option (``--res 64 paths.assets=DIR``) too
    stray = next((word for word in later if word.startswith("-") or "=" not in word), None)
    if stray is not None:
        fail(f"python -m pipeline.scenes: unrecognized argument {stray!r} (see --help)")
    args.overrides += later
    bounded("--res", args.res, 8, MAX_RES)
    problem = option_problem("scene", args.scene, conf_dirs(searchpath_of(args.overrides)))
    if problem is not None:
        fail(problem)
    cfg = compose_run([f"scene={args.scene}", *args.overrides])
    out = args.out or Path(cfg.paths.results) / "figures" / "scenes"
    try:
        python = blender_python(cfg.paths.blender_python)
        scene = load_scene(cfg.scene, Path(cfg.paths.assets), python)
        with open_renderer(scene, cfg.render, python, threads=os.cpu_count()) as renderer:
            path = show(scene, renderer, out, args.res)
    except SceneError as exc:
        fail(str(exc))
    print(path)


if __name__ == "__main__":
    run_command(main, sys.argv[1:])
