"""``python -m pipeline.experiments.paper_states [overrides] [--scenes S,..] [--seeds N,..] [--steps K,..]
[--budgets paper,cpu] [--state-budget cpu] [--records DIR] [--contenders C,..] [--outcomes R,..|all]
[--vis-points P] [--threads T]``: do the benchmark's verdicts hold at the paper's scale? One-step decisions at
states trained at the paper's counts, beside the same states at the cpu budget.

A state (scene, seed, step ``k``) is the observations before step ``k`` of a recorded episode of
``--state-budget`` (default cpu: the committed episodes; the initial views and the poses selected at steps
``0..k-1``): NVF's record where ``(i + seed)`` is even (``i``: the step's place in ``--steps``), else w/o Vis.'s,
as the duel alternates. For each budget of ``--budgets`` the state is rebuilt at that budget: its views
rendered at the budget's image size by its ground truth (``budget=paper``: 512 px by Blender Cycles;
``render.backend=pyrender`` among the overrides to change it, and the rows say which), then

1. each contender's model trained as its episode's step ``k`` trains it (``--contenders``: NVF and any method or
   ablation the duel takes; ``pipeline.episode.shared_training.train_models``, one model where their trainings
   agree);
2. the budget's own candidate draw of step ``k`` (NVF's planner: 512 candidates at 300 px at the paper's budget),
   scored by every contender, one render per chunk serving the scorers of one model (``score_poses_together``):
   each contender's pick, its pose and its scores' spread (``ScoreSummary``, and the standard deviation over the
   mean's magnitude: is the score flat?), and against NVF the Spearman correlation and whether the argmax agree;
3. the visibility field against the scene mesh: at ``--vis-points`` points on the mesh surface (0.01 outside it
   along the face normal) whether some camera of the state sees them (the mesh's exact line of sight, the truth),
   the labels ``V*`` of M17-M18 (bin centres, the budget's label samples) and NVF's head ``v``: the AUC of each;
4. for every rival of ``--outcomes`` (default ``all``: every contender but NVF) whose pick differs from NVF's, the
   one-step outcome of both picks: the plain backbone trained with the pick at the budget's counts (seed of step
   ``k+1``) and its held-out PSNR on the 20 evaluation views (``decisions.heldout_psnr``).

A state the folder already holds is extended, not measured again, when the call names contenders or outcomes its
row lacks: the candidate draw reads only NVF's backbone (M28's density filter; the later stages leave the backbone
as stage 1 left it, ``shared_training.serves``), so it is rebuilt from stage 1 alone (it cannot be rebuilt without a
trained model); the contenders that train only that backbone are scored again (a pick the row holds must come out
the same, else one ``error:`` line: the state was not rebuilt), the others keep the row's picks (``reused``), and
the outcomes the row lacks are trained. The new row names the one it extends (``extends``, ``row_files``); the
file keeps both.

Every row says what it was made with (``made_with``: commit, dirty flag, threads, ground truth, the resolved values
its overrides change in its budget, the sizes: ``pipeline.experiments.provenance``) and where its state came from
(``source_record``: the record's digest and settings; a record planned otherwise than its budget's file is
refused).

Writes ``${paths.results}/pilots/paper_states/``: ``states.jsonl`` (a row per scene, seed, step and budget,
written once the state is complete: a killed run resumes at its first missing state, after the models and the
one-step outcomes that state had finished, kept under ``${paths.outputs}/paper_states/`` by what the state is, its
owner and its views, until its row is written, ``StateProgress``), ``setting.json`` (the overrides, the states'
budget, ``--vis-points`` and ``--threads``: another set under the same folder is refused, as is another thread
count, on which the numbers depend), ``command.txt``, then ``summary.csv`` and ``summary.md``
(``pipeline.experiments.paper_states_summary``). Nothing is written before every scene, record and renderer the
call needs is found. Torch runs with ``--threads`` threads (default 1); run several processes on disjoint scenes or
seeds to use more cores.
"""

import argparse
import dataclasses
import hashlib
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import torch

