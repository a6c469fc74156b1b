"""``python -m pipeline.experiments.visibility_study --setting NAME [overrides] [--scenes S,..] [--seeds N,..]
[--steps K,..] [--sets N] [--records DIR]``: does NVF's visibility field change a decision, and does the
change help? Paired one-step measurements on the states of recorded NVF episodes.

For each scene, seed and sampled step ``k`` of the committed NVF record (``<records>/<scene>/nvf-argmax-none/
<budget>/seed_<seed>``, of the run's budget or of ``--state-budget``), the state is the record's observations
before step ``k`` (the initial views and the poses selected at steps ``0..k-1``). At that state, under the
setting's overrides (say ``nvf.entropy.logdet_coeff=1.0``):

1. a model is trained as the episode's step ``k`` trains it (same seed, the method's stages);
2. ``--sets`` candidate sets are drawn (set 0 is the planner's own draw at step ``k``, the others come from
   their own seeded generators) and scored with NVF and with w/o Vis. (the same settings, ``v = 1``):
   their Spearman correlation, whether their argmax agree, how many candidates tie at each maximum, and each
   reward split into its terms (``pipeline.metrics.ranking.term_attribution``: the decisive term);
3. where the two picks differ, the backbone is trained once with each pick added (the seed of step ``k+1``,
   the same for both) and each model's held-out PSNR is taken on the scene's 20 evaluation views: the
   one-step gain of NVF's pick over w/o Vis.'s, paired.

The candidate sets, the one-step outcome and the rows' file are the duel's (``pipeline.experiments.decisions``;
``python -m pipeline.experiments.duel method=nvf rival=wo_vis`` is the same comparison on states from both
records, without the terms).

It also runs the visibility diagnostic (``pipeline.diagnostics.visibility_report``, what ``python -m pipeline.bench
visibility`` reports) on each scene's initial views (3 sets of 64 candidates, the sources ``head`` and ``labels``,
plus ``nvf.entropy.visibility_source`` when that is ``mesh``).

Writes ``${paths.results}/pilots/visibility_study/<setting>/``: ``decisions.jsonl`` (a row per scene, seed,
step and set; a killed study resumes after its last complete row, and a larger ``--sets`` measures the new sets
alone), ``<scene>_diagnostic.json``, ``command.txt`` (every command that wrote into the folder, one per line),
``setting.json`` (the setting's overrides and ``--threads``: a folder takes no other overrides, so give them
another ``--setting``, nor another thread count, on which the numbers depend; a setting without it was made with
one thread); then ``summary.csv`` and ``surface.csv`` of the whole study
(``pipeline.experiments.visibility_summary``). Torch runs with ``--threads`` threads (default 1: two studies side
by side on 2 cores). Before any work, every seed must be one a run can
have, every step one the records hold, and the folder's files must read back
(``pipeline.experiments.visibility_summary.DECISION``; never through a symbolic link).
"""

import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from nvf.cameras import Intrinsics, pose_to_matrix
from nvf.device import resolve_device
from nvf.methods import NVF
from nvf.observations import Observations
from nvf.planning import argmax_first, score_poses
from nvf.uncertainty.nvf_entropy import NVFEntropyScorer
from pipeline.atomic_write import atomic_write_text
from pipeline.cli import ArgumentParser, bounded, cores, description, fail, run_command
from pipeline.config.catalog import declared, study_defaults
from pipeline.config.typed_run import Run
from pipeline.config.validation import compose_run
from pipeline.diagnostics.visibility_report import visibility_report
from pipeline.episode.loop import Episode
from pipeline.episode.settings import EpisodeSettings
from pipeline.experiments.decisions import (
    candidate_set,
    check_scene,
    contender,
    heldout_psnr,
    recorded_steps,
    with_view,
)
from pipeline.experiments.options import (
    SEEDS,
    add_command,
    name_list,
    other_threads,
    seed_list,
    setting_overrides,
    step_list,
)
from pipeline.experiments.provenance import checkout, made_with
from pipeline.experiments.row_files import JsonLines
from pipeline.experiments.visibility_summary import DECISION, DIAGNOSTIC, SETTING, STUDY, write_summary, write_surface
from pipeline.metrics.image import LpipsMetric
from pipeline.metrics.ranking import render_for_terms, spearman, term_attribution, ties_at_max, view_terms
from pipeline.records.checked_files import read_json
from pipeline.records.files import check_directory, make_directory
from pipeline.records.store import check_key, check_seed
from pipeline.repo import RUNS
from pipeline.scenes.blender import blender_python
from pipeline.scenes.loading import load_scene
from pipeline.scenes.scene import SceneError

