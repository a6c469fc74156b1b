"""``python -m pipeline.experiments.uncertainty [overrides]``: the stand-alone uncertainty experiment (PROTOCOL 4.4,
the paper's entropy-comparison figure), default ``scene=hotdog budget=cpu``.

One model per method is trained, as an episode's step 0 trains it (the method's stages and seeds), on
a one-sided "partial" training set (``partial_views``, drawn with seed 0) instead of the scene's
initial views. NVF's four ablations change only the score, so they are scored on NVF's model (unless
``train.ablation_affects_training``, which trains them on their own). On the scene's 20 evaluation
views each entry's per-pixel score is correlated with the per-pixel error (patch- and view-level
Pearson r, AUSE; ``pipeline.metrics.correlation.uncertainty_correlation``), next to the image and geometry
metrics of its model (PROTOCOL 4). Writes ``${paths.results}/uncertainty/<scene>_<budget>.{json,md,png}`` (or
``--out DIR``; settings beyond the budget are appended to its name, as in the tables): the numbers, a
table, and GT | prediction | error | every entry's score map of the evaluation view that looks most
unlike every training view (``least_seen_view``). ``--entries nvf,nvf-wo_vis,wd`` runs a subset of
``ENTRIES`` (named ``method`` or ``method-ablation``), appended to the file name.

Every entry is trained and scored once per seed of ``--seeds`` (default ``SEEDS``, the tables' three):
one model's correlations move by up to 0.2 (view r) with float-level differences alone (1 against 2
torch threads, results/uncertainty/README.md), so a row is the mean ± population std over the seeds, and the JSON keeps
every seed's numbers. Seeds other than ``SEEDS`` are appended to the file name. A killed run resumes at
its first missing seed.
"""

import dataclasses
import io
import json
import math
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import torch
from jaxtyping import Float
from matplotlib.figure import Figure
from torch import Tensor
from tqdm import tqdm

from nvf.cameras import look_at
from nvf.device import resolve_device
from nvf.model import SceneModel
from nvf.observations import Observations
from nvf.uncertainty import ViewScorer
from pipeline.atomic_write import atomic_write_bytes, atomic_write_text
from pipeline.cli import ArgumentParser, BadInput, description, fail, run_command
from pipeline.config.catalog import ablation_configs, method_configs, study_defaults
from pipeline.config.method import build_method
from pipeline.config.settings_beyond_groups import config_label
from pipeline.config.validation import compose_run
from pipeline.episode.loop import Episode
from pipeline.episode.settings import EpisodeSettings
from pipeline.experiments.options import SEEDS, seed_list
from pipeline.metrics.image import LpipsMetric
from pipeline.records.images import colorize, save_figure
from pipeline.records.store import to_jsonable
from pipeline.scenes.blender import blender_python
from pipeline.scenes.loading import load_scene
from pipeline.scenes.scene import Scene, SceneError
from pipeline.tables.aggregate import mean_std_valid
from pipeline.tables.labels import row_name
from pipeline.tables.table_formats import markdown_table

S = 0.16665  # PROTOCOL 2.3: the reference's scale unit s (Hubble's partial views)
PARTIAL_VIEWS = 20
PARTIAL_SEED = 0


def all_entries() -> tuple[tuple[str, str], ...]:
    """Every (method, ablation) with a per-pixel score, in the order of the table and the figure: each ablated
    method (NVF), then its ablations in Table S2's order, then the other methods that score pixels, in table
    order (``conf/method``, ``conf/ablation``; Random has no score, a method that scores whole views, FisherRF,
    no map to correlate)."""
    ablations = [a for a in ablation_configs().values() if a["name"] != "none"]
    ablated = {a["of"] for a in ablations}
    entries = [(method, "none") for method in ablated] + [(a["of"], a["name"]) for a in ablations]
    scoring = [name for name, m in method_configs().items() if isinstance(build_method(m).scorer(), ViewScorer)]
    return (*entries, *((name, "none") for name in scoring if name not in ablated))


ENTRIES = all_entries()
COLUMNS = (("patch_pearson", "patch r ↑"), ("view_pearson", "view r ↑"), ("ause", "AUSE ↓"), ("psnr", "PSNR ↑"))


def _directions(theta: Float[Tensor, " n"], phi: Float[Tensor, " n"]) -> Float[Tensor, "n 3"]:
    """``(sin phi cos theta, sin phi sin theta, cos phi)``, phi from +z (PROTOCOL 2.4)."""
    return torch.stack([phi.sin() * theta.cos(), phi.sin() * theta.sin(), phi.cos()], -1)


