"""``python -m pipeline.scenes show SCENE [KEY=VALUE ...] [--res N] [--out PATH]``: draw a scene's initial and
evaluation views and a top view with its boxes and cameras (``pipeline.scenes.show``), to check an asset
before a long run. ``python -m pipeline.scenes new NAME --mesh FILE [--conf DIR] [--up z|y]``: a scene of your own
from a mesh (``pipeline.scenes.new_scene``: its yaml in your config directory, boxes by PROTOCOL 2.1's rule), its
picture, and the command that runs it.

The overrides are the run config's, the scene's own keys among them (``scene.asset=FILE``,
``scene.tight_box=...``), e.g. ``paths.assets=DIR``, ``render.backend=blender render.samples=32``;
the picture goes to ``${paths.results}/figures/scenes/<scene>.png`` unless ``--out`` names a folder. Bad input
is one line on stderr and exit status 2.
"""

import argparse
import os
import re
import sys
from pathlib import Path

from pipeline.cli import ArgumentParser, bounded, description, fail, run_command
from pipeline.config.catalog import conf_dirs, option_problem, searchpath_of
from pipeline.config.validation import compose_run
from pipeline.scenes.blender import blender_python
from pipeline.scenes.ground_truth import open_renderer
from pipeline.scenes.loading import load_scene, scene_names
from pipeline.scenes.new_scene import assets_folder, new_scene
from pipeline.scenes.scene import SceneError
from pipeline.scenes.show import show

PLAIN_NAME = re.compile(r"[A-Za-z0-9_-]+")
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
    new_parser = sub.add_parser("new", help="a scene of your own from a mesh: its yaml, its picture, how to run it")
    new_parser.add_argument("scene", help="its name (letters, digits, '_', '-')")
    new_parser.add_argument(
        "overrides", nargs="*", metavar="KEY=VALUE", help="config overrides, e.g. paths.results=DIR"
    )
    new_parser.add_argument("--mesh", type=Path, required=True, help="the mesh (.glb, .gltf, .ply, .obj or .blend)")
    new_parser.add_argument(
        "--conf", type=Path, default=Path("my_conf"), help="your config directory (default my_conf)"
    )
    new_parser.add_argument("--up", choices=("z", "y"), default="z", help="the mesh's up axis (default z)")
    args, later = parser.parse_known_args(argv)  # overrides after an option (``--res 64 paths.assets=DIR``) too
    stray = next((word for word in later if word.startswith("-") or "=" not in word), None)
    if stray is not None:
        fail(f"python -m pipeline.scenes: unrecognized argument {stray!r} (see --help)")
    args.overrides += later
    if args.command == "new":
        create(args)
        return
    bounded("--res", args.res, 8, MAX_RES)
    problem = option_problem("scene", args.scene, conf_dirs(searchpath_of(args.overrides)))
    if problem is not None:
        fail(problem)
    print(draw(args.scene, args.overrides, args.out, args.res))


def draw(scene_name: str, overrides: list[str], out: Path | None, res: int) -> Path:
    """``show``'s picture of the scene the overrides declare, written under ``out`` (default the results' figures)."""
    cfg = compose_run([f"scene={scene_name}", *overrides])
    try:
        python = blender_python(cfg.paths.blender_python)
        scene = load_scene(cfg.scene, Path(cfg.paths.assets), python)
        with open_renderer(scene, cfg.render, python, threads=os.cpu_count()) as renderer:
            return show(scene, renderer, out or Path(cfg.paths.results) / "figures" / "scenes", res)
    except SceneError as exc:
        fail(str(exc))


def create(args: argparse.Namespace) -> None:
    """``new``: the scene's yaml in ``--conf``, its picture, and the command that runs it."""
    if not PLAIN_NAME.fullmatch(args.scene):
        fail(f"scene name {args.scene!r}: use letters, digits, '_' and '-'")
    if not args.mesh.is_file():
        fail(f"--mesh {args.mesh}: no such file")
    conf = args.conf.resolve()
    try:
        path = new_scene(args.scene, args.mesh, conf, args.up, blender_python(None))
    except SceneError as exc:
        fail(str(exc))
    assets = assets_folder(args.scene, args.mesh.resolve())
    found = [f"hydra.searchpath=[file://{conf}]", f"paths.assets={assets}"]
    picture = draw(args.scene, [*found, *args.overrides], None, 96)
    print(f"wrote {path}\nwrote {picture} (its views and boxes: check them)\nrun it with:")
    print(f'  python -m pipeline.run scene={args.scene} paths.assets={assets} "hydra.searchpath=[file://{conf}]"')


if __name__ == "__main__":
    run_command(main, sys.argv[1:])