DEFAULTS = study_defaults("visibility_study")  # conf/study/visibility_study.yaml
SCENES, STEPS = tuple(DEFAULTS["scenes"]), tuple(DEFAULTS["steps"])
MAX_SETS = 64


def scorer_pair(episode: Episode) -> tuple[NVFEntropyScorer, NVFEntropyScorer]:
    """NVF's scorer with the run's settings and the same with ``use_visibility=False`` (w/o Vis.)."""
    method = episode.settings.method
    assert isinstance(method, NVF), "the study's method is NVF"
    blind_entropy = dataclasses.replace(method.entropy, use_visibility=False)
    nvf, blind = method.scorer(), dataclasses.replace(method, entropy=blind_entropy).scorer()
    assert isinstance(nvf, NVFEntropyScorer) and isinstance(blind, NVFEntropyScorer), "the study's method is NVF"
    return nvf, blind


def terms_of(planning, scorers: dict[str, NVFEntropyScorer], candidates: torch.Tensor, intr: Intrinsics) -> dict:
    """Per scorer, per candidate, the mean of each reward term over the planning image ([m] per term); one
    render per candidate serves every scorer."""
    views: dict[str, list[dict[str, float]]] = {name: [] for name in scorers}
    for c2w in pose_to_matrix(candidates):
        result = render_for_terms(planning, c2w, intr, next(iter(scorers.values())).sampler)[0]
        for name, scorer in scorers.items():
            views[name].append(view_terms(scorer, result))
    return {name: {term: np.array([v[term] for v in rows]) for term in rows[0]} for name, rows in views.items()}


def decision(episode: Episode, planning, candidates: torch.Tensor, scorers, obs: Observations, k: int) -> dict:
    """One candidate set at one state: both scores, their agreement, terms and (if they disagree) the
    one-step held-out PSNR of each pick."""
    s = episode.settings
    nvf, blind = scorers
    start = time.perf_counter()
    scores = {
        name: score_poses(planning, scorer, candidates, episode.plan_intrinsics, s.planner.score_chunk_rays)
        for name, scorer in (("nvf", nvf), ("wo_vis", blind))
    }
    plan_seconds = time.perf_counter() - start
    own, rival = (scores[name].cpu().numpy() for name in ("nvf", "wo_vis"))
    picks = {name: argmax_first(values) for name, values in scores.items()}
    row: dict[str, object] = {
        "candidates": int(candidates.shape[0]),
        "spearman": spearman(own, rival),
        "same_argmax": picks["nvf"] == picks["wo_vis"],
        "picks": picks,
        "ties_at_max": {"nvf": ties_at_max(own), "wo_vis": ties_at_max(rival)},
        "terms": {
            name: term_attribution(terms)
            for name, terms in terms_of(
                planning, {"nvf": nvf, "wo_vis": blind}, candidates, episode.plan_intrinsics
            ).items()
        },
        "plan_seconds": plan_seconds,
    }
    if not row["same_argmax"]:
        outcomes = {
            name: heldout_psnr(episode, with_view(obs, episode, candidates[i]), k + 1) for name, i in picks.items()
        }
        picked_psnr = {name: value for name, (value, _) in outcomes.items()}
        row["psnr"] = picked_psnr
        row["gain"] = picked_psnr["nvf"] - picked_psnr["wo_vis"]
        row["outcome_train_seconds"] = sum(seconds for _, seconds in outcomes.values())
    return row


