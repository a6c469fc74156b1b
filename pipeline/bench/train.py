"""``python -m pipeline.bench train [--out PATH] [--repeats N] [--precisions fp32,bf16] [--windows W] [overrides]``:
end-to-end training and inference throughput of the scene model at a budget (default ``budget=cpu
scene=default``), for each training precision side by side.

On the scene's 20 evaluation views as training views, one model per ``train.precision`` in ``--precisions``
(the first is the reference) from the same initial weights and seed, trained in lockstep
(``pipeline.bench._paired``): stage 1's kept samples per second, inference's, the matmul limit and the field
and MLP floors (``pipeline.bench._field_floor``), and held-out PSNR, per precision with paired ratios against the
reference. Rates from wall time and (``*_cpu``) from process CPU time / threads. The models run on the run's
device (``device``, CUDA where present). Writes ``results/bench/train.json`` (or ``--out``) and prints a
table; results/bench/README.md ("train.json") defines every field of the report.
"""

import dataclasses
import statistics
import time
from pathlib import Path

import torch
from jaxtyping import Float
from torch import Tensor

from nvf.cameras import Intrinsics
from nvf.config import Precision
from nvf.device import resolve_device, synchronize
from nvf.encoding import cpp_extension
from nvf.field import HEADS
from nvf.observations import Observations
from nvf.precision import precision_dtype
from nvf.training import train_backbone
from pipeline.bench._field_floor import field_floor
from pipeline.bench._models import (
    HELD_OUT_VIEWS,
    RGB,
    CountingModel,
    held_out_poses,
    parse_precisions,
    report_settings,
    same_initial_models,
    train_in_lockstep,
    view_psnr,
)
from pipeline.bench._paired import IterationClock, ratio_spread
from pipeline.bench._report import report_path, write_report
from pipeline.bench.field_throughput import matmul_gflops, mlp_flops
from pipeline.cli import ArgumentParser, bounded, description
from pipeline.config.typed_run import Run
from pipeline.config.validation import compose_run
from pipeline.diagnostics.initial_view_model import load, observations
from pipeline.episode.evaluation import RENDER_CHUNK
from pipeline.episode.settings import EpisodeSettings
from pipeline.scenes.ground_truth import Renderer, ground_truth_info, open_renderer
from pipeline.scenes.scene import Scene

GOALS = {"train_samples_per_s": 1e6, "infer_samples_per_s": 3e6}
MAX_REPEATS = 100
MAX_WINDOWS = 100  # iteration windows (fewer where there are fewer iterations)
# A low precision against the reference (fp32), paired in one run: training throughput (median over
# windows), held-out PSNR (at most this far below), inference (median over rounds) never slower.
PRECISION_GOALS = {"train_samples_per_s": 1.5, "heldout_psnr_drop_db": 0.2, "infer_samples_per_s": 1.0}


def inference_rates(
    model: CountingModel,
    precisions: list[str],
    poses: Float[Tensor, "n 4 4"],
    intr: Intrinsics,
    heads: frozenset[str],
    repeats: int,
) -> dict[str, dict[str, float | list[float]]]:
    """Kept samples/s of ``render_image`` over ``poses`` with the model's MLPs in each precision, side by
    side: one warm-up pass each, then ``repeats`` rounds, each timing every precision once (order rotated
    per round). Per precision: median wall and CPU rates, kept samples per pass and the per-round wall
    and CPU rates (for paired ratios)."""

    def render_all(name: str) -> tuple[float, float, int]:
        before, start, start_cpu = model.samples, time.perf_counter(), time.process_time()
        with model.field.mlp_precision(torch.float32, infer=precision_dtype(name)):
            for c2w in poses:
                model.render_image(c2w, intr, heads=heads, chunk=RENDER_CHUNK)
        synchronize()
        cpu = (time.process_time() - start_cpu) / torch.get_num_threads()
        return time.perf_counter() - start, cpu, model.samples - before

    for name in precisions:
        render_all(name)
    rounds: dict[str, list[tuple[float, float, int]]] = {name: [] for name in precisions}
    for r in range(repeats):
        for name in precisions[r % len(precisions) :] + precisions[: r % len(precisions)]:
            rounds[name].append(render_all(name))
    out: dict[str, dict[str, float | list[float]]] = {}
    for name, timed in rounds.items():
        wall = [n / w for w, _, n in timed]
        cpu = [n / c for _, c, n in timed]
        out[name] = {
            "wall": wall,
            "cpu": cpu,
            "samples_per_pass": timed[0][2],
            "samples_per_s": statistics.median(wall),
            "samples_per_s_cpu": statistics.median(cpu),
        }
    return out