from nvf.device import resolve_device
from nvf.observations import Observations
from nvf.planning import ScoreSummary, argmax_first, score_poses_together
from nvf.visibility import visibility_labels
from pipeline.cli import ArgumentParser, bounded, cores, fail, help_page, run_command
from pipeline.config.catalog import conf_dirs, declared, option_problem, searchpath_of, study_defaults
from pipeline.config.validation import compose_run
from pipeline.episode.loop import Episode
from pipeline.episode.settings import EpisodeSettings
from pipeline.episode.shared_training import Trained, train_models, training_plan
from pipeline.experiments.decisions import (
    Contender,
    candidate_set,
    contender,
    heldout_psnr,
    prepared_scorer,
    recorded_steps,
    with_view,
)
from pipeline.experiments.options import (
    SEEDS,
    name_list,
    seed_list,
    setting_overrides,
    step_list,
)
from pipeline.experiments.paper_state_progress import StateProgress
from pipeline.experiments.paper_states_folder import open_folder, setting_digest
from pipeline.experiments.paper_states_summary import (
    STATE,
    state_key,
    write_summary,
)
from pipeline.experiments.provenance import checkout, made_with
from pipeline.experiments.row_files import JsonLines, row_digest
from pipeline.metrics.image import LpipsMetric
from pipeline.metrics.ranking import auc, spearman
from pipeline.records.lock import RunLock
from pipeline.records.store import check_seed
from pipeline.repo import RUNS
from pipeline.scenes.blender import blender_python, missing_python
from pipeline.scenes.loading import load_scene
from pipeline.scenes.scene import Scene, SceneError

DEFAULTS = study_defaults("paper_states")  # conf/study/paper_states.yaml: scenes, steps, contenders, label points
SCENES = tuple(DEFAULTS["scenes"])
STEPS = tuple(DEFAULTS["steps"])
BUDGETS = ("paper", "cpu")
CONTENDERS = tuple(DEFAULTS["contenders"])  # NVF first: the others are compared with it
OWNERS = ("nvf", "wo_vis")  # whose records the states come from, alternately
ALL = "all"  # --outcomes: every rival
VIS_POINTS = int(DEFAULTS["vis_points"])
SURFACE_OFFSET = 0.01  # scene units outside the surface, along the face normal
OWN_KEYS = ("method", "rival", "ablation", "scene", "seed", "budget")  # the command's own: not config overrides
DRAW = "(backbone)"  # the model the candidate draw reads when NVF's own is not trained: NVF's stage 1 alone


def state_owner(i: int, seed: int) -> Contender:
    """Whose record the ``i``-th listed step's state comes from for ``seed``: NVF's and w/o Vis.'s alternately."""
    return contender(OWNERS[(i + seed) % 2])


def settings_of(scene: Scene, who: Contender, seed: int, budget: str, overrides: list[str]) -> EpisodeSettings:
    cfg = compose_run([f"scene={scene.name}", f"seed={seed}", f"budget={budget}", *who.overrides, *overrides])
    return EpisodeSettings.of(cfg, scene)


def score_spread(scores: np.ndarray) -> dict:
    """``ScoreSummary`` of the scores plus ``relative_std``: their standard deviation over the magnitude of their
    mean (0 for a flat score)."""
    summary = dataclasses.asdict(ScoreSummary.of(torch.from_numpy(scores)))
    mean = abs(float(scores.mean()))
    summary["relative_std"] = float(scores.std()) / mean if mean > 0 else None
    return summary


def picks_of(
    episodes: dict[str, Episode], trained: dict[str, Trained], obs: Observations, k: int, candidates: torch.Tensor
) -> tuple[dict[str, np.ndarray], dict[str, float], dict[str, float]]:
    """Every contender's scores of ``candidates``, the seconds its scorer's preparation took and its scoring's
    (one ``score_poses_together`` per model: the scorers of a shared model read one render)."""
    scorers, prepare = {}, {}
    for name, episode in episodes.items():
        start = time.perf_counter()
        scorers[name] = prepared_scorer(episode, trained[name].model, obs, k)
        prepare[name] = time.perf_counter() - start
    scores: dict[str, np.ndarray] = {}
    seconds: dict[str, float] = {}
    models: dict[int, list[str]] = {}
    for name in episodes:
        models.setdefault(id(trained[name].model), []).append(name)
    for names in models.values():
        episode = episodes[names[0]]
        chosen = [scorers[name] for name in names]
        assert all(scorer is not None for scorer in chosen), "a contender without a scorer is refused by main"
        start = time.perf_counter()
        found = score_poses_together(
            trained[names[0]].model,
            [scorer for scorer in chosen if scorer is not None],
            candidates,
            episode.plan_intrinsics,
            episode.settings.planner.score_chunk_rays,
        )
        took = time.perf_counter() - start
        for name, values in zip(names, found, strict=True):
            scores[name], seconds[name] = values.cpu().numpy(), took
    return scores, prepare, seconds


