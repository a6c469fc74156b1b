"""``python -m pipeline.experiments.discriminate [overrides] [--scenes S,..] [--seeds N,..] [--jobs J] [--label NAME]``:
does a budget tell the methods apart? The paired discrimination experiment of one budget.

For each scene and seed it runs (through ``python -m pipeline.run -m``, scene by scene, one Hydra sweep per entry,
``hydra/launcher=joblib`` with ``J`` parallel jobs of cores / J torch threads each, or ``OMP_NUM_THREADS``; finished
runs are skipped, so a killed experiment resumes; ``step_metrics=psnr``: the steps before the last record the PSNR
alone) full NVF (recording, at every step, how w/o Vis.'s score ranks the same candidates:
``diagnostics.rank_against=wo_vis``), its ablations w/o Vis. and Ind. Rays, and the baselines: every other method
whose yaml lists ``discriminate`` under ``experiments`` (WD, ActiveNeRF, NeurAR), on every scene whose yaml lists it
(default, hotdog, hubble). An entry the overrides cannot change (``pipeline.records.compat.inert_keys``:
``nvf.entropy.logdet_coeff=1.0`` on WD) is not run again where ``--reuse DIR`` (default the checkout's
``results/runs``, wherever the command runs from) holds its finished records of the plain budget. Then, per scene,
the paired (same seed) differences of final PSNR and of PSNR averaged over the steps: NVF - w/o Vis., NVF - Ind.
Rays and NVF - the best baseline (the baseline with the highest mean final PSNR on that scene), each with a 95%
Student-t interval over the seeds, the Spearman correlation of NVF's and w/o Vis.'s candidate scores, and minutes
per episode.

Writes ``${paths.results}/pilots/discriminate/<label>/`` (``<label>``: the budget and every setting beyond it, as
the tables label runs, unless ``--label``, a plain name: letters, digits, ``_``, ``.``, ``-``): ``runs/`` (the
records, images off), ``summary.csv`` (``scene, comparison, mean_diff, ci_low, ci_high, n, minutes_per_episode``;
final PSNR in dB), ``details.csv`` (both PSNR
measures, every seed's difference, which baseline), ``per_seed.csv`` (every run, with the share of its steps whose
score was flat), ``summary.md`` and ``command.txt``; for a setting beyond the budget, ``against_plain.csv``: each
entry the setting acts on minus the plain budget's experiment, same seeds (did the setting make NVF better, or its
ablation worse?). ``--summarize-only`` skips the runs (e.g. to summarise records made elsewhere with
``paths.outputs=DIR``).
"""

import math
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.atomic_write import atomic_write_text
from pipeline.cli import ArgumentParser, bounded, cores, description, fail, run_command
from pipeline.config.catalog import members, method_configs
from pipeline.config.settings_beyond_groups import config_label
from pipeline.config.validation import compose_run
from pipeline.experiments.decisions import check_scene
from pipeline.experiments.options import SEEDS, name_list, seed_list
from pipeline.records.checked_files import read_csv
from pipeline.records.experiment_columns import DISCRIMINATE_PER_SEED_COLUMNS, DISCRIMINATE_SUMMARY_COLUMNS, only
from pipeline.records.files import make_directory
from pipeline.records.store import RunRecord, check_key, record_status, run_dir
from pipeline.repo import REPO, RUNS
from pipeline.tables.escape import as_csv
from pipeline.tables.load import collect_runs, load_run
from pipeline.tables.stats import Interval
from pipeline.tables.table_formats import markdown_table