def precision_goals_met(ratio: dict) -> dict[str, bool]:
    """``PRECISION_GOALS`` against one ``ratios`` entry of the report."""
    return {
        "train_samples_per_s": ratio["train_samples_per_s"]["median"] >= PRECISION_GOALS["train_samples_per_s"],
        "heldout_psnr_drop_db": ratio["heldout_psnr_diff"] >= -PRECISION_GOALS["heldout_psnr_drop_db"],
        "infer_samples_per_s": ratio["infer_samples_per_s"]["median"] >= PRECISION_GOALS["infer_samples_per_s"],
    }


def print_report(report: dict, update_every: int) -> None:
    """The report as a few lines of text: rates against their limits, floors, and the precisions side by side."""
    r = report
    rows, width = r["settings"]["matmul_rows"], r["settings"]["hidden_dim"]
    print(f"{'':14}{'samples/s':>12}{'(cpu)':>12}{'at limit':>12}{'frac. limit':>13}{'goal':>9}")
    for key, label in (("train", "train step"), ("infer", "infer all"), ("infer_rgb", "infer rgb")):
        goal = GOALS.get(f"{key}_samples_per_s")
        mark = "" if goal is None else ("met" if r[f"{key}_samples_per_s"] >= goal else f"<{goal:.0e}")
        print(
            f"{label:14}{r[f'{key}_samples_per_s']:>12.3e}{r[f'{key}_samples_per_s_cpu']:>12.3e}"
            f"{r[f'{key}_samples_per_s_at_limit']:>12.3e}{r[f'{key}_fraction_of_limit']:>13.3f}"
            f"{mark:>9}"
        )
    print(
        f"matmul [{rows}x{width}]x[{width}x{width}]: {r['matmul_gflops']:.1f} GFLOP/s; "
        f"PSNR held-out {r['heldout_psnr']:.2f} dB ({r['heldout_psnr_off_edges']:.2f} off edges), "
        f"training views {r['train_view_psnr']:.2f} dB; "
        f"{r['settings']['train_samples_per_ray']:.1f} samples/ray (train); {r['seconds']:.0f} s"
    )
    print(
        f"field floor {r['train_samples_per_s_field_floor']:.3e} kept samples/s: forward+backward "
        f"{r['field_floor_fwd_bwd_ms']:.1f} ms ({r['field_floor_kept_samples']} kept), skipping pass "
        f"{r['field_floor_skip_density_ms']:.1f} ms ({r['field_floor_marched_samples']} marched; training's mean "
        f"{r['train_samples_per_iter']:.0f} kept, {r['train_marched_per_iter']:.0f} marched), grid update "
        f"{r['field_floor_grid_update_ms']:.0f} ms / {update_every}; training runs at "
        f"{r['train_fraction_of_field_floor']:.2f} of it"
    )
    print(
        f"MLP floor {r['train_samples_per_s_mlp_floor']:.3e} kept samples/s (the MLPs' layers alone on the same rows: "
        f"forward+backward {r['mlp_floor_fwd_bwd_ms']:.1f} ms, skipping pass {r['mlp_floor_skip_density_ms']:.1f} ms, "
        f"grid update {r['mlp_floor_grid_update_ms']:.0f} ms / {update_every})"
    )
    print(
        f"{'precision':10}{'train/s':>11}{'(cpu)':>11}{'ms/iter':>9}{'infer/s':>11}{'rgb/s':>11}{'held-out':>10}"
        f"{'field floor':>13}{'MLP floor':>11}"
    )
    for name, p in r["precisions"].items():
        print(
            f"{name:10}{p['train_samples_per_s']:>11.3e}{p['train_samples_per_s_cpu']:>11.3e}"
            f"{p['train_ms_per_iter']:>9.1f}{p['infer_samples_per_s']:>11.3e}{p['infer_rgb_samples_per_s']:>11.3e}"
            f"{p['heldout_psnr']:>10.2f}{p['train_samples_per_s_field_floor']:>13.3e}"
            f"{p['train_samples_per_s_mlp_floor']:>11.3e}"
        )

    def spread(x: dict) -> str:
        return f"{x['median']:.2f} [{x['min']:.2f}-{x['max']:.2f}]"

    for key, ratio in r["ratios"].items():
        met = r["precision_goals_met"][key]
        print(
            f"{key} (median [min-max], paired): train {spread(ratio['train_samples_per_s'])} "
            f"(cpu {spread(ratio['train_samples_per_s_cpu'])}; per iteration {spread(ratio['train_iter_speedup'])}), "
            f"infer {spread(ratio['infer_samples_per_s'])}, infer rgb {spread(ratio['infer_rgb_samples_per_s'])}, "
            f"floors (same model): field {ratio['train_samples_per_s_field_floor']:.2f}, "
            f"MLP {ratio['train_samples_per_s_mlp_floor']:.2f}; held-out PSNR {ratio['heldout_psnr_diff']:+.2f} dB; "
            "goals " + ", ".join(f"{goal} {'met' if ok else 'not met'}" for goal, ok in met.items())
        )