def visibility_agreement(episode: Episode, trained: Trained, obs: Observations, points: int, seed: int) -> dict:
    """Labels (M17-M18, bin centres) and NVF's head against the mesh's line of sight at points on the surface."""
    mesh = episode.scene.mesh
    where, faces = mesh.sample(points, return_index=True, seed=seed)
    x = torch.tensor(where + SURFACE_OFFSET * mesh.face_normals[faces], dtype=torch.float32)
    truth = episode.renderer.line_of_sight(x, obs.c2w, obs.intrinsics).numpy()
    model, s = trained.model, episode.settings
    device_x = x.to(episode.device)
    support, density = model.density_support(), model.label_density(s.train.label_lattice)
    with torch.no_grad():
        labels = visibility_labels(
            density, device_x, obs.c2w, obs.intrinsics, s.train, aabb=support.box, grid=support.grid
        )
        head = model.field(device_x, torch.zeros_like(device_x), frozenset({"visibility"})).visibility
    assert head is not None
    labels_np, head_np = labels.cpu().numpy(), head.cpu().numpy()
    return {
        "points": int(points),
        "seen_fraction": float(truth.mean()),
        "auc_labels": auc(labels_np[truth], labels_np[~truth]),
        "auc_head": auc(head_np[truth], head_np[~truth]),
    }


def views_digest(obs: Observations) -> str:
    """``sha256`` hex of a state's camera poses (float32 bytes, in order): what the state's views are."""
    return hashlib.sha256(obs.c2w.detach().to(torch.float32).cpu().numpy().tobytes()).hexdigest()


def pose_list(pose: torch.Tensor) -> list[float]:
    """A pose ``[qx, qy, qz, qw, x, y, z]`` as the row records it."""
    return [float(v) for v in pose.detach().cpu().tolist()]


def pose_key(k: int, pose: torch.Tensor) -> tuple:
    """A pick's outcome's identity at a state of step ``k``: the step and the pose rounded to 7 decimals."""
    return (k, *(round(v, 7) for v in pose_list(pose)))


def reusable(earlier: dict | None, episodes: dict[str, Episode]) -> list[str]:
    """The contenders whose picks an extended state keeps from ``earlier`` (its row): those it holds whose model is
    more than the plain backbone (NVF's and its ablations' heads, ActiveNeRF's auxiliary loss); the others are
    scored again on the backbone the draw needs anyway."""
    if earlier is None:
        return []
    backbone = backbone_plan(episodes["nvf"])
    return [
        name
        for name in episodes
        if name in earlier["contenders"] and training_plan(episodes[name].settings) != backbone
    ]


def backbone_only(settings: EpisodeSettings) -> EpisodeSettings:
    """``settings`` with its method's training cut to stage 1 (NVF's: the backbone the candidate draw reads)."""
    return dataclasses.replace(settings, method=dataclasses.replace(settings.method, stages=["backbone"]))


def backbone_plan(episode: Episode) -> tuple[tuple, tuple]:
    """The training plan of ``episode``'s stage 1 alone (NVF's: no auxiliary loss)."""
    return training_plan(backbone_only(episode.settings))