def partial_views(scene: Scene, generator: torch.Generator) -> Float[Tensor, "n 4 4"]:
    """PROTOCOL 4.4's one-sided training set: 20 random views of a scene ``conf/study/uncertainty.yaml`` declares
    (Hubble, Hotdog), Room's 10 initial views.

    Draw order (ours; the protocol gives only the distributions): theta [20], phi [20], look-at
    targets [20, 3], up vectors [20, 3], all float64 uniforms from ``generator``.
    """
    if scene.name == "room":
        return scene.init_poses.clone()  # the reference's pose file is unreleased (not confirmed)
    draws = study_defaults("uncertainty")["partial_views"]
    if scene.name not in draws:
        raise SceneError(
            f"PROTOCOL 4.4 defines the partial training set for {', '.join(draws)} and room only, not {scene.name!r} "
            f"(conf/study/uncertainty.yaml); pass scene={next(iter(draws))} or scene=room"
        )
    draw, n = draws[scene.name], PARTIAL_VIEWS
    units = {"1": 1.0, "s": S, "2s": 2 * S}

    def uniform(*shape: int) -> Tensor:
        return torch.rand(*shape, generator=generator, dtype=torch.float64)

    (theta_low, theta_width), (phi_low, phi_width) = draw["theta"], draw["phi"]
    theta = theta_low * math.pi + uniform(n) * (theta_width * math.pi)
    phi = phi_low * math.pi + uniform(n) * (phi_width * math.pi)
    where, looks = draw["position"], draw["target"]
    positions = units[where["unit"]] * (
        torch.tensor(where["offset"]) + torch.tensor(where["scale"]) * _directions(theta, phi)
    )
    targets = units[looks["unit"]] * (torch.tensor(looks["low"]) + uniform(n, 3) * torch.tensor(looks["width"]))
    ups = uniform(n, 3)
    return torch.stack([look_at(p, t, tuple(u.tolist())) for p, t, u in zip(positions, targets, ups, strict=True)])


def least_seen_view(eval_poses: Float[Tensor, "e 4 4"], train_poses: Float[Tensor, "t 4 4"]) -> int:
    """Index of the evaluation view whose viewing direction (the camera's -z axis, OpenGL) makes the
    largest angle with that of its nearest training view: the figure's view of the unseen side."""
    eval_forward, train_forward = -eval_poses[:, :3, 2].double(), -train_poses[:, :3, 2].double()
    return int((eval_forward @ train_forward.T).max(dim=1).values.argmin())


class ArgumentError(BadInput, ValueError):
    """A command-line argument the experiment cannot use (``--entries``, ``--seeds``, a ``seed=`` override)."""


def entry_name(method: str, ablation: str) -> str:
    """``nvf``, ``nvf-wo_vis``, ...: an entry as ``--entries`` and the file names spell it."""
    return method if ablation == "none" else f"{method}-{ablation}"


def select_entries(names: list[str] | None) -> tuple[tuple[str, str], ...]:
    """The entries of ``ENTRIES`` named in ``names``, in ``ENTRIES``' order (all of them for None)."""
    if names is None:
        return ENTRIES
    known = [entry_name(*entry) for entry in ENTRIES]
    unknown = [name for name in names if name not in known]
    if unknown or not names:
        raise ArgumentError(f"--entries: unknown {unknown or names}; choose from {','.join(known)}")
    return tuple(entry for entry in ENTRIES if entry_name(*entry) in names)


def summary(runs: list[dict]) -> dict:
    """One row from an entry's per-seed results: each number's mean and population std (``<key>_std``) over
    the seeds that have it (None and NaN are missing), and every seed's results under ``seeds``."""
    row: dict = {}
    for key, value in runs[0].items():
        if key != "seed" and (value is None or isinstance(value, int | float)) and not isinstance(value, bool):
            values = np.array([math.nan if run[key] is None else run[key] for run in runs], dtype=np.float64)
            row[key], row[f"{key}_std"], _ = mean_std_valid(values)
    return row | {"seeds": runs}


