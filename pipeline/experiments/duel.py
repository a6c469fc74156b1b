"""``python -m pipeline.experiments.duel method=A rival=B [overrides] [--scenes S,..] [--seeds N,..] [--steps K,..]
[--sets N] [--records DIR] [--threads T]``: a duel between two methods. Given the same map, whose next view
is better? Paired one-step decisions on the states of both methods' recorded episodes.

A contender is a method (``conf/method``) or an NVF ablation (``conf/ablation``: ``rival=wo_vis`` is NVF with
w/o Vis.), planned by argmax (the -OPT planner is not dueled). ``rival=`` takes a comma list
(``rival=fisherrf,activenerf,wd,random``): one process then shares the method's states, models and outcomes
between the rivals. The other ``key=value`` arguments are config overrides of both contenders (``budget=cpu``,
the default).

States: for scene ``s``, seed ``n`` and the ``i``-th listed step ``k``, the observations before step ``k`` (the
initial views and the poses selected at steps ``0..k-1``) of A's record if ``(i + n)`` is even, else of B's, so
each step comes from both trajectories over the seeds. Records: ``<records>/<scene>/<method>-argmax-<ablation>/
<budget>/seed_<n>`` (``--records``, default the repository's ``results/runs`` wherever the command runs from),
verified, of the run's budget or of ``--state-budget`` (``budget=paper --state-budget cpu``:
the committed cpu episodes' states, trained and scored at the paper's counts; the setting says so).

At a state each contender's model is trained as its own episode's step ``k`` trains it (contenders whose
training is identical share one). ``--sets`` candidate sets are drawn (set 0: the state's own planner draw at
step ``k``; the others from their own seeded generators) and each contender picks from the same set as its
episode would. Where the picks differ, the plain backbone is trained with each pick added (the seed of step
``k+1``, the same for both) and evaluated on the scene's 20 evaluation views: the gain is A's pick's held-out
PSNR minus B's, paired on the state (``pipeline.experiments.decisions``).

Writes ``${paths.results}/pilots/duel/<A>_vs_<B>/``: ``decisions.jsonl`` (a row per scene, seed, step and set,
a repeated one refused on write and on read; each state's rows in one write, and a state lacking a set's row,
as a kill can leave it, is decided again for that set), ``outcomes.jsonl`` (every evaluated pick, reused by
later calls of the same setting and threads), ``setting.json`` (the overrides, states' budget and ``--threads``: a
call with others under the same folder is refused in one line, as is one with another thread count than the
folder's rows where its setting predates the count) and ``command.txt`` (every command that added rows), both
written under the pair's lock once everything is checked; then ``summary.csv``, ``details.csv`` and ``summary.md``
of every duel under ``pilots/duel/`` (``pipeline.experiments.duel_summary``). Torch runs with ``--threads``
threads (1 to the cores this process may run on; default 1; a record's numbers depend on it). To use more
cores run several processes on disjoint ``--scenes`` or ``--seeds``, one thread each: they append to the same
folders side by side; a pair, scene and seed has one writer (the records' lock: a second process on it is refused
in one line). Every record a state needs is read before anything is written, none through a symbolic link leaving
``--records`` (nor a pair folder through a link); a contender against itself is refused.
"""

import argparse
import contextlib
import dataclasses
import itertools
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch

from nvf.device import resolve_device
from nvf.observations import Observations
from pipeline.cli import ArgumentParser, bounded, cores, fail, help_page, run_command
from pipeline.config.catalog import conf_dirs, declared, searchpath_of, study_defaults
from pipeline.config.validation import compose_run
from pipeline.episode.loop import Episode
from pipeline.episode.settings import EpisodeSettings
from pipeline.episode.shared_training import Trained, train_models
from pipeline.experiments.decisions import (
    Contender,
    Outcomes,
    Pick,
    Recorded,
    candidate_set,
    check_scene,
    contender,
    heldout_psnr,
    outcome_key,
    pick,
    prepared_scorer,
    recorded_steps,
    with_view,
)
from pipeline.experiments.duel_pairs import Pair, pairs_of, setting_problem
from pipeline.experiments.duel_summary import DUEL, pair_folders, write_summaries
from pipeline.experiments.options import (
    SEEDS,
    name_list,
    seed_list,
    setting_overrides,
    step_list,
)
from pipeline.experiments.provenance import checkout, made_with
from pipeline.metrics.image import LpipsMetric
from pipeline.metrics.ranking import spearman
from pipeline.records.files import check_directory
from pipeline.records.lock import RunLock
from pipeline.records.store import check_seed
from pipeline.repo import RUNS
from pipeline.scenes.blender import blender_python
from pipeline.scenes.loading import load_scene
from pipeline.scenes.scene import Scene, SceneError