def measure_state(call: "Call", state: "State", episode: Episode, earlier: dict | None) -> dict:
    """One state at one budget: the row of the module docstring (``episode``: the owner's at this budget, its
    views those of the state; ``earlier``: the folder's row of this state, which the new row extends)."""
    start = time.perf_counter()
    episode.replay(state.rows[len(episode.poses) - len(episode.scene.init_poses) : state.k])
    replayed = time.perf_counter() - start
    obs = episode.observations()
    budget = episode.settings.budget.name
    episodes = {
        name: episode.as_method(
            settings_of(episode.scene, contender(name, call.dirs), state.seed, budget, call.overrides)
        )
        for name in call.contenders
    }
    reused = reusable(earlier, episodes)
    measured = {name: e for name, e in episodes.items() if name not in reused}
    if "nvf" not in measured:
        nvf = episodes["nvf"]
        measured[DRAW] = nvf.as_method(backbone_only(nvf.settings))
    progress = StateProgress.open(
        call.saved / state.folder(budget) / f"{state.owner.name}-{views_digest(obs)[:16]}", call.saved
    )
    trained = progress.load_models(measured, state.k)
    if trained is None:
        trained = train_models(measured, obs, state.k)
        progress.trained(trained, time.perf_counter() - start)
    else:
        progress.resumed(replayed)
    draw = trained["nvf"] if "nvf" in trained else trained[DRAW]
    candidates = candidate_set(episodes["nvf"], draw.model, state.k, 0)
    scorers = {name: e for name, e in measured.items() if name != DRAW}
    scores, prepare, seconds = picks_of(scorers, trained, obs, state.k, candidates)
    picks = {name: argmax_first(torch.from_numpy(values)) for name, values in scores.items()}
    if earlier is not None:
        again = [n for n in picks if n in earlier["contenders"] and earlier["contenders"][n]["pick"] != picks[n]]
        if again:
            fail(
                f"{state.describe(budget)}: rebuilt, {again[0]} picks candidate {picks[again[0]]} where the folder's "
                f"row has {earlier['contenders'][again[0]]['pick']}: the state was not rebuilt as it was measured; "
                "move its rows aside to measure it afresh"
            )
        picks |= {name: earlier["contenders"][name]["pick"] for name in reused}
    contenders = {}
    for name in call.contenders:
        if name in reused:
            assert earlier is not None
            found = dict(earlier["contenders"][name]) | {"reused": True}
        else:
            found = {
                "spread": score_spread(scores[name]),
                "shared_training": trained[name] is trained.get("nvf", draw),
                "seconds": {"train": trained[name].seconds, "prepare": prepare[name], "score": seconds[name]},
                "reused": False,
            }
        contenders[name] = found | {"pick": picks[name], "pose": pose_list(candidates[picks[name]])}
    against = {}
    for name in call.contenders[1:]:
        same = picks[name] == picks["nvf"]
        if name in scores and "nvf" in scores:
            against[name] = {"spearman": spearman(scores["nvf"], scores[name]), "same_pick": same}
        elif "nvf" in reused and earlier is not None and name in earlier["against_nvf"]:
            against[name] = earlier["against_nvf"][name]  # the rival's pick as the earlier row's (checked above)
        else:  # NVF's scores and this rival's come from two runs: only the picks compare
            against[name] = {"spearman": None, "same_pick": same}
    row: dict = {
        "scene": state.scene.name,
        "seed": state.seed,
        "step": state.k,
        "budget": budget,
        "state_budget": call.state_budget,
        "source": state.owner.name,
        "ground_truth": episode.settings.render.backend,
        "views": obs.num_images,
        "candidates": int(candidates.shape[0]),
        "threads": call.threads,
        "made_with": made_with(call.git, state.scene.name, budget, call.overrides, call.threads),
        "source_record": state.source,
        "contenders": contenders,
        "against_nvf": against,
        "visibility": (
            visibility_agreement(episode, trained["nvf"], obs, call.vis_points, state.seed)
            if "nvf" in trained
            else earlier["visibility"]  # type: ignore[index]  # NVF is reused only from an earlier row
        ),
    }
    row["outcomes"] = outcomes_of(call, state, episode, obs, candidates, picks, earlier, progress)
    if earlier is not None:
        row["extends"] = row_digest(earlier)
    row["seconds"] = progress.seconds(start)
    return row