EXPERIMENT = "discriminate"  # what a method or scene lists under ``experiments`` to join this one
SCENES = tuple(members("scene", EXPERIMENT))  # every scene that declares it, by name
NVF, WO_VIS, IND_RAYS = ("nvf", "none"), ("nvf", "wo_vis"), ("nvf", "ind_rays")
# NVF's rivals: every other method that declares the experiment, in table order (``rank``)
BASELINES = tuple(
    (name, "none")
    for name, node in method_configs().items()
    if EXPERIMENT in node.get("experiments", []) and name != NVF[0]
)
ENTRIES = (NVF, WO_VIS, IND_RAYS, *BASELINES)
EXTRA = {NVF: "diagnostics.rank_against=wo_vis"}  # an entry's measurement beyond the run
COMPARISONS = (("nvf-wo_vis", WO_VIS), ("nvf-ind_rays", IND_RAYS), ("nvf-best_baseline", None))
SUMMARY_COLUMNS = tuple(DISCRIMINATE_SUMMARY_COLUMNS)  # summary.csv's, declared with their shapes in pipeline.records
TEXT = ("scene", "comparison", "measure", "against", "method", "ablation", "entry")  # csv columns of names (escaped)
# what against_plain reads of the plain budget's per_seed.csv (read back checked; flat_steps empty where undefined)
PER_SEED = only(
    DISCRIMINATE_PER_SEED_COLUMNS, "scene", "method", "ablation", "seed", "final_psnr", "mean_psnr", "flat_steps"
)


def entry_labels(overrides: list[str]) -> dict[tuple[str, str], str]:
    """Each entry's budget label under ``overrides`` (the plain budget's where they cannot act on it)."""
    return {
        entry: config_label(compose_run([f"method={entry[0]}", f"ablation={entry[1]}", *overrides]).composed)
        for entry in ENTRIES
    }


def reusable(reuse: Path | None, entry: tuple[str, str], label: str, plain: str, scene: str, seeds) -> bool:
    """Whether ``reuse`` holds a finished record of ``entry`` for every seed under the plain budget, and the
    overrides cannot change the entry (its label is the plain budget's)."""
    if reuse is None or label != plain:
        return False
    directories = [run_dir(reuse, scene, entry[0], "argmax", entry[1], plain, seed) for seed in seeds]
    return all(record_status(RunRecord(d).info(), d) == "done" for d in directories)


def sweep_commands(
    overrides: list[str], entries: list[tuple[str, tuple[str, str]]], seeds: tuple[int, ...], outputs: Path, jobs: int
) -> list[list[str]]:
    """One ``python -m pipeline.run -m`` per (scene, entry) in ``entries``, scene by scene, so that each
    scene's comparisons are complete before the next scene starts."""
    common = [
        f"seed={','.join(map(str, seeds))}",
        f"paths.outputs='{outputs}'",
        "save_images=false",  # quoted: '=' in labels
        "step_metrics=psnr",
        "hydra/launcher=joblib",
        f"hydra.launcher.n_jobs={jobs}",
        *overrides,
    ]
    commands = []
    for scene, (method, ablation) in entries:
        command = [
            sys.executable,
            "-m",
            "pipeline.run",
            "-m",
            f"scene={scene}",
            f"method={method}",
            f"ablation={ablation}",
            *common,
        ]
        extra = EXTRA.get((method, ablation))
        commands.append(command + ([extra] if extra else []))
    return commands


def mean_spearman(agreement: list[dict]) -> float:
    """The mean of the steps' ``rank_agreement`` Spearman correlations where defined (NaN if none is): a step
    whose rival score is constant over the candidates records None."""
    values = [a["spearman"] for a in agreement if a["spearman"] is not None and math.isfinite(a["spearman"])]
    return float(np.mean(values)) if values else math.nan


def flat_steps(steps: list[dict]) -> float:
    """The fraction of a run's steps whose score was constant over the candidates (every candidate tied at the
    maximum: a pick by draw order, as Random's); NaN for a run without scores or recorded ties."""
    scores = [s.get("candidate_scores") or {} for s in steps]
    if not scores or any(c.get("ties_at_max") is None for c in scores):
        return math.nan
    return float(np.mean([c["ties_at_max"] >= c["count"] for c in scores]))


