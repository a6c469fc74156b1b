"""``python -m pipeline.experiments.paper_states [overrides] [--scenes S,..] [--seeds N,..] [--steps K,..]
[--budgets paper,cpu] [--state-budget cpu] [--records DIR] [--outcomes R,..] [--threads T]``: do the paper's
findings hold at its scale? One-step decisions at states trained at the paper's counts, beside the same states
at the cpu budget.

A state (scene, seed, step ``k``) is the observations before step ``k`` of a recorded episode of
``--state-budget`` (default cpu: the committed episodes; the initial views and the poses selected at steps
``0..k-1``): NVF's record where ``(i + seed)`` is even (``i``: the step's place in ``--steps``), else w/o Vis.'s,
as the duel alternates. For each budget of ``--budgets`` the state is rebuilt at that budget: its views
rendered at the budget's image size by its ground truth (``budget=paper``: 512 px by Blender Cycles;
``render.backend=pyrender`` among the overrides to change it, and the rows say which), then

1. each contender's model trained as its episode's step ``k`` trains it at that budget (NVF, w/o Vis., FisherRF,
   ActiveNeRF: ``pipeline.experiments.decisions.train_models``, one model where their trainings agree and one
   stage 1 for NVF's and ActiveNeRF's backbones);
2. the budget's own candidate draw of step ``k`` (NVF's planner: 512 candidates at 300 px at the paper's budget)
   scored by every contender, one render per chunk serving the scorers of one model (``score_poses_together``):
   each contender's pick and its scores' spread (``ScoreSummary``, and the standard deviation over the mean's
   magnitude: is the score flat?), and against NVF the Spearman correlation and whether the argmax agree;
3. the visibility field against the scene mesh: at ``--vis-points`` points on the mesh surface (0.01 outside it
   along the face normal) whether some camera of the state sees them (the mesh's exact line of sight, the truth),
   the labels ``V*`` of M17-M18 (bin centres, the budget's label samples) and NVF's head ``v``: the AUC of each;
4. with ``--outcomes R,..`` (contenders), where NVF's pick and R's differ, each pick's one-step outcome: the plain
   backbone trained with the pick at the budget's counts (seed of step ``k+1``) and its held-out PSNR on the 20
   evaluation views (``decisions.heldout_psnr``).

Writes ``${paths.results}/pilots/paper_states/``: ``states.jsonl`` (a row per scene, seed, step and budget,
written once the state is complete: a killed run resumes at its first missing state, after the models and the
one-step outcomes that state had finished, kept under ``${paths.outputs}/paper_states/`` until its row is
written, ``StateProgress``), ``setting.json`` (the
overrides and ``--threads``: another set under the same folder is refused, as is another thread count, on which
the numbers depend), ``command.txt``, then ``summary.csv`` and ``summary.md``
(``pipeline.experiments.paper_states_summary``). Torch runs with ``--threads`` threads (default 1); run several
processes on disjoint scenes or seeds to use more cores.
"""

import argparse
import dataclasses
import hashlib
import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import torch