def outcomes_of(
    call: "Call",
    state: "State",
    episode: Episode,
    obs: Observations,
    candidates: torch.Tensor,
    picks: dict[str, int],
    earlier: dict | None,
    progress: StateProgress,
) -> dict:
    """For every rival of ``call.outcomes`` whose pick differs from NVF's, both picks' held-out PSNR (an outcome the
    earlier row holds for a pick is kept, ``reused``) and NVF's gain."""
    known: dict[int, float] = {}  # pick -> held-out PSNR the earlier row holds
    for name, found in (earlier or {}).get("outcomes", {}).items():
        if name in earlier["contenders"]:  # type: ignore[index]  # earlier is a row here
            known[earlier["contenders"]["nvf"]["pick"]] = found["nvf_psnr"]  # type: ignore[index]
            known[earlier["contenders"][name]["pick"]] = found["rival_psnr"]  # type: ignore[index]
    out = {}
    for name in call.outcomes:
        if picks[name] == picks["nvf"]:
            continue
        found, reused = {}, []
        for who in ("nvf", name):
            pick = picks[who]
            if pick in known:
                found[who] = (known[pick], 0.0)
                reused.append(who)
                continue
            key = pose_key(state.k, candidates[pick])
            if key not in progress.outcomes:
                progress.add_outcome(key, heldout_psnr(episode, with_view(obs, episode, candidates[pick]), state.k + 1))
            found[who] = progress.outcomes[key]
        out[name] = {
            "nvf_psnr": found["nvf"][0],
            "rival_psnr": found[name][0],
            "gain": found["nvf"][0] - found[name][0],
            "seconds": found["nvf"][1] + found[name][1],
            "reused": reused,
        }
    return out


@dataclasses.dataclass(frozen=True)
class State:
    """A state: its scene, seed, step, owner, the record its views come from (``provenance.source_record``) and
    that record's step rows."""

    scene: Scene
    seed: int
    k: int
    owner: Contender
    source: dict
    rows: list[dict]

    def folder(self, budget: str) -> Path:
        return Path(self.scene.name) / f"seed_{self.seed}" / f"step_{self.k}_{budget}"

    def describe(self, budget: str) -> str:
        return f"{self.scene.name} seed {self.seed} step {self.k} at {budget} ({self.owner.name}'s state)"


@dataclasses.dataclass
class Call:
    """What one command measures and where it writes."""

    folder: Path
    overrides: list[str]
    state_budget: str
    records: Path
    contenders: list[str]
    outcomes: list[str]
    vis_points: int
    threads: int
    states: JsonLines
    saved: Path  # where states in progress keep what they finished (``StateProgress``)
    git: dict  # the checkout's commit and dirty flag when the command started (``provenance.checkout``)
    dirs: list[Path]  # where methods and scenes are declared: conf/ and the overrides' hydra.searchpath


def complete(row: dict, call: Call) -> bool:
    """Whether ``row`` holds every contender of ``call`` and the outcome of every rival of ``call.outcomes`` whose
    pick differs from NVF's."""
    held = row["contenders"]
    if any(name not in held for name in call.contenders):
        return False
    return all(name in row["outcomes"] or held[name]["pick"] == held["nvf"]["pick"] for name in call.outcomes)


def run_scene(call: Call, scene: Scene, seeds: list[int], steps: list[int], budget: str, device: torch.device) -> None:
    """Every state of one scene at ``budget`` that the folder lacks or holds without what the call asks for; one
    writer per scene and seed (a lock), which reads what is done once it holds it."""
    lpips = LpipsMetric()
    for seed in seeds:
        with RunLock(call.folder / scene.name / f"seed_{seed}", call.folder):
            call.states = JsonLines(call.states.path, STATE, state_key)
            held = {state_key(row): row for row in call.states.rows}
            by_owner: dict[str, list[int]] = {}
            for i, k in enumerate(steps):
                row = held.get((scene.name, seed, k, budget))
                if row is None or not complete(row, call):
                    by_owner.setdefault(state_owner(i, seed).name, []).append(k)
            for name, ks in by_owner.items():
                measure_owner(call, scene, seed, budget, contender(name), ks, held, lpips, device)