def per_seed(
    roots: list[Path], labels: dict[tuple[str, str], str], planner: str, scenes: tuple[str, ...], seeds: tuple[int, ...]
) -> pd.DataFrame:
    """One row per finished run of the experiment under ``roots`` (each entry's budget label in ``labels``,
    ``planner``): scene, method, ablation, seed, final PSNR, PSNR averaged over the steps, minutes (the steps'
    train + eval + plan seconds), mean Spearman (``mean_spearman``) and same-choice fraction."""
    runs = collect_runs(roots)
    final = runs.final[(runs.final["status"] == "done") & (runs.final["planner"] == planner)]
    mine = np.array(
        [labels.get((m, a)) == b for m, a, b in zip(final["method"], final["ablation"], final["budget"], strict=True)],
        dtype=bool,
    )
    rows = []
    for _, run in final[final["scene"].isin(scenes) & final["seed"].isin(seeds) & mine].iterrows():
        steps = load_run(Path(run["directory"]))[1]
        agreement = [s["rank_agreement"] for s in steps if "rank_agreement" in s]
        rows.append(
            {
                "scene": run["scene"],
                "method": run["method"],
                "ablation": run["ablation"],
                "seed": int(run["seed"]),
                "final_psnr": run["psnr"],
                "mean_psnr": float(np.mean([s["metrics"]["psnr"] for s in steps])),
                "minutes": sum(sum(s["seconds"].values()) for s in steps) / 60.0,
                "spearman": mean_spearman(agreement),
                "same_choice": float(np.mean([a["same_choice"] for a in agreement])) if agreement else math.nan,
                "flat_steps": flat_steps(steps),
            }
        )
    return pd.DataFrame(rows, columns=list(DISCRIMINATE_PER_SEED_COLUMNS))


def compare(runs: pd.DataFrame) -> pd.DataFrame:
    """Per scene, comparison and PSNR measure: the paired differences, their interval and the minutes."""
    rows = []
    for scene, group in runs.groupby("scene", sort=False):
        entry = {key: g.set_index("seed") for key, g in group.groupby(["method", "ablation"])}
        if NVF not in entry:
            continue
        present = [b for b in BASELINES if b in entry]
        best = max(present, key=lambda b: entry[b]["final_psnr"].mean()) if present else None
        for name, listed in COMPARISONS:
            other = best if listed is None else listed
            if other is None or other not in entry:
                continue
            seeds = entry[NVF].index.intersection(entry[other].index)
            minutes = float(pd.concat([entry[NVF].loc[seeds, "minutes"], entry[other].loc[seeds, "minutes"]]).mean())
            for measure in ("final_psnr", "mean_psnr"):
                diffs = (entry[NVF].loc[seeds, measure] - entry[other].loc[seeds, measure]).to_numpy(float)
                interval = Interval.of(diffs)
                rows.append(
                    {
                        "scene": scene,
                        "comparison": name,
                        "measure": measure,
                        "against": "-".join(other),
                        "mean_diff": interval.mean,
                        "ci_low": interval.low,
                        "ci_high": interval.high,
                        "n": interval.n,
                        "minutes_per_episode": minutes,
                        "diffs": " ".join(f"{d:.3f}" for d in diffs),
                        "seeds": " ".join(map(str, seeds)),
                    }
                )
    return pd.DataFrame(rows)


def against_plain(runs: pd.DataFrame, plain: pd.DataFrame, entries: list[tuple[str, str]]) -> pd.DataFrame:
    """What the setting changes, entry by entry: per scene and entry of ``entries`` (those the setting acts
    on), its runs minus the plain budget's experiment's runs (``plain``, ``per_seed``'s columns), paired by
    seed, for both PSNR measures, with the share of steps where each run's score was flat."""
    rows = []
    for (scene, method, ablation), group in runs.groupby(["scene", "method", "ablation"], sort=False):
        if (method, ablation) not in entries:
            continue
        mine = group.set_index("seed")
        base = plain[(plain["scene"] == scene) & (plain["method"] == method) & (plain["ablation"] == ablation)]
        base = base.set_index("seed")
        seeds = mine.index.intersection(base.index)
        for measure in ("final_psnr", "mean_psnr"):
            interval = Interval.of((mine.loc[seeds, measure] - base.loc[seeds, measure]).to_numpy(float))
            rows.append(
                {
                    "scene": scene,
                    "entry": f"{method}-{ablation}",
                    "measure": measure,
                    "mean_diff": interval.mean,
                    "ci_low": interval.low,
                    "ci_high": interval.high,
                    "n": interval.n,
                    "flat_steps": float(mine.loc[seeds, "flat_steps"].mean()),
                    "plain_flat_steps": float(base.loc[seeds, "flat_steps"].mean()),
                }
            )
    return pd.DataFrame(rows)


