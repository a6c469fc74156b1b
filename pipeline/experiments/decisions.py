"""One decision of the duel (``pipeline.experiments.duel``): the contenders, their models at a recorded state,
a candidate set, each contender's pick from it, and the one-step outcome of a pick.

- A contender is a method (``conf/method``) or an NVF ablation (``conf/ablation``: method ``nvf`` with it),
  planned by argmax.
- At a state (a record's observations before step ``k``) each contender's model is trained as its own
  episode's step ``k`` trains it, one training where their trainings agree
  (``pipeline.episode.shared_training``).
- A pick is what the contender's episode would pick from the candidates: the argmax of its scores
  (``argmax_first``; a ``StepScorer`` such as FisherRF's prepared once per state, ``prepare_scorer``), or for a
  method without a scorer (Random) the planner's uniform choice (``random_pick``) with the step's generator.
- The outcome of a pick is the same for every contender: the plain backbone (stage 1, no auxiliary loss)
  trained on the state's observations plus the picked view with the seed of step ``k+1``, and its held-out
  PSNR on the scene's evaluation views (PROTOCOL 4.1).
"""

import dataclasses
import re
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from jaxtyping import Float
from torch import Tensor

from nvf.cameras import matrix_to_pose, pose_to_matrix
from nvf.model import SceneModel
from nvf.observations import Observations
from nvf.planning import argmax_first, candidate_poses, prepare_scorer, random_pick, score_poses
from nvf.seeding import generator_factory, seeded_generator
from nvf.training import train_model
from nvf.uncertainty import ViewScorer, WholeViewScorer
from nvf.visibility_source import SourcedVisibility
from pipeline.cli import fail
from pipeline.config.catalog import (
    ablation_configs,
    conf_dirs,
    declared,
    option_problem,
    searchpath_of,
    searchpath_override,
)
from pipeline.config.validation import compose_run
from pipeline.episode.evaluation import render_view
from pipeline.episode.loop import Episode
from pipeline.experiments.provenance import MADE_WITH, SOURCE_RECORD, flat, source_record
from pipeline.experiments.row_files import JsonLines
from pipeline.metrics.image import psnr
from pipeline.records.checked_files import Each, Flag, Number, Optional, Text
from pipeline.records.files import refuse_escaping_link
from pipeline.records.schema import MAX_HORIZON
from pipeline.records.store import MAX_SEED, run_dir
from pipeline.repo import CONF
from pipeline.scenes.ground_truth import built_differently
from pipeline.scenes.loading import find_asset
from pipeline.scenes.scene import Scene, SceneError
from pipeline.tables.load import load_run

PLAIN_NAME = re.compile(r"[A-Za-z0-9_.-]+")
Planning = SceneModel | SourcedVisibility


@dataclass(frozen=True)
class Contender:
    """A method (``ablation == "none"``) or an NVF ablation, by the name the command line gives it."""

    name: str
    method: str
    ablation: str

    @property
    def overrides(self) -> list[str]:
        return [f"method={self.method}", f"ablation={self.ablation}"]


def contender(name: str, dirs: Sequence[Path] = (CONF,)) -> Contender:
    """The contender ``name`` names: a method declared in ``dirs`` (``conf/`` and a search path's, ``conf_dirs``) or an
    ablation; ValueError (one line) when it is neither."""
    if not PLAIN_NAME.fullmatch(name):
        raise ValueError(f"{name!r} is not a plain name (letters, digits, '_', '-', '.')")
    if option_problem("method", name, dirs) is None:
        return Contender(name, name, "none")
    ablations = {key: node for key, node in ablation_configs().items() if key != "none"}
    if name in ablations:
        return Contender(name, str(ablations[name]["of"]), name)
    methods = "; ".join(f"{', '.join(declared('method', d))} ({Path(d) / 'method'})" for d in dirs)
    outside = "" if len(dirs) > 1 else "; a method of your own joins with hydra.searchpath=[file://DIR]"
    raise ValueError(
        f"unknown contender {name!r}: name a method ({methods}) or an ablation of conf/ablation "
        f"({', '.join(ablations)}){outside}"
    )


def check_scene(name: str, overrides: list[str]) -> None:
    """One ``error:`` line and exit 2 unless ``name`` is a scene declared in ``conf/`` or the overrides' search path
    (``hydra.searchpath``, as ``pipeline.run`` reads it) whose asset, for a mesh scene, is found."""
    problem = option_problem("scene", name, conf_dirs(searchpath_of(overrides)))
    if problem is not None:
        fail(problem)
    run = compose_run([f"scene={name}", *overrides])
    if run.scene.source == "mesh":
        try:
            find_asset(dataclasses.asdict(run.scene), Path(run.paths.assets))
        except SceneError as err:
            fail(str(err))