def measure_owner(
    call: Call,
    scene: Scene,
    seed: int,
    budget: str,
    owner: Contender,
    steps: list[int],
    held: dict[tuple, dict],
    lpips: LpipsMetric,
    device: torch.device,
) -> None:
    """The states of ``owner``'s record at ``steps`` of one scene and seed at one budget, in one episode; each
    state's row written once it is complete (``held``: the folder's rows, which a state's row extends)."""
    recorded = recorded_steps(
        call.records, scene.name, owner, seed, call.state_budget, max(steps), scene, call.overrides
    )
    episode = Episode(settings_of(scene, owner, seed, budget, call.overrides), scene, device, lpips)
    try:
        for k in sorted(steps):
            state = State(scene, seed, k, owner, recorded.source, recorded.rows)
            earlier = held.get((scene.name, seed, k, budget))
            if earlier is not None:
                check_same_state(state, budget, earlier)
            row = measure_state(call, state, episode, earlier)
            call.states.add([row])
            shutil.rmtree(call.saved / state.folder(budget))
            verdicts = ", ".join(
                f"{n} {'same' if a['same_pick'] else 'differs'} (rho {a['spearman']})"
                for n, a in row["against_nvf"].items()
            )
            print(f"{state.describe(budget)}, {row['seconds'] / 3600:.2f} h: {verdicts}", flush=True)
    finally:
        episode.close()


def check_same_state(state: State, budget: str, earlier: dict) -> None:
    """One ``error:`` line when the folder's row of this state came from another owner or another record."""
    theirs = (earlier.get("source_record") or {}).get("digest")
    if earlier["source"] != state.owner.name or (theirs is not None and theirs != state.source["digest"]):
        fail(
            f"{state.describe(budget)}: the folder's row of this state came from {earlier['source']}'s record "
            f"{theirs or '(digest not recorded)'}, not {state.source['run']} ({state.source['digest']}); pass "
            "paths.results=DIR for states of other records"
        )


def contender_list(names: tuple[str, ...], overrides: list[str]) -> list[str]:
    """``--contenders``: NVF first (added when not named), each a method or ablation the duel takes (a method of
    the overrides' search path too), with a scorer (one ``error:`` line otherwise)."""
    ordered = list(dict.fromkeys(["nvf", *names]))
    for name in ordered:
        try:
            who = contender(name, conf_dirs(searchpath_of(overrides)))
        except ValueError as err:
            fail(f"--contenders: {err}")
        if compose_run([*who.overrides, *overrides]).method.scorer() is None:
            fail(f"--contenders {name}: it scores no view (it picks at random); name contenders that score views")
    return ordered


def outcome_list(names: tuple[str, ...], contenders: list[str]) -> list[str]:
    """``--outcomes``: ``all`` (every rival) or rivals among the contenders (one ``error:`` line otherwise)."""
    if names == (ALL,):
        return contenders[1:]
    unknown = [name for name in names if name not in contenders[1:]]
    if unknown:
        fail(f"--outcomes {unknown[0]}: name rivals among the contenders ({', '.join(contenders[1:])}) or {ALL}")
    return list(names)