SCENES = tuple(study_defaults("duel")["scenes"])  # conf/study/duel.yaml
MAX_SETS = 64
STEP_EVERY = 3  # --steps' default: every third step of the states' horizon (0, 3, .., 18 of the cpu budget's 20)
OWN_KEYS = ("method", "rival", "ablation", "scene", "seed")  # the duel's own: not config overrides


@dataclass
class Call:
    """What one command measures: its pairs (one method against each rival), overrides and choices."""

    pairs: list[Pair]
    overrides: list[str]
    seeds: list[int]
    steps: list[int]
    sets: int
    records: Path
    threads: int
    outcomes: Outcomes
    budget: str  # of the records the states come from
    git: dict  # the checkout's commit and dirty flag when the command started (``provenance.checkout``)
    command: list[str] = field(default_factory=list)  # added to each pair's command.txt before its first rows


def open_episode(call: Call, scene: Scene, who: Contender, seed: int, lpips: LpipsMetric) -> Episode:
    cfg = compose_run([f"scene={scene.name}", f"seed={seed}", *who.overrides, *call.overrides])
    return Episode(EpisodeSettings.of(cfg, scene), scene, resolve_device(cfg.device), lpips)


@dataclass
class State:
    """What one state holds for its pairs: its owner (whose record it comes from), where it is, the owner's
    episode and observations, each contender's model (``Trained``: one object where shared) and scorer
    preparation seconds, the candidate sets and each contender's pick from each (by name and set)."""

    owner: str
    scene: str
    seed: int
    step: int
    episode: Episode
    obs: Observations
    trained: dict[str, Trained]
    prepare: dict[str, float]
    candidates: list[torch.Tensor]
    picks: dict[tuple[str, int], Pick]
    made_with: dict  # what the state's rows are made with (``provenance.made_with``)
    recorded: int | None  # the owner's record's pick at this step
    source: dict  # the owner's record (``provenance.source_record``)

    def outcome(self, call: Call, pair: Pair, pose: torch.Tensor) -> tuple[float, float]:
        """Held-out PSNR and seconds of the pick at ``pose`` (``heldout_psnr``), computed once per pose."""
        key = outcome_key(self.scene, self.seed, self.owner, self.step, pose.tolist())
        known = call.outcomes.get(key)
        if known is None:
            known = heldout_psnr(self.episode, with_view(self.obs, self.episode, pose), self.step + 1)
            call.outcomes.add(pair.folder, key, *known)
        return known


def decision_rows(call: Call, pair: Pair, state: State) -> list[dict]:
    """The rows of one pair at one state, a row per candidate set."""
    a, b = pair.method.name, pair.rival.name
    rows = []
    missing = pair.missing(state.scene, state.seed, state.step, len(state.candidates))
    for index, candidates in enumerate(state.candidates):
        if index not in missing:
            continue
        picks = {name: state.picks[(name, index)] for name in (a, b)}
        same = picks[a].index == picks[b].index
        x, y = picks[a].scores, picks[b].scores
        row: dict[str, object] = {
            "scene": state.scene,
            "seed": state.seed,
            "step": state.step,
            "set": index,
            "source": state.owner,
            "method": a,
            "rival": b,
            "candidates": int(candidates.shape[0]),
            "method_pick": picks[a].index,
            "rival_pick": picks[b].index,
            "method_pose": candidates[picks[a].index].tolist(),
            "rival_pose": candidates[picks[b].index].tolist(),
            "same_pick": same,
            "spearman": spearman(x, y) if x is not None and y is not None else None,
            "source_pick_recorded": state.picks[(state.owner, 0)].index == state.recorded if index == 0 else None,
            "shared_training": state.trained[a] is state.trained[b],
            "threads": call.threads,
            "made_with": state.made_with,
            "source_record": state.source,
        }
        seconds = {
            name: {"train": state.trained[name].seconds, "prepare": state.prepare[name], "score": picks[name].seconds}
            for name in (a, b)
        }
        if not same:
            (ours, seconds[a]["outcome"]), (theirs, seconds[b]["outcome"]) = (
                state.outcome(call, pair, candidates[picks[name].index]) for name in (a, b)
            )
            row |= {"method_psnr": ours, "rival_psnr": theirs, "gain": ours - theirs}
        row["seconds"] = {"method": seconds[a], "rival": seconds[b]}
        rows.append(row)
    return rows