def interval_cells(group: pd.DataFrame) -> dict[str, str]:
    """Per measure of ``group`` (rows with ``measure, mean_diff, ci_low, ci_high``), 'mean [low, high]' in dB."""
    return {
        row["measure"]: Interval(row["mean_diff"], row["ci_low"], row["ci_high"], int(row["n"])).text()
        for _, row in group.iterrows()
    }


def against_plain_markdown(plain_label: str, changes: pd.DataFrame) -> list[str]:
    """The lines of ``against_plain``'s table for summary.md."""
    lines = [
        "",
        f"What the setting changes, entry by entry: this experiment's runs minus `{plain_label}`'s (same seed), "
        "and the share of steps where the run's score was constant over the candidates (a pick by draw order):",
        "",
    ]
    rows = []
    for (scene, entry), group in changes.groupby(["scene", "entry"], sort=False):
        cells = interval_cells(group)
        first = group.iloc[0]
        flat = [f"{v:.2f}" if math.isfinite(v) else "-" for v in (first["flat_steps"], first["plain_flat_steps"])]
        rows.append([scene, entry, cells["final_psnr"], cells["mean_psnr"], first["n"], *flat])
    columns = ["scene", "entry", "final PSNR", "PSNR over steps", "n", "flat steps", "flat steps, plain"]
    lines += markdown_table(columns, rows, left=2)
    return lines


def markdown(label: str, details: pd.DataFrame, runs: pd.DataFrame) -> str:
    """The experiment's table: every comparison with both PSNR measures, then the rank agreement."""
    lines = [
        f"# Discrimination experiment: {label}",
        "",
        "Paired (same seed) differences in dB, mean [95% Student-t interval] over n seeds; a lead is "
        "established where the interval lies above zero. Best baseline: the one of WD, ActiveNeRF, NeurAR with "
        "the highest mean final PSNR on the scene.",
        "",
    ]
    rows = []
    for (scene, name), group in details.groupby(["scene", "comparison"], sort=False):
        cells = interval_cells(group)
        first = group.iloc[0]
        rows.append(
            [
                scene,
                name,
                first["against"],
                cells.get("final_psnr", "-"),
                cells.get("mean_psnr", "-"),
                first["n"],
                f"{first['minutes_per_episode']:.1f}",
            ]
        )
    columns = ["scene", "comparison", "against", "final PSNR", "PSNR over steps", "n", "min/episode"]
    lines += markdown_table(columns, rows, left=3)
    nvf = runs[(runs["method"] == NVF[0]) & (runs["ablation"] == NVF[1])]
    lines += [
        "",
        "NVF vs w/o Vis. on NVF's own candidates (mean over steps, then over seeds; '-': records made "
        "without `diagnostics.rank_against=wo_vis`):",
        "",
    ]
    rows = []
    for scene, group in nvf.groupby("scene", sort=False):
        spearman, same = group["spearman"].dropna(), group["same_choice"].dropna()
        shown = f"{spearman.mean():.3f}" if len(spearman) else "-", f"{same.mean():.2f}" if len(same) else "-"
        rows.append([scene, shown[0], shown[1], f"{len(spearman)} of {len(group)}"])
    lines += markdown_table(["scene", "Spearman", "same choice", "seeds"], rows)
    return "\n".join(lines) + "\n"


def summarize(
    roots: list[Path],
    out: Path,
    label: str,
    labels: dict[tuple[str, str], str],
    planner: str,
    scenes: tuple[str, ...],
    seeds: tuple[int, ...],
    plain: Path | None = None,
) -> list[Path]:
    """Write summary.csv, details.csv, per_seed.csv and summary.md for the runs under ``roots``; with ``plain``
    (the plain budget's experiment folder, for a setting beyond it) also against_plain.csv (``against_plain``)."""
    runs = per_seed(roots, labels, planner, scenes, seeds)
    if runs.empty:
        fail(
            f"no finished {label} runs of scenes {', '.join(scenes)} under {', '.join(map(str, roots))}; "
            "run without --summarize-only"
        )
    details = compare(runs)
    if details.empty:
        fail(
            f"no finished NVF {label} runs paired with another entry of scenes {', '.join(scenes)} under "
            f"{', '.join(map(str, roots))}; with --summarize-only, pass paths.outputs=DIR of the runs"
        )
    summary = details[details["measure"] == "final_psnr"].loc[:, list(SUMMARY_COLUMNS)]
    files = [out / "summary.csv", out / "details.csv", out / "per_seed.csv", out / "summary.md"]
    atomic_write_text(files[0], as_csv(summary, TEXT))
    atomic_write_text(files[1], as_csv(details, TEXT))
    atomic_write_text(files[2], as_csv(runs, TEXT))
    text = markdown(label, details, runs)
    base = read_csv(plain / "per_seed.csv", PER_SEED) if plain is not None else None
    if plain is not None and base is not None:
        changes = against_plain(runs, base, [e for e, entry_label in labels.items() if entry_label == labels[NVF]])
        files.append(out / "against_plain.csv")
        atomic_write_text(files[-1], as_csv(changes, TEXT))
        text += "\n".join(against_plain_markdown(plain.name, changes)) + "\n"
    atomic_write_text(files[3], text)
    return files