def precision_ratios(
    per: dict[str, dict],
    clocks: dict[str, IterationClock],
    rounds: dict[str, dict[str, dict]],
    base: str,
    name: str,
    windows: list[tuple[int, int]],
) -> dict:
    """``name`` against ``base``: training samples/s and the per-iteration speed-up paired by iteration
    window (the trainings ran in lockstep), inference paired by round, the floors' ratios (same model and
    batch), and the held-out PSNR difference (dB)."""
    win = {p: [clocks[p].rates(first, last) for first, last in windows] for p in (base, name)}
    ratio = {
        key: ratio_spread([w[key] for w in win[name]], [w[key] for w in win[base]])
        for key in ("train_samples_per_s", "train_samples_per_s_cpu")
    }
    ratio["train_iter_speedup"] = ratio_spread(
        [w["train_ms_per_iter"] for w in win[base]], [w["train_ms_per_iter"] for w in win[name]]
    )
    for key, timed in rounds.items():
        ratio[f"{key}_samples_per_s"] = ratio_spread(timed[name]["wall"], timed[base]["wall"])
        ratio[f"{key}_samples_per_s_cpu"] = ratio_spread(timed[name]["cpu"], timed[base]["cpu"])
    for floor in ("field", "mlp"):
        key = f"train_samples_per_s_{floor}_floor"
        ratio[key] = per[name][key] / per[base][key]
    ratio["heldout_psnr_diff"] = per[name]["heldout_psnr"] - per[base]["heldout_psnr"]
    return ratio


def train_side_by_side(
    cfg: Run, s: EpisodeSettings, scene: Scene, obs: Observations, precisions: list[str]
) -> tuple[dict[str, CountingModel], dict[str, IterationClock]]:
    """Stage 1 of one model per ``train.precision``, from the same initial weights and seed, in lockstep."""
    models = same_initial_models(cfg, scene, s, precisions, CountingModel)

    def train(name: str, model: CountingModel, progress: IterationClock) -> None:
        generator = torch.Generator(obs.images.device).manual_seed(int(cfg.seed))
        train_backbone(
            model, obs, dataclasses.replace(s.train, precision=Precision(name)), generator, progress=progress
        )

    return models, train_in_lockstep(models, s.train.backbone.iters, train)