def measure_state(
    call: Call, episodes: dict[str, Episode], owner: str, recorded: Recorded, k: int, pairs: list[Pair]
) -> None:
    """Train, draw and pick at the state of ``owner``'s record before step ``k``, then write each pair's rows."""
    rows = recorded.rows
    needed = {owner} | {name for pair in pairs for name in (pair.method.name, pair.rival.name)}
    active = {name: episodes[name] for name in episodes if name in needed}
    for episode in active.values():
        episode.replay(rows[len(episode.poses) - len(episode.scene.init_poses) : k])
    source = active[owner]
    obs = source.observations()
    trained = train_models(active, obs, k)
    planning = {name: e.planning_model(trained[name].model, obs) for name, e in active.items()}
    prepare, scorers = {}, {}
    for name, episode in active.items():
        start = time.perf_counter()
        scorers[name] = prepared_scorer(episode, planning[name], obs, k)
        prepare[name] = time.perf_counter() - start
    candidates = [candidate_set(source, planning[owner], k, index) for index in range(call.sets)]
    picks = {
        (name, index): pick(episode, planning[name], scorers[name], candidates[index], k, index)
        for name, episode in active.items()
        for index in range(call.sets)
    }
    seed, scene = source.settings.seed, source.scene.name
    budget = source.settings.budget.name
    made = made_with(call.git, scene, budget, call.overrides, call.threads)
    state = State(
        owner,
        scene,
        seed,
        k,
        source,
        obs,
        trained,
        prepare,
        candidates,
        picks,
        made,
        rows[k].get("selected_index"),
        recorded.source,
    )
    lines = []
    for pair in pairs:
        found = decision_rows(call, pair, state)
        pair.record(found)
        verdicts = ("same" if r["same_pick"] else f"{r['gain']:+.2f} dB" for r in found)
        lines.append(f"{pair.rival.name}: {', '.join(verdicts)}")
    print(f"{scene} seed {seed} step {k} ({owner}'s state): " + "; ".join(lines), flush=True)


def duel_scene(call: Call, scene_name: str) -> None:
    """Every missing state of one scene."""
    cfg = compose_run([f"scene={scene_name}", *call.pairs[0].method.overrides, *call.overrides])
    try:
        scene = load_scene(cfg.scene, Path(cfg.paths.assets), blender_python(cfg.paths.blender_python))
    except SceneError as err:
        fail(str(err))
    lpips = LpipsMetric()
    for seed in call.seeds:
        with contextlib.ExitStack() as held:  # one writer per pair, scene and seed; what is done read under it
            for pair in call.pairs:
                held.enter_context(RunLock(pair.folder / scene_name / f"seed_{seed}", pair.folder))
                pair.read()
            duel_seed(call, scene, seed, lpips)


def duel_seed(call: Call, scene: Scene, seed: int, lpips: LpipsMetric) -> None:
    """Every state of one scene and seed that some pair has not decided for every candidate set."""
    todo: dict[str, dict[int, list[Pair]]] = {}  # owner -> step -> pairs missing that state
    owners: dict[str, Contender] = {}
    for (i, k), pair in itertools.product(enumerate(call.steps), call.pairs):
        if pair.missing(scene.name, seed, k, call.sets):
            who = pair.owner(i, seed)
            owners[who.name] = who
            todo.setdefault(who.name, {}).setdefault(k, []).append(pair)
    for pair in call.pairs:  # a pair with a state to decide: its setting and command, before its first rows
        if any(p is pair for states in todo.values() for pairs in states.values() for p in pairs):
            pair.open(call.command)
    for name, states in todo.items():
        recorded = recorded_steps(
            call.records, scene.name, owners[name], seed, call.budget, max(call.steps), scene, call.overrides
        )
        contenders = {c.name: c for pairs in states.values() for p in pairs for c in (p.method, p.rival)}
        episodes: dict[str, Episode] = {}
        try:
            for who in contenders.values():
                episodes[who.name] = open_episode(call, scene, who, seed, lpips)
            for k in sorted(states):
                measure_state(call, episodes, name, recorded, k, states[k])
        finally:
            for episode in episodes.values():
                episode.close()