from nvf.device import resolve_device
from nvf.planning import ScoreSummary, argmax_first, score_poses_together
from nvf.training import Observations
from nvf.visibility import visibility_labels
from pipeline.atomic_write import atomic_write_text
from pipeline.cli import ArgumentParser, bounded, cores, fail, help_page, run_command
from pipeline.config.catalog import declared
from pipeline.config.validation import compose_run
from pipeline.episode.loop import Episode
from pipeline.episode.settings import EpisodeSettings
from pipeline.episode.shared_training import Trained, load_trained, save_trained, train_models
from pipeline.experiments.decisions import (
    Contender,
    JsonLines,
    candidate_set,
    contender,
    heldout_psnr,
    prepared_scorer,
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
from pipeline.experiments.paper_states_summary import FOLDER, SETTING, STATE, state_key, write_summary
from pipeline.metrics.image import LpipsMetric
from pipeline.metrics.ranking import auc, spearman
from pipeline.records.checked_files import read_json, read_json_lines
from pipeline.records.files import check_directory, make_directory
from pipeline.records.lock import RunLock
from pipeline.records.store import check_seed
from pipeline.repo import RUNS
from pipeline.scenes.blender import blender_python
from pipeline.scenes.loading import find_asset, load_scene, scene_config
from pipeline.scenes.scene import Scene, SceneError

SCENES = ("hubble", "default", "hotdog")
SETTING_LOCK = ".setting"  # setting.json and command.txt are written under this lock of the folder
STEPS = (2, 8, 14)
BUDGETS = ("paper", "cpu")
CONTENDERS = ("nvf", "wo_vis", "fisherrf", "activenerf")  # NVF first: the others are compared with it
OWNERS = ("nvf", "wo_vis")  # whose records the states come from, alternately
VIS_POINTS = 4096
SURFACE_OFFSET = 0.01  # scene units outside the surface, along the face normal
OWN_KEYS = ("method", "rival", "ablation", "scene", "seed", "budget")  # the command's own: not config overrides


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
        assert all(scorer is not None for scorer in chosen), "every contender of CONTENDERS scores"
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


def measure_state(
    call: "Call", scene: Scene, seed: int, k: int, owner: Contender, rows: list[dict], budget: str, episode: Episode
) -> dict:
    """One state at one budget: the row of the module docstring (``episode``: the owner's at this budget)."""
    start = time.perf_counter()
    episode.replay(rows[len(episode.poses) - len(episode.scene.init_poses) : k])
    replayed = time.perf_counter() - start
    obs = episode.observations()
    episodes = {
        name: episode.as_method(settings_of(scene, contender(name), seed, budget, call.overrides))
        for name in CONTENDERS
    }
    progress = StateProgress.open(call.saved / scene.name / f"seed_{seed}" / f"step_{k}_{budget}", call.saved)
    trained = load_trained(progress.models, episodes, k)
    if trained is None:
        trained = train_models(episodes, obs, k)
        progress.trained(trained, time.perf_counter() - start)
    else:
        progress.resumed(replayed)
    candidates = candidate_set(episodes["nvf"], trained["nvf"].model, k, 0)
    scores, prepare, seconds = picks_of(episodes, trained, obs, k, candidates)
    picks = {name: argmax_first(torch.from_numpy(values)) for name, values in scores.items()}
    row: dict = {
        "scene": scene.name,
        "seed": seed,
        "step": k,
        "budget": budget,
        "state_budget": call.state_budget,
        "source": owner.name,
        "ground_truth": episode.settings.render.backend,
        "views": obs.num_images,
        "candidates": int(candidates.shape[0]),
        "threads": call.threads,
        "contenders": {
            name: {
                "pick": picks[name],
                "spread": score_spread(scores[name]),
                "shared_training": trained[name] is trained["nvf"],
                "seconds": {"train": trained[name].seconds, "prepare": prepare[name], "score": seconds[name]},
            }
            for name in CONTENDERS
        },
        "against_nvf": {
            name: {"spearman": spearman(scores["nvf"], scores[name]), "same_pick": picks[name] == picks["nvf"]}
            for name in CONTENDERS[1:]
        },
        "visibility": visibility_agreement(episode, trained["nvf"], obs, call.vis_points, seed),
    }
    outcomes = {}
    for name in call.outcomes:
        if picks[name] == picks["nvf"]:
            continue
        found = {}
        for who in ("nvf", name):
            pose = candidates[picks[who]]
            key = (k, *(round(float(v), 7) for v in pose.tolist()))  # a pick's outcome at this state
            if key not in progress.outcomes:
                progress.add_outcome(key, heldout_psnr(episode, with_view(obs, episode, pose), k + 1))
            found[who] = progress.outcomes[key]
        outcomes[name] = {
            "nvf_psnr": found["nvf"][0],
            "rival_psnr": found[name][0],
            "gain": found["nvf"][0] - found[name][0],
            "seconds": found["nvf"][1] + found[name][1],
        }
    row["outcomes"] = outcomes
    row["seconds"] = progress.seconds(start)
    return row


@dataclasses.dataclass
class StateProgress:
    """What a state has finished before its row, kept under ``paths.outputs`` so that a killed state resumes
    after it: its trained models (``models``: ``save_trained``) and, in ``progress.json``, the seconds spent up to
    them and each one-step outcome taken (pose key, held-out PSNR and seconds). A resumed state's ``seconds`` are
    those of one run: the earlier run's up to its models, plus this run's after its replay. Removed once the row
    is written."""

    folder: Path
    spent: float = 0.0  # seconds from the state's start to its saved models
    outcomes: dict[tuple, tuple[float, float]] = dataclasses.field(default_factory=dict)
    earlier: float = 0.0  # what this run's seconds add to: the earlier run's up to its models, less this replay

    @property
    def models(self) -> Path:
        return self.folder / "trained.pt"

    @staticmethod
    def open(folder: Path, root: Path) -> "StateProgress":
        """The progress kept in ``folder`` (below ``root``; created), or a fresh one."""
        make_directory(root, folder)
        path = folder / "progress.json"
        if not path.is_file():
            return StateProgress(folder)
        try:
            found = json.loads(path.read_text(encoding="utf-8"))
            outcomes = {tuple(item["key"]): (float(item["psnr"]), float(item["seconds"])) for item in found["outcomes"]}
            return StateProgress(folder, float(found["seconds"]), outcomes)
        except (ValueError, KeyError, TypeError) as err:
            fail(f"{path}: not a state's progress ({err}); remove {folder} to measure the state from the start")

    def _write(self) -> None:
        outcomes = [{"key": list(key), "psnr": v[0], "seconds": v[1]} for key, v in self.outcomes.items()]
        text = json.dumps({"seconds": self.spent, "outcomes": outcomes}) + "\n"
        atomic_write_text(self.folder / "progress.json", text)

    def trained(self, trained: dict[str, Trained], seconds: float) -> None:
        """The state's models, trained ``seconds`` after its start, kept."""
        save_trained(trained, self.models)
        self.spent = seconds
        self._write()

    def resumed(self, replayed: float) -> None:
        """This run took its models from an earlier one, after a replay of ``replayed`` seconds (the earlier run
        replayed too): its seconds add to the earlier run's from after that replay."""
        self.earlier = self.spent - replayed

    def add_outcome(self, key: tuple, found: tuple[float, float]) -> None:
        """The held-out PSNR and seconds of the pick ``key``, kept."""
        self.outcomes[key] = found
        self._write()

    def seconds(self, start: float) -> float:
        """The state's seconds: this run's since ``start``, after an earlier run's (``resumed``)."""
        return self.earlier + time.perf_counter() - start


@dataclasses.dataclass
class Call:
    """What one command measures and where it writes."""

    folder: Path
    overrides: list[str]
    state_budget: str
    records: Path
    outcomes: list[str]
    vis_points: int
    threads: int
    states: JsonLines
    saved: Path  # where states in progress keep what they finished (``StateProgress``)


def run_scene(call: Call, scene_name: str, seeds: list[int], steps: list[int], budgets: list[str]) -> None:
    """Every missing state of one scene, budget by budget; one writer per scene and seed (a lock), which reads
    what is done once it holds it."""
    lpips = LpipsMetric()
    for budget in budgets:
        cfg = compose_run([f"scene={scene_name}", f"budget={budget}", *call.overrides])
        try:
            scene = load_scene(cfg.scene, Path(cfg.paths.assets), blender_python(cfg.paths.blender_python))
        except SceneError as err:
            fail(str(err))
        for seed in seeds:
            with RunLock(call.folder / scene_name / f"seed_{seed}", call.folder):
                call.states = JsonLines(call.states.path, STATE, state_key)
                done = {state_key(row) for row in call.states.rows}
                by_owner: dict[str, list[int]] = {}
                for i, k in enumerate(steps):
                    if (scene_name, seed, k, budget) not in done:
                        by_owner.setdefault(state_owner(i, seed).name, []).append(k)
                for name, ks in by_owner.items():
                    measure_owner(call, scene, seed, budget, contender(name), ks, lpips, resolve_device(cfg.device))


def measure_owner(
    call: Call,
    scene: Scene,
    seed: int,
    budget: str,
    owner: Contender,
    steps: list[int],
    lpips: LpipsMetric,
    device: torch.device,
) -> None:
    """The states of ``owner``'s record at ``steps`` of one scene and seed at one budget, in one episode; each
    state's row written once it is complete."""
    rows = recorded_steps(call.records, scene.name, owner, seed, call.state_budget, max(steps), scene)
    episode = Episode(settings_of(scene, owner, seed, budget, call.overrides), scene, device, lpips)
    try:
        for k in sorted(steps):
            row = measure_state(call, scene, seed, k, owner, rows, budget, episode)
            call.states.add([row])
            shutil.rmtree(call.saved / scene.name / f"seed_{seed}" / f"step_{k}_{budget}")
            verdicts = ", ".join(
                f"{n} {'same' if a['same_pick'] else 'differs'} (rho {a['spearman']})"
                for n, a in row["against_nvf"].items()
            )
            hours = row["seconds"] / 3600
            print(
                f"{scene.name} seed {seed} step {k} at {budget} ({owner.name}'s state, {hours:.2f} h): {verdicts}",
                flush=True,
            )
    finally:
        episode.close()


def check_setting(folder: Path, setting: dict) -> None:
    """One ``error:`` line when ``folder`` holds another setting, or another thread count than its setting's or,
    where the setting predates it, its rows'."""
    made = read_json(folder / "setting.json", SETTING)
    if made is None:
        return
    if made["overrides"] != setting["overrides"]:
        fail(
            f"{folder} holds states made with overrides {made['overrides']}, not {setting['overrides']}; pass "
            "paths.results=DIR for another setting"
        )
    rows = read_json_lines(folder / "states.jsonl", STATE)[0]
    other = other_threads(
        folder, setting["threads"], {made["threads"]} if "threads" in made else {r["threads"] for r in rows}
    )
    if other is not None:
        fail(other)


def setting_digest(setting: dict) -> str:
    """A short name of ``setting`` (overrides, states' budget, threads): states in progress of one setting never
    resume another's."""
    return hashlib.sha256(json.dumps(setting, sort_keys=True).encode()).hexdigest()[:16]


def open_folder(root: Path, setting: dict, command: list[str]) -> Path:
    """The folder, its ``setting.json`` checked (``check_setting``: before anything is written) and, under the
    folder's own lock, checked again (another process may have written one since) and written, and the command
    added to ``command.txt``."""
    folder = root / FOLDER
    check_directory(root.parent, folder)
    check_setting(folder, setting)
    make_directory(root.parent, folder)
    with RunLock(folder / SETTING_LOCK, folder):
        check_setting(folder, setting)
        atomic_write_text(folder / "setting.json", json.dumps(setting, indent=2) + "\n")
        add_command(folder, command)
    return folder


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
        "--outcomes",
        type=name_list,
        default=(),
        help="contenders whose pick's one-step outcome is taken where it differs from NVF's (e.g. wo_vis)",
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
    unknown = [name for name in args.outcomes if name not in CONTENDERS[1:]]
    if unknown:
        fail(f"--outcomes {unknown[0]}: name contenders compared with NVF ({', '.join(CONTENDERS[1:])})")
    bounded("--threads", args.threads, 1, cores(), "the cores this process may run on")
    bounded("--vis-points", args.vis_points, 1, 1 << 20)
    budgets = list(args.budgets)
    for budget in [*budgets, args.state_budget]:
        if budget not in declared("budget"):
            fail(f"budget {budget!r}: not one of conf/budget ({', '.join(declared('budget'))})")
    for scene in args.scenes:
        try:
            found = scene_config(scene)
            cfg = compose_run([f"scene={scene}", *args.overrides])
            if found["source"] == "mesh":
                find_asset(found, Path(cfg.paths.assets))
        except SceneError as err:
            fail(str(err))
    for scene in args.scenes:  # every record a state needs, before anything is written
        for seed in seeds:
            for i, k in enumerate(args.steps):
                recorded_steps(args.records, scene, state_owner(i, seed), seed, args.state_budget, k)
    torch.set_num_threads(args.threads)
    cfg = compose_run(args.overrides)
    root = Path(cfg.paths.results) / "pilots"
    setting = {
        "overrides": setting_overrides(list(args.overrides)),
        "state_budget": args.state_budget,
        "threads": args.threads,
    }
    folder = open_folder(root, setting, ["python", "-m", "pipeline.experiments.paper_states", *argv])
    call = Call(
        folder,
        list(args.overrides),
        args.state_budget,
        args.records,
        list(args.outcomes),
        args.vis_points,
        args.threads,
        JsonLines(folder / "states.jsonl", STATE, state_key),
        Path(cfg.paths.outputs) / "paper_states" / setting_digest(setting),
    )
    for scene in args.scenes:
        run_scene(call, scene, seeds, list(args.steps), budgets)
    for path in write_summary(folder):
        print(f"wrote {path}")


if __name__ == "__main__":
    run_command(main, sys.argv[1:])