def parse_args(argv: list[str]):
    parser = ArgumentParser(prog="python -m pipeline.bench train", description=description(__doc__))
    parser.add_argument("overrides", nargs="*", help="Hydra overrides, e.g. budget=smoke")
    parser.add_argument(
        "--out", type=Path, default=None, help="JSON report path (default: ${paths.results}/bench/train.json)"
    )
    parser.add_argument("--repeats", type=int, default=3, help="timed inference passes (median)")
    parser.add_argument(
        "--precisions",
        help="train.precision values compared, first the reference (default: fp32,bf16 "
        "where the CPU has bfloat16, else fp32)",
    )
    parser.add_argument("--windows", type=int, default=5, help="iteration windows of the paired training ratios")
    args = parser.parse_intermixed_args(argv)
    bounded("--repeats", args.repeats, 1, MAX_REPEATS)
    bounded("--windows", args.windows, 1, MAX_WINDOWS)
    return args


def training_results(
    models: dict[str, CountingModel],
    clocks: dict[str, IterationClock],
    warmup: int,
    renderer: Renderer,
    scene: Scene,
    obs: Observations,
    intr: Intrinsics,
    gt_samples: int,
) -> dict[str, dict]:
    """Each precision's training rates and its model's held-out and training-view PSNR, rendered as an
    episode renders them (MLPs in float32)."""
    per: dict[str, dict] = {name: clocks[name].rates(warmup) for name in models}
    held_out = held_out_poses(scene)
    for name, model in models.items():
        r = per[name]
        r["heldout_psnr"], r["heldout_psnr_off_edges"] = view_psnr(model, renderer, held_out, intr, gt_samples)
        r["train_view_psnr"], r["train_view_psnr_off_edges"] = view_psnr(
            model, renderer, obs.c2w[:HELD_OUT_VIEWS], intr, gt_samples
        )
    return per


def same_work_rates(
    per: dict[str, dict],
    reference: CountingModel,
    precisions: list[str],
    obs: Observations,
    intr: Intrinsics,
    s: EpisodeSettings,
    seed: int,
    repeats: int,
) -> dict[str, dict]:
    """The same work in each precision, on the reference precision's model: inference (all heads, RGB
    alone; added to ``per``) and the training floors. Returns the inference rounds."""
    rounds = {}
    for heads, key in ((HEADS, "infer"), (RGB, "infer_rgb")):
        rounds[key] = inference_rates(reference, precisions, obs.c2w, intr, heads, repeats)
        for name, rates in rounds[key].items():
            per[name][f"{key}_samples_per_s"] = rates["samples_per_s"]
            per[name][f"{key}_samples_per_s_cpu"] = rates["samples_per_s_cpu"]
    base = precisions[0]
    per_iter = (per[base]["train_samples_per_iter"], per[base]["train_marched_per_iter"])
    grid = {key: value.clone() for key, value in reference.grid.state_dict().items()}
    for name in precisions:
        reference.grid.load_state_dict(grid)  # field_floor updates the grid once: each precision starts alike
        generator = torch.Generator(obs.images.device).manual_seed(seed)
        with reference.field.mlp_precision(precision_dtype(name)):
            floors = field_floor(
                reference, obs, s.train.backbone.batch, per_iter, s.sampler.update_every, generator, repeats
            )
        per[name].update(floors)
    return rounds


def limits(r: dict, model: CountingModel, width: int, repeats: int) -> int:
    """The reference precision's rates against the matmul limit of its MLPs (added to ``r``); returns the
    matmul's rows (kept samples per iteration)."""
    r["train_fraction_of_field_floor"] = r["train_samples_per_s"] / r["train_samples_per_s_field_floor"]
    rows = max(1, round(r["train_samples_per_iter"]))
    r["matmul_gflops"], r["matmul_gflops_cpu"] = matmul_gflops(rows, width, repeats)
    flops = {
        "train": mlp_flops(model.field, RGB, train=True),
        "infer": mlp_flops(model.field, HEADS, train=False),
        "infer_rgb": mlp_flops(model.field, RGB, train=False),
    }
    for key, value in flops.items():
        r[f"mlp_flops_{key}"] = value
        r[f"{key}_samples_per_s_at_limit"] = r["matmul_gflops"] * 1e9 / value
        r[f"{key}_fraction_of_limit"] = r[f"{key}_samples_per_s"] / r[f"{key}_samples_per_s_at_limit"]
        r[f"{key}_fraction_of_limit_cpu"] = value * r[f"{key}_samples_per_s_cpu"] / (r["matmul_gflops_cpu"] * 1e9)
    return rows