def main(argv: list[str]) -> int:
    parser = ArgumentParser(prog="python -m pipeline.experiments.discriminate", description=description(__doc__))
    parser.add_argument(
        "overrides", nargs="*", help="Hydra overrides of the budget, e.g. budget=cpu train.precision=bf16"
    )
    parser.add_argument(
        "--scenes", type=name_list, default=SCENES, help=f"comma-separated (default {','.join(SCENES)})"
    )
    parser.add_argument("--seeds", type=seed_list, default=SEEDS, help="comma-separated (default 100,101,102)")
    parser.add_argument("--jobs", type=int, default=2, help="parallel jobs, cores / J torch threads each (default 2)")
    parser.add_argument("--label", default=None, help="the experiment's folder name (default: its budget label)")
    parser.add_argument("--summarize-only", action="store_true", help="only summarise existing runs")
    parser.add_argument(
        "--reuse",
        type=Path,
        default=RUNS,
        help="finished plain-budget records of the entries the overrides cannot change (default "
        f"{RUNS}, wherever the command runs from; 'none' runs every entry)",
    )
    args = parser.parse_intermixed_args(argv)
    scenes, seeds = args.scenes, args.seeds
    if any(o.split("=")[0].lstrip("+~") in ("method", "ablation", "scene", "seed") for o in args.overrides):
        fail("method, ablation, scene and seed are the experiment's own: use --scenes and --seeds")
    bounded("--jobs", args.jobs, 1, cores(), "the cores this process may run on")
    cfg = compose_run(args.overrides)
    budget = config_label(cfg.composed)
    try:
        label = check_key("--label", args.label, "option") if args.label is not None else budget
    except ValueError as err:
        fail(str(err))
    labels = entry_labels(args.overrides)
    reuse = None if str(args.reuse) == "none" else args.reuse
    results = Path(cfg.paths.results)
    out = results / "pilots" / "discriminate" / label
    outputs = Path(cfg.paths.outputs) if args.summarize_only else out / "runs"
    roots = [outputs] + ([reuse] if reuse is not None and reuse.resolve() != outputs.resolve() else [])
    if not args.summarize_only:
        for scene in scenes:  # a missing scene or asset is one line now, not 18 failed jobs later
            check_scene(scene, list(args.overrides))
        make_directory(results, out)
        plain = cfg.budget.name
        entries = [
            (scene, entry)
            for scene in scenes
            for entry in ENTRIES
            if not reusable(reuse, entry, labels[entry], plain, scene, seeds)
        ]
        commands = sweep_commands(args.overrides, entries, seeds, outputs.resolve(), args.jobs)
        atomic_write_text(out / "command.txt", "".join(shlex.join(["python", *c[1:]]) + "\n" for c in commands))
        for command in commands:
            subprocess.run(command, cwd=REPO, check=False)  # a failed job is recorded; the summary counts seeds
    plain_dir = out.parent / cfg.budget.name if labels[NVF] != cfg.budget.name else None
    files = summarize(roots, out, label, labels, cfg.planner.name, scenes, seeds, plain_dir)
    print("pipeline.experiments.discriminate: wrote " + ", ".join(map(str, files)))
    return 0


if __name__ == "__main__":
    run_command(main, sys.argv[1:])