def missing_sets(decisions: JsonLines, scene: str, seed: int, step: int, sets: int) -> list[int]:
    """The candidate sets of a state ``decisions`` lacks (all of a state not measured yet, the new ones of a larger
    ``--sets``)."""
    have = {r["set"] for r in decisions.rows if (r["scene"], r["seed"], r["step"]) == (scene, seed, step)}
    return [index for index in range(sets) if index not in have]


def study_scene(
    run: Run,
    overrides: list[str],
    seeds: list[int],
    steps: list[int],
    sets: int,
    records: Path,
    decisions: JsonLines,
    state_budget: str,
    git: dict,
) -> None:
    """Every missing (seed, step) state of one scene (``run``: the scene's config with the setting's
    ``overrides``; ``state_budget``: the budget of the records the states come from; ``git``: the checkout the
    command started from, ``provenance.checkout``), each row saying what it was made with and from which record."""
    scene_name = run.scene.name
    scene = load_scene(run.scene, Path(run.paths.assets), blender_python(run.paths.blender_python))
    lpips = LpipsMetric()
    for seed in seeds:
        todo = [k for k in steps if missing_sets(decisions, scene_name, seed, k, sets)]
        if not todo:
            continue
        recorded = recorded_steps(
            records, scene_name, contender("nvf"), seed, state_budget, max(steps), scene, overrides
        )
        rows = recorded.rows
        made = made_with(git, scene_name, run.budget.name, overrides, torch.get_num_threads())
        seeded = compose_run([f"scene={scene_name}", f"seed={seed}", *overrides])
        episode = Episode(EpisodeSettings.of(seeded, scene), scene, resolve_device(seeded.device), lpips)
        try:
            for k in todo:
                episode.replay(rows[len(episode.poses) - len(scene.init_poses) : k])
                obs = episode.observations()
                start = time.perf_counter()
                model, _ = episode.train(obs, k)
                train_seconds = time.perf_counter() - start
                planning = episode.planning_model(model, obs)
                scorers = scorer_pair(episode)
                found = []
                for index in missing_sets(decisions, scene_name, seed, k, sets):
                    candidates = candidate_set(episode, planning, k, index, purpose="study_candidates")
                    row = decision(episode, planning, candidates, scorers, obs, k)
                    found.append(
                        {
                            "scene": scene_name,
                            "seed": seed,
                            "step": k,
                            "set": index,
                            "train_seconds": train_seconds,
                            **row,
                            "made_with": made,
                            "source_record": recorded.source,
                        }
                    )
                decisions.add(found)
                print(
                    f"{scene_name} seed {seed} step {k}: "
                    + ", ".join("same" if r["same_argmax"] else f"differ, gain {r['gain']:+.2f} dB" for r in found),
                    flush=True,
                )
        finally:
            episode.close()


def settings_of(overrides: list[str]) -> list[str]:
    """A study's overrides as settings, sorted, without ``paths.*`` (where files are, not what is computed)."""
    return sorted(setting_overrides(overrides))