@dataclass(frozen=True)
class Recorded:
    """A recorded episode a study takes its states from: its step rows and what it is (``provenance.source_record``:
    its digest and the settings it was made with)."""

    rows: list[dict]
    source: dict


def recorded_steps(
    records: Path,
    scene: str,
    who: Contender,
    seed: int,
    budget: str,
    last: int,
    built: Scene | None = None,
    overrides: Sequence[str] = (),
) -> Recorded:
    """``who``'s recorded argmax episode of ``budget`` (verified, ``pipeline.records.verify``; never reached through a
    symbolic link leaving ``records``), which must hold step ``last``, have been planned as its budget's file plans
    (``planner_difference``; a method or scene of the user's own found through the command ``overrides``'
    ``hydra.searchpath``) and, given the scene as ``built``, have been made on it (``built_differently``);
    otherwise one ``error:`` line and exit 2."""
    directory = run_dir(records, scene, who.method, "argmax", who.ablation, budget, seed)
    try:
        refuse_escaping_link(records, directory)
        info, rows = load_run(directory)
    except (ValueError, OSError) as err:
        fail(f"no usable record of {who.name} at {directory}: {err}; pass --records DIR holding it")
    other = built_differently(info, built) if built is not None else None
    if other is not None:
        fail(
            f"the record at {directory} was made on another build of scene '{scene}': {other}; set scene.asset to "
            "the file it was built from, or pass --records DIR holding records of this build"
        )
    search = searchpath_override(overrides)
    planned = planner_difference(info, [f"scene={scene}", f"budget={budget}", *who.overrides, *search])
    if planned is not None:
        fail(
            f"the record at {directory} was planned with {planned}: its states are not its budget's; pass --records "
            "DIR holding records made with the budget's planner"
        )
    if len(rows) <= last:
        fail(f"--steps asks for step {last}: the record at {directory} holds steps 0 to {len(rows) - 1}; measure those")
    return Recorded(rows, source_record(records, directory, info))


def planner_difference(info: dict, overrides: list[str]) -> str | None:
    """The first planner setting (``planner.<key>=<value>``, the record's beside the file's) in which a record's
    run.json (``info``) differs from the config ``overrides`` compose (its scene, method and budget), on the keys
    both hold; None when they agree."""
    recorded = (info.get("config") or {}).get("planner") or {}
    expected = flat(compose_run(overrides).composed["planner"], "planner")
    for key, value in flat(recorded, "planner").items():
        if key in expected and expected[key] != value:
            return f"{key}={value} (its budget's file: {expected[key]})"
    return None


def prepared_scorer(
    episode: Episode, planning: Planning, obs: Observations, step: int
) -> ViewScorer | WholeViewScorer | None:
    """The scorer ``episode``'s step ``step`` plans with (``prepare_scorer``: FisherRF's from the model and the
    views, with the step's generators)."""
    s = episode.settings
    generators = generator_factory(s.seed, step, episode.device)
    return prepare_scorer(episode.scorer, planning, obs, generators, s.planner.score_chunk_rays)


def candidate_set(
    episode: Episode, planning: Planning, step: int, index: int, purpose: str = "duel_candidates"
) -> Float[Tensor, "m 7"]:
    """Candidate set ``index`` at step ``step`` of ``episode``'s state, drawn as its planner draws them (the
    filters its method applies: none for Random unless ``planner.random_filters``): set 0 with the step's own
    generator (the set its episode chose from), the others with their own (``<purpose>/<index>``)."""
    s = episode.settings
    generator = (
        generator_factory(s.seed, step, episode.device)("candidates")
        if index == 0
        else seeded_generator(s.seed, step, f"{purpose}/{index}", episode.device)
    )
    filters = episode.scorer is not None or s.planner.random_filters
    current = matrix_to_pose(episode.poses[-1]).to(episode.device)
    box = episode.scene.camera_box.to(episode.device)
    return candidate_poses(
        planning, s.planner, box, current, s.tau, s.collision_free, generator, filters, episode.renderer.unoccluded
    )


@dataclass
class Pick:
    """A contender's pick from a candidate set: its index, every candidate's score (None for Random) and the
    seconds the scoring took."""

    index: int
    scores: np.ndarray | None
    seconds: float


def pick(
    episode: Episode,
    planning: Planning,
    scorer: ViewScorer | WholeViewScorer | None,
    candidates: Float[Tensor, "m 7"],
    step: int,
    index: int,
) -> Pick:
    """What ``episode``'s method picks from candidate set ``index`` at step ``step``: the argmax of its scores,
    or without a scorer the planner's uniform draw (set 0 with the step's own generator, the others with
    ``duel_random_pick/<index>``)."""
    s, start = episode.settings, time.perf_counter()
    if scorer is None:
        generator = (
            generator_factory(s.seed, step, episode.device)("random_pick")
            if index == 0
            else seeded_generator(s.seed, step, f"duel_random_pick/{index}", episode.device)
        )
        return Pick(random_pick(candidates.shape[0], generator), None, time.perf_counter() - start)
    scores = score_poses(planning, scorer, candidates, episode.plan_intrinsics, s.planner.score_chunk_rays)
    return Pick(argmax_first(scores), scores.cpu().numpy(), time.perf_counter() - start)