def score_seed(
    overrides: list[str], seed: int, entries: tuple[tuple[str, str], ...], partial: Scene, view: int, lpips: LpipsMetric
) -> tuple[list[dict], dict[str, np.ndarray]]:
    """Train and score every entry with ``seed``: per entry its metrics, the per-view sums behind the view r
    and the model it was scored on (``trained_as``); and the figure's arrays of evaluation view ``view``: ``gt``,
    the first entry's ``pred``, and every entry's ``score:<label>`` map."""
    results: list[dict] = []
    arrays: dict[str, np.ndarray] = {}
    trained: dict[tuple[str, str], tuple[Episode, Observations, SceneModel]] = {}  # per training key
    for method, ablation in entries:
        run = compose_run([*overrides, f"seed={seed}", f"method={method}", f"ablation={ablation}"])
        key = (method, ablation if run.train.ablation_affects_training else "none")
        if key not in trained:  # an ablation scored on NVF's model shares its episode (renders, evaluator)
            episode = Episode(EpisodeSettings.of(run, partial), partial, resolve_device(run.device), lpips)
            obs = episode.observations()
            trained[key] = (episode, obs, episode.train(obs, 0)[0])
        episode, obs, model = trained[key]
        metrics, images, view_sums = episode.evaluator.evaluate(
            model, run.method.scorer(), episode.face_ids, obs, 0, view
        )
        label = row_name(run.composed).label
        results.append({"seed": seed, "label": label, "trained_as": "/".join(key), **metrics} | view_sums)
        arrays.setdefault("gt", images["gt"])
        arrays.setdefault("pred", images["pred"])
        arrays[f"score:{label}"] = images["score"]
    return results, arrays


def save_seed(path: Path, results: list[dict], arrays: dict[str, np.ndarray], seconds: float) -> None:
    """One finished seed (``score_seed``'s output and its seconds) as an ``.npz``, written atomically."""
    buffer = io.BytesIO()
    results_json = np.array(json.dumps(to_jsonable({"results": results, "seconds": seconds})))
    # numpy types savez's **kwds as possibly its allow_pickle flag; the names here are gt, pred and score:<label>
    np.savez(buffer, results=results_json, **arrays)  # type: ignore[arg-type]
    atomic_write_bytes(path, buffer.getvalue())


def load_seed(path: Path) -> tuple[list[dict], dict[str, np.ndarray], float]:
    """``save_seed``'s file back as ``(results, arrays, seconds)``."""
    with np.load(path) as data:
        saved = json.loads(str(data["results"]))
        return saved["results"], {key: data[key] for key in data.files if key != "results"}, saved["seconds"]


def run(
    overrides: list[str],
    out: Path | None,
    entries: tuple[tuple[str, str], ...] = ENTRIES,
    seeds: tuple[int, ...] = SEEDS,
) -> list[Path]:
    """Train, score and write the experiment (``entries`` x ``seeds``) for the configured scene and budget;
    returns the files. Each finished seed is kept in ``.<name>.seeds/`` beside the files, so a killed run
    resumes at its first missing seed (delete the directory to start over); it is removed once the files are
    written."""
    if any(o.startswith("seed=") for o in overrides):
        raise ArgumentError("a seed= override: the experiment's seeds are --seeds (default 100,101,102)")
    overrides = overrides if any(o.startswith("scene=") for o in overrides) else ["scene=hotdog", *overrides]
    base = compose_run(overrides)
    scene = load_scene(base.scene, Path(base.paths.assets), blender_python(base.paths.blender_python))
    partial = dataclasses.replace(scene, init_poses=partial_views(scene, torch.Generator().manual_seed(PARTIAL_SEED)))
    view = least_seen_view(scene.eval_poses, partial.init_poses)
    label = config_label(base.composed)
    name = f"{base.scene.name}_{label}"
    if entries != ENTRIES:
        name += "+entries=" + ",".join(entry_name(*entry) for entry in entries)
    if seeds != SEEDS:
        name += "+seeds=" + ",".join(map(str, seeds))
    out = Path(base.paths.results) / "uncertainty" if out is None else out
    finished = out / f".{name}.seeds"
    lpips, per_seed = LpipsMetric(), {}
    for seed in tqdm(seeds, desc="seeds", disable=not sys.stderr.isatty()):
        path = finished / f"seed_{seed}.npz"
        if not path.exists():
            start = time.perf_counter()
            results, arrays = score_seed(overrides, seed, entries, partial, view, lpips)
            save_seed(path, results, arrays, time.perf_counter() - start)
        per_seed[seed] = load_seed(path)
    rows = [
        {
            "label": per_seed[seeds[0]][0][i]["label"],
            "method": method,
            "ablation": ablation,
            "trained_as": per_seed[seeds[0]][0][i]["trained_as"],
            **summary([per_seed[s][0][i] for s in seeds]),
        }
        for i, (method, ablation) in enumerate(entries)
    ]
    arrays = per_seed[seeds[0]][1]
    labels = [row["label"] for row in rows]
    shown = {"gt": arrays["gt"], "pred": arrays["pred"], "label": labels[0], "view": view}
    settings = [o for o in overrides if not o.startswith("paths.")]  # where files live is not a setting
    report = {
        "scene": base.scene.name,
        "scene_source": scene.source,
        "budget": label,
        "field": base.field.kind,
        "partial_views": len(partial.init_poses),
        "partial_seed": PARTIAL_SEED,
        "seeds": list(seeds),
        "torch_threads": torch.get_num_threads(),
        "figure_view": view,
        "figure_seed": seeds[0],
        "overrides": settings,
        "rows": rows,
        "seconds": sum(saved[2] for saved in per_seed.values()),
        "lpips_missing_reason": lpips.missing,
    }
    atomic_write_text(out / f"{name}.json", json.dumps(to_jsonable(report), indent=2) + "\n")
    atomic_write_text(out / f"{name}.md", markdown(report))
    save_figure(figure(shown, {label: arrays[f"score:{label}"] for label in labels}), out / f"{name}.png")
    shutil.rmtree(finished)
    return [out / f"{name}.{ext}" for ext in ("json", "md", "png")]