def prepare_scenes(names: tuple[str, ...], budgets: list[str], overrides: list[str]) -> dict[tuple[str, str], Scene]:
    """Each scene as built at each budget, and the ground-truth renderer it needs found, before anything is
    written (one ``error:`` line for a missing asset, Blender or bad scene)."""
    scenes = {}
    for name in names:
        problem = option_problem("scene", name, conf_dirs(searchpath_of(overrides)))
        if problem is not None:
            fail(problem)
        for budget in budgets:
            cfg = compose_run([f"scene={name}", f"budget={budget}", *overrides])
            python = blender_python(cfg.paths.blender_python)
            missing = missing_python(python) if cfg.render.backend == "blender" else None
            if missing is not None:
                fail(f"budget {budget} renders its ground truth with Blender: {missing}")
            try:
                scenes[name, budget] = load_scene(cfg.scene, Path(cfg.paths.assets), python)
            except SceneError as err:
                fail(str(err))
    return scenes


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    parser = ArgumentParser(
        prog="python -m pipeline.experiments.paper_states",
        description=help_page(__doc__),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "overrides", nargs="*", help="config overrides of every contender, e.g. render.backend=pyrender"
    )
    parser.add_argument(
        "--scenes", type=name_list, default=SCENES, help=f"comma-separated (default {','.join(SCENES)})"
    )
    parser.add_argument("--seeds", type=seed_list, default=SEEDS[:1], help="comma-separated (default 100)")
    parser.add_argument(
        "--steps", type=step_list, default=STEPS, help="the recorded steps whose states are used (default 2,8,14)"
    )
    parser.add_argument(
        "--budgets", type=name_list, default=BUDGETS, help="the budgets each state is trained at (default paper,cpu)"
    )
    parser.add_argument(
        "--state-budget", default="cpu", help="the budget of the records the states come from (default cpu)"
    )
    parser.add_argument("--records", type=Path, default=RUNS, help=f"where the records are (default {RUNS})")
    parser.add_argument(
        "--contenders",
        type=name_list,
        default=CONTENDERS,
        help=f"methods or ablations scored at each state, NVF first (default {','.join(CONTENDERS)})",
    )
    parser.add_argument(
        "--outcomes",
        type=name_list,
        default=(ALL,),
        help=f"rivals whose pick's one-step outcome is taken where it differs from NVF's (default {ALL})",
    )
    parser.add_argument(
        "--vis-points",
        type=int,
        default=VIS_POINTS,
        help=f"surface points of the visibility AUC (default {VIS_POINTS})",
    )
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    args = parser.parse_intermixed_args(argv)
    own = [o for o in args.overrides if o.split("=", 1)[0].lstrip("+~") in OWN_KEYS]
    if own:
        fail(f"{own[0]}: the contenders, states and budgets are the command's own; use --scenes, --seeds and --budgets")
    try:
        seeds = [check_seed(seed) for seed in args.seeds]
    except ValueError as err:
        fail(f"--seeds: {err}")
    contenders = contender_list(args.contenders, list(args.overrides))
    outcomes = outcome_list(args.outcomes, contenders)
    bounded("--threads", args.threads, 1, cores(), "the cores this process may run on")
    bounded("--vis-points", args.vis_points, 1, 1 << 20)
    budgets = list(args.budgets)
    for budget in [*budgets, args.state_budget]:
        if budget not in declared("budget"):
            fail(f"budget {budget!r}: not one of conf/budget ({', '.join(declared('budget'))})")
    scenes = prepare_scenes(args.scenes, budgets, list(args.overrides))
    for scene in args.scenes:  # every record a state needs, made on the scene as built, before anything is written
        for seed in seeds:
            for i, k in enumerate(args.steps):
                for budget in budgets:
                    recorded_steps(
                        args.records,
                        scene,
                        state_owner(i, seed),
                        seed,
                        args.state_budget,
                        k,
                        scenes[scene, budget],
                        list(args.overrides),
                    )
    torch.set_num_threads(args.threads)
    git = checkout()
    cfg = compose_run(args.overrides)
    root = Path(cfg.paths.results) / "pilots"
    setting = {
        "overrides": setting_overrides(list(args.overrides)),
        "state_budget": args.state_budget,
        "vis_points": args.vis_points,
        "threads": args.threads,
    }
    folder = open_folder(root, setting, ["python", "-m", "pipeline.experiments.paper_states", *argv])
    call = Call(
        folder,
        list(args.overrides),
        args.state_budget,
        args.records,
        contenders,
        outcomes,
        args.vis_points,
        args.threads,
        JsonLines(folder / "states.jsonl", STATE, state_key),
        Path(cfg.paths.outputs) / "paper_states" / setting_digest(setting),
        git,
        conf_dirs(searchpath_of(list(args.overrides))),
    )
    for scene in args.scenes:
        for budget in budgets:
            run_scene(call, scenes[scene, budget], seeds, list(args.steps), budget, resolve_device(cfg.device))
    for path in write_summary(folder):
        print(f"wrote {path}")


if __name__ == "__main__":
    run_command(main, sys.argv[1:])