def with_view(obs: Observations, episode: Episode, pose: Float[Tensor, "7"]) -> Observations:
    """``obs`` plus the ground truth at ``pose``, rendered as the episode observes."""
    c2w = pose_to_matrix(pose.detach().cpu().to(torch.float32))
    image = episode.renderer.render_rgba(c2w, episode.intrinsics, episode.settings.budget.gt_samples)
    images = torch.cat([obs.images, torch.from_numpy(image)[None].to(obs.images)])
    return Observations(images, torch.cat([obs.c2w, c2w[None].to(obs.c2w)]), obs.intrinsics)


def heldout_psnr(episode: Episode, obs: Observations, step: int) -> tuple[float, float]:
    """Train the plain backbone on ``obs`` as step ``step`` would (its seed, stage 1, no auxiliary loss) and
    return its held-out PSNR on the scene's evaluation views (PROTOCOL 4.1, pooled MSE) and the seconds the
    training and the evaluation took."""
    s, start = episode.settings, time.perf_counter()
    model = episode.new_model(step, obs.num_images)
    train_model(model, obs, s.train, ["backbone"], s.entropy, seeded_generator(s.seed, step, "train", episode.device))
    evaluator = episode.evaluator
    views = [
        render_view(model, None, c2w.to(episode.device), evaluator.intrinsics)["rgb"]
        for c2w in episode.scene.eval_poses
    ]
    return psnr(np.stack(views).clip(0.0, 1.0), evaluator.gt), time.perf_counter() - start


SECONDS = {"train": Number(0.0), "prepare": Number(0.0), "score": Number(0.0), "outcome": Optional(Number(0.0))}
DECISION = {
    "scene": Text(),
    "seed": Number(0, MAX_SEED, integer=True),
    "step": Number(0, MAX_HORIZON, integer=True),
    "set": Optional(Number(0, 2**31, integer=True)),
    "source": Optional(Text()),
    "same_pick": bool,
    "shared_training": bool,
    "threads": Number(1, 4096, integer=True),
    "spearman": Optional(Number(-1.0, 1.0, null=True)),
    "gain": Optional(Number(-100.0, 100.0)),  # dB
    "source_pick_recorded": Optional(Flag(null=True)),
    "made_with": Optional(MADE_WITH),
    "source_record": Optional(SOURCE_RECORD),
    "seconds": {"method": SECONDS, "rival": SECONDS},
}


def decision_key(row: dict) -> tuple:
    """A decision's identity in its pair's file: scene, seed, step and candidate set (one row each)."""
    return row["scene"], row["seed"], row["step"], row["set"]


OUTCOME = {
    "scene": Text(),
    "seed": Number(0, MAX_SEED, integer=True),
    "source": Text(),
    "step": Number(0, MAX_HORIZON, integer=True),
    "pose": Each(Number()),
    "psnr": Number(0.0, 100.0),
    "seconds": Number(0.0),
}


OutcomeKey = tuple[str, int, str, int, tuple[float, ...]]


def outcome_key(scene: str, seed: int, source: str, step: int, pose: list[float]) -> OutcomeKey:
    """What an outcome depends on: the state (scene, seed, the record it comes from, step) and the pose."""
    return scene, int(seed), source, int(step), tuple(float(x) for x in pose)


class Outcomes:
    """Outcomes known so far, by ``outcome_key``: read from the ``outcomes.jsonl`` of ``folders``, a new one
    appended to the file of the folder it was computed for."""

    def __init__(self, folders: list[Path]):
        self.known: dict[OutcomeKey, tuple[float, float]] = {}
        for folder in folders:
            for row in JsonLines(folder / "outcomes.jsonl", OUTCOME).rows:
                key = outcome_key(row["scene"], row["seed"], row["source"], row["step"], row["pose"])
                self.known[key] = (row["psnr"], row["seconds"])

    def get(self, key: OutcomeKey) -> tuple[float, float] | None:
        return self.known.get(key)

    def add(self, folder: Path, key: OutcomeKey, psnr_db: float, seconds: float) -> None:
        self.known[key] = (psnr_db, seconds)
        scene, seed, source, step, pose = key
        row = {"scene": scene, "seed": seed, "source": source, "step": step, "pose": list(pose)}
        JsonLines(folder / "outcomes.jsonl", OUTCOME).add([row | {"psnr": psnr_db, "seconds": seconds}])