def markdown(report: dict) -> str:
    """The experiment's table: one row per entry, the correlations first."""
    lines = [
        f"# Uncertainty vs error: {report['scene']} ({report['scene_source']}), budget {report['budget']}",
        "",
        f"Models trained on {report['partial_views']} one-sided views (PROTOCOL 4.4, drawn with seed "
        f"{report['partial_seed']}), scored on the 20 evaluation views. Pearson r of the per-pixel score with the "
        "per-pixel error over 16 x 16 patches per view and over per-view sums; AUSE is our addition (lower is better). "
        f"One model per entry and seed (seeds {', '.join(map(str, report['seeds']))}; "
        f"torch threads: {report['torch_threads']}): mean ± population std over the seeds.",
        "",
        *markdown_table(
            ["Method", *(header for _, header in COLUMNS), "trained as"],
            [
                [
                    row["label"],
                    *(cell(row[key], row[f"{key}_std"], len(report["seeds"])) for key, _ in COLUMNS),
                    row["trained_as"],
                ]
                for row in report["rows"]
            ],
        ),
    ]
    return "\n".join(lines) + "\n"


def cell(mean: float | None, std: float, seeds: int) -> str:
    """``0.553 ± 0.021`` (the mean alone from one seed), ``-`` if no seed has the number."""
    if mean is None or not math.isfinite(mean):
        return "-"
    return f"{mean:.3f}" + (f" ± {std:.3f}" if seeds > 1 else "")


def figure(shown: dict, maps: dict[str, np.ndarray]) -> Figure:
    """GT, the first entry's prediction and per-pixel error, and every entry's score map of the shown
    evaluation view (``shown["view"]``; the first seed's models; each map scaled to its own range, magma)."""
    first = shown["label"]
    panels = [(f"GT (evaluation view {shown['view']})", shown["gt"]), (f"prediction ({first})", shown["pred"])]
    panels.append((f"error ({first})", colorize(np.abs(shown["pred"] - shown["gt"]).sum(-1), "magma")))
    panels += [(label, colorize(score, "magma")) for label, score in maps.items()]
    cols = 5
    rows = math.ceil(len(panels) / cols)
    fig = Figure(figsize=(2.6 * cols, 2.8 * rows), layout="constrained")
    axes = np.asarray(fig.subplots(rows, cols, squeeze=False)).ravel()
    for ax in axes:
        ax.set_axis_off()
    for ax, (title, image) in zip(axes, panels, strict=False):  # the grid's last row may have empty axes
        ax.imshow(np.clip(image, 0.0, 1.0))
        ax.set_title(title, fontsize=9)
    return fig


def main(argv: list[str]) -> int:
    parser = ArgumentParser(prog="python -m pipeline.experiments.uncertainty", description=description(__doc__))
    parser.add_argument("overrides", nargs="*", help="Hydra overrides, e.g. scene=hubble budget=smoke")
    parser.add_argument(
        "--out", type=Path, default=None, help="output directory (default ${paths.results}/uncertainty)"
    )
    parser.add_argument("--entries", default=None, help="comma-separated subset, e.g. nvf,nvf-wo_vis,wd (default all)")
    parser.add_argument(
        "--seeds", type=seed_list, default=SEEDS, help="comma-separated training seeds (default 100,101,102)"
    )
    args = parser.parse_intermixed_args(argv)
    names = None if args.entries is None else args.entries.split(",")
    try:
        written = run(args.overrides, args.out, select_entries(names), args.seeds)
    except (SceneError, ArgumentError) as err:
        fail(str(err))
    print("pipeline.experiments.uncertainty: wrote " + ", ".join(map(str, written)))
    return 0


if __name__ == "__main__":
    run_command(main, sys.argv[1:])