def main(argv: list[str] | None = None) -> None:
    parser = ArgumentParser(prog="python -m pipeline.experiments.visibility_study", description=description(__doc__))
    parser.add_argument(
        "overrides", nargs="*", help="the setting's config overrides, e.g. nvf.entropy.logdet_coeff=1.0"
    )
    parser.add_argument(
        "--setting", required=True, help="the setting's name: its folder under pilots/visibility_study/"
    )
    parser.add_argument("--scenes", type=name_list, default=SCENES)
    parser.add_argument("--seeds", type=seed_list, default=SEEDS)
    parser.add_argument("--steps", type=step_list, default=STEPS, help="the recorded steps whose states are studied")
    parser.add_argument("--sets", type=int, default=3, help="candidate sets per state (0: the planner's own)")
    parser.add_argument("--records", type=Path, default=RUNS, help=f"where the NVF records are (default {RUNS})")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (1 to the machine's cores)")
    parser.add_argument(
        "--state-budget", default=None, help="the budget of the records the states come from (default: the run's)"
    )
    args = parser.parse_intermixed_args(sys.argv[1:] if argv is None else argv)
    try:
        check_key("--setting", args.setting, "option")
        seeds = [check_seed(seed) for seed in args.seeds]
    except ValueError as err:
        parser.error(str(err))
    steps = list(args.steps)
    bounded("--sets", args.sets, 1, MAX_SETS)
    bounded("--threads", args.threads, 1, cores(), "the cores this process may run on")
    torch.set_num_threads(args.threads)
    git = checkout()
    cfg = compose_run(args.overrides)
    state_budget = cfg.budget.name if args.state_budget is None else args.state_budget
    if state_budget not in declared("budget"):
        fail(f"--state-budget {state_budget!r}: not one of conf/budget ({', '.join(declared('budget'))})")
    scenes = list(args.scenes)
    for scene in scenes:  # a bad scene, seed or step is one line now, not after the diagnostics' minutes
        check_scene(scene, list(args.overrides))
        for seed in seeds:
            recorded_steps(
                args.records, scene, contender("nvf"), seed, state_budget, max(steps), overrides=list(args.overrides)
            )
    results = Path(cfg.paths.results)
    out = results / "pilots" / STUDY / args.setting
    check_directory(results, out)
    made = read_json(out / "setting.json", SETTING)
    if made is not None and settings_of(made.get("overrides", [])) != settings_of(args.overrides):
        fail(
            f"--setting {args.setting}: {out} holds a study made with the overrides {made.get('overrides', [])}, not "
            f"{args.overrides}; give these overrides their own --setting"
        )
    other = other_threads(out, args.threads, {made.get("threads", 1)} if made is not None else set())
    if other is not None:
        fail(other)
    make_directory(results, out)
    decisions = JsonLines(out / "decisions.jsonl", DECISION)
    measured = {scene: read_json(out / f"{scene}_diagnostic.json", DIAGNOSTIC) is not None for scene in scenes}
    add_command(
        out, ["python", "-m", "pipeline.experiments.visibility_study", *(sys.argv[1:] if argv is None else argv)]
    )
    entropy, train = cfg.nvf.entropy, cfg.train
    setting = {
        "name": args.setting,
        "overrides": args.overrides,
        "visibility_source": entropy.visibility_source,
        "logdet_coeff": entropy.logdet_coeff,
        "label_margin": train.label_margin,
        "budget": cfg.budget.name,
        "threads": args.threads,
    } | ({"state_budget": state_budget} if state_budget != cfg.budget.name else {})
    if made is None:
        atomic_write_text(out / "setting.json", json.dumps(setting, indent=2) + "\n")
    for scene in scenes:
        scene_cfg = compose_run([f"scene={scene}", *args.overrides])
        if not measured[scene]:
            sources = ["head", "labels"] + (["mesh"] if scene_cfg.nvf.entropy.visibility_source == "mesh" else [])
            report = visibility_report(
                compose_run([f"scene={scene}", "planner.num_candidates=64", *args.overrides]), 3, sources
            )
            atomic_write_text(out / f"{scene}_diagnostic.json", json.dumps(report, indent=2) + "\n")
        try:
            study_scene(scene_cfg, args.overrides, seeds, steps, args.sets, args.records, decisions, state_budget, git)
        except SceneError as err:
            fail(str(err))
    write_summary(Path(cfg.paths.results) / "pilots" / STUDY)
    write_surface(Path(cfg.paths.results) / "pilots" / STUDY, args.records)


if __name__ == "__main__":
    run_command(main, sys.argv[1:])