def goals(r: dict, ratios: dict) -> dict:
    """The report's goals and whether the measured rates meet them."""
    return {
        "precision_goals": PRECISION_GOALS,
        "precision_goals_met": {key: precision_goals_met(ratio) for key, ratio in ratios.items()},
        "goals": GOALS,
        "goals_met": {key: r[key] >= goal for key, goal in GOALS.items()},
        "goals_within_limit": {key: r[f"{key}_at_limit"] >= goal for key, goal in GOALS.items()},
        "train_goal_within_field_floor": r["train_samples_per_s_field_floor"] >= GOALS["train_samples_per_s"],
        "train_goal_within_mlp_floor": r["train_samples_per_s_mlp_floor"] >= GOALS["train_samples_per_s"],
    }


def main(argv: list[str]) -> None:
    args = parse_args(argv)
    start = time.perf_counter()
    cfg = compose_run(args.overrides)
    device = resolve_device(str(cfg.device))
    args.out = report_path(args.out, cfg.paths.results, "train")  # checked before any work
    precisions = parse_precisions(args.precisions, device)
    scene = load(cfg)
    s = EpisodeSettings.of(cfg, scene)
    size = int(cfg.budget.image_size)
    intr = Intrinsics.from_fov(size, size)
    renderer = open_renderer(scene, s.render, s.blender_python)  # render.backend: pyrender's or Blender's ground truth
    gt_samples = int(cfg.budget.gt_samples)
    obs = observations(renderer, scene.eval_poses, intr, gt_samples, device)

    models, clocks = train_side_by_side(cfg, s, scene, obs, precisions)
    warmup = max(1, min(10, s.train.backbone.iters // 10))
    per = training_results(models, clocks, warmup, renderer, scene, obs, intr, gt_samples)
    renderer.close()  # its ground truth is rendered (for Blender, this ends the worker process)
    base = precisions[0]
    rounds = same_work_rates(per, models[base], precisions, obs, intr, s, int(cfg.seed), args.repeats)
    windows = clocks[base].windows(warmup, args.windows)
    ratios = {
        f"{name}_over_{base}": precision_ratios(per, clocks, rounds, base, name, windows) for name in precisions[1:]
    }
    r = dict(per[base])
    rows = limits(r, models[base], s.field.hidden_dim, args.repeats)
    report = {
        **r,
        "precision": base,
        "precisions": per,
        "ratios": ratios,
        **goals(r, ratios),
        "settings": {
            **report_settings(cfg, s, obs.num_images, size, precisions, args.overrides),
            "field_backend_resolved": "cpp" if s.field.backend != "torch" and cpp_extension() is not None else "torch",
            "hidden_dim": s.field.hidden_dim,
            "iterations": s.train.backbone.iters,
            "warmup_iterations": warmup,
            "rays_per_batch": s.train.backbone.batch,
            "train_samples_per_ray": r["train_samples_per_iter"] / s.train.backbone.batch,
            "infer_samples_per_ray": rounds["infer"][base]["samples_per_pass"] / (obs.num_images * intr.num_pixels),
            "infer_chunk": RENDER_CHUNK,
            "matmul_rows": rows,
            "ratio_windows": args.windows,
            "inference_repeats": args.repeats,
            "heldout_views": HELD_OUT_VIEWS,
            "gt_samples_per_side": gt_samples,
            "ground_truth": ground_truth_info(scene, renderer, Path(cfg.paths.assets)),
        },
        "seconds": time.perf_counter() - start,
    }
    write_report(report, args.out)
    print_report(report, s.sampler.update_every)
    print(f"wrote {args.out}")