def split_arguments(positional: list[str]) -> tuple[Contender, list[Contender], list[str]]:
    """The method, the rivals and the config overrides of the positional arguments (one line for bad ones)."""
    named = {o.split("=", 1)[0]: o.split("=", 1)[1] for o in positional if o.split("=", 1)[0] in ("method", "rival")}
    overrides = [o for o in positional if o.split("=", 1)[0] not in ("method", "rival")]
    if "method" not in named or "rival" not in named:
        fail("name both contenders: method=A rival=B (a method of conf/method or an ablation of conf/ablation)")
    own = [o for o in overrides if o.split("=", 1)[0].lstrip("+~") in OWN_KEYS]
    if own:
        fail(f"{own[0]}: the contenders and states are the duel's own; use method=, rival=, --scenes and --seeds")
    dirs = conf_dirs(searchpath_of(overrides))  # a user's own methods, as pipeline.run finds them
    try:
        rivals = list(dict.fromkeys(contender(name, dirs) for name in named["rival"].split(",")))
        method = contender(named["method"], dirs)
    except ValueError as err:
        fail(str(err))
    if method in rivals:
        fail(f"rival={method.name}: a contender against itself decides nothing; name another rival")
    return method, rivals, overrides


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    parser = ArgumentParser(
        prog="python -m pipeline.experiments.duel",
        description=help_page(__doc__),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("overrides", nargs="*", help="method=A rival=B[,C..] and config overrides, e.g. budget=cpu")
    parser.add_argument(
        "--scenes", type=name_list, default=SCENES, help=f"comma-separated (default {','.join(SCENES)})"
    )
    parser.add_argument("--seeds", type=seed_list, default=SEEDS, help="comma-separated (default 100,101,102)")
    parser.add_argument(
        "--steps",
        type=step_list,
        default=None,
        help="the recorded steps whose states are used (default every third step the states' records hold: 0,3,..,18 "
        "at the cpu budget, 0 at smoke)",
    )
    parser.add_argument(
        "--sets",
        type=int,
        default=2,
        help=f"candidate sets per state, 1..{MAX_SETS} (default 2; set 0 is the planner's own draw)",
    )
    parser.add_argument("--records", type=Path, default=RUNS, help=f"where the records are (default {RUNS})")
    parser.add_argument(
        "--state-budget", default=None, help="the budget of the records the states come from (default: the run's)"
    )
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    args = parser.parse_intermixed_args(argv)
    method, rivals, overrides = split_arguments(args.overrides)
    try:
        seeds = [check_seed(seed) for seed in args.seeds]
    except ValueError as err:
        fail(f"--seeds: {err}")
    scenes = list(args.scenes)
    bounded("--sets", args.sets, 1, MAX_SETS)
    bounded("--threads", args.threads, 1, cores(), "the cores this process may run on")
    cfg = compose_run([*method.overrides, *overrides])
    if cfg.planner.name != "argmax" or cfg.train.warm_start:
        fail("the duel replays argmax episodes trained from scratch: drop planner= and train.warm_start=")
    for scene in scenes:  # a missing scene or asset is one line now, before anything is written
        check_scene(scene, overrides)
    torch.set_num_threads(args.threads)
    root = Path(cfg.paths.results) / "pilots" / DUEL
    kept = setting_overrides(overrides)
    state_budget = cfg.budget.name if args.state_budget is None else args.state_budget
    if state_budget not in declared("budget"):
        fail(f"--state-budget {state_budget!r}: not one of conf/budget ({', '.join(declared('budget'))})")
    steps = list(args.steps or range(0, compose_run([f"budget={state_budget}"]).budget.horizon, STEP_EVERY))
    setting = {"method": method.name, "overrides": kept, "budget": cfg.budget.name, "threads": args.threads}
    if state_budget != cfg.budget.name:
        setting["state_budget"] = state_budget  # the states' records are of another budget
    planned = Call(
        [], overrides, seeds, steps, args.sets, args.records, args.threads, Outcomes([]), state_budget, checkout()
    )
    for scene, seed, rival in itertools.product(scenes, seeds, rivals):  # every record a state needs, before writing
        for i, _ in enumerate(steps):
            recorded_steps(
                planned.records,
                scene,
                Pair.owner_of(method, rival, i, seed),
                seed,
                planned.budget,
                max(planned.steps),
                overrides=overrides,
            )
    check_directory(Path(cfg.paths.results), root)  # never read through a link leaving paths.results
    pairs = pairs_of(root, method, rivals, setting)
    same_setting = [  # their outcomes are this call's: the same overrides, states and threads
        folder
        for folder in pair_folders(root)
        if os.path.lexists(folder / "setting.json") and setting_problem(folder, setting) is None
    ]
    command = ["python", "-m", "pipeline.experiments.duel", *argv]
    call = dataclasses.replace(planned, pairs=pairs, outcomes=Outcomes(same_setting), command=command)
    for scene in scenes:
        duel_scene(call, scene)
    for path in write_summaries(root, args.records):
        print(f"wrote {path}")


if __name__ == "__main__":
    run_command(main, sys.argv[1:])
