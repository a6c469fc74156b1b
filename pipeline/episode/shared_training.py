"""Several methods' models at one state, each trained as its own episode's step trains it, with one training where
their trainings agree (the duel, ``pipeline.experiments.paper_states``, the paper-size benchmarks).

``training_plan`` says what a method's training does, stage by stage; a model trained by a plan serves every plan
its stages begin with (``serves``: the stages run in order on one generator, so a later stage changes nothing an
earlier one trained); a backbone trained with an auxiliary loss (ActiveNeRF's M25, which trains only the variance
head beside stage 1) is continued by a plan whose stage 1 is the same without it (``continues``). ``train_models``
trains a group of methods this way; ``tests/test_duel.py`` checks that every shared or continued model is bitwise
the model the method's own training gives. ``save_trained`` and ``load_trained`` keep a group's models on disk, so
that a state killed after its training resumes after it.
"""

import copy
import io
import time
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from nvf.model import SceneModel
from nvf.observations import Observations
from nvf.seeding import seeded_generator
from nvf.training import train_model, variance_mixture_config
from pipeline.atomic_write import atomic_write_bytes
from pipeline.episode.loop import Episode
from pipeline.episode.settings import EpisodeSettings


def training_plan(s: EpisodeSettings) -> tuple[tuple, tuple]:
    """What ``Episode.train`` does under ``s``: what every stage shares (field, sampler, training settings, seed)
    and, stage by stage in run order, what the stage reads (the backbone its auxiliary loss, the variance head
    its mixture, M21)."""
    stages: list[tuple] = []
    for stage in s.stages:
        if stage == "backbone":
            stages.append((stage, type(s.method).aux_loss))
        elif stage == "variance":
            stages.append((stage, variance_mixture_config(s.train, s.entropy)))
        else:
            stages.append((stage,))
    return (s.field, s.sampler, s.train, s.seed), tuple(stages)


def serves(trained: tuple[tuple, tuple], wanted: tuple[tuple, tuple]) -> bool:
    """Whether a model trained by plan ``trained`` is the one plan ``wanted`` trains (its stages begin with
    ``wanted``'s)."""
    return trained[0] == wanted[0] and trained[1][: len(wanted[1])] == wanted[1]


@dataclass
class Trained:
    """A model trained at a state, the plan it was trained by, the seconds its training took and each stage's
    summary (``nvf.training.TrainStats.stages``: iterations, seconds, samples per ray, ...); for a model whose
    backbone trained with an auxiliary loss (ActiveNeRF's M25), what another plan needs to continue from that
    backbone (``Continuation``)."""

    model: SceneModel
    plan: tuple[tuple, tuple]
    seconds: float
    stages: dict[str, dict[str, float]]
    continuation: "Continuation | None" = None


@dataclass
class Continuation:
    """A backbone trained with an auxiliary loss, as a plan without one would have trained it: the variance
    head's initial weights (the loss trained only that head; the backbone, the colour head and the occupancy
    grid are bitwise what stage 1 alone gives, ``tests/test_duel.py``) and the training generator's state
    after stage 1."""

    initial_variance: dict[str, Tensor]
    generator_state: Tensor


def _backbone_plan(plan: tuple[tuple, tuple]) -> tuple[tuple, tuple]:
    """``plan`` cut to stage 1 without its auxiliary loss."""
    return plan[0], (("backbone", None),)


def continues(trained: Trained, wanted: tuple[tuple, tuple]) -> bool:
    """Whether ``wanted`` can continue from ``trained``'s backbone: ``trained`` trained stage 1 alone with an
    auxiliary loss, and ``wanted``'s stage 1 is the same without it."""
    return (
        trained.continuation is not None
        and _backbone_plan(trained.plan) == _backbone_plan(wanted)
        and wanted[1][0] == ("backbone", None)
    )


def _train(episode: Episode, obs: Observations, step: int, plan: tuple[tuple, tuple]) -> Trained:
    """``episode``'s model trained as its step ``step`` trains it; a backbone with an auxiliary loss keeps its
    ``Continuation``."""
    s, start = episode.settings, time.perf_counter()
    aux = type(s.method).aux_loss
    if aux is None or len(plan[1]) > 1:
        model, stats = episode.train(obs, step)
        return Trained(model, plan, time.perf_counter() - start, stats.stages)
    model = episode.new_model(step)
    initial = {k: v.clone() for k, v in model.field.variance_head.state_dict().items()}
    generator = seeded_generator(s.seed, step, "train", episode.device)
    stats = train_model(model, obs, s.train, s.stages, s.entropy, generator, aux)
    continuation = Continuation(initial, generator.get_state())
    return Trained(model, plan, time.perf_counter() - start, stats.stages, continuation)


def _continue(base: Trained, episode: Episode, obs: Observations, plan: tuple[tuple, tuple]) -> Trained:
    """``episode``'s model from ``base``'s backbone: a copy with the variance head at its initial weights, its
    stages after the backbone trained from the generator state stage 1 left."""
    assert base.continuation is not None, "continued only from a backbone with an auxiliary loss"
    s, start = episode.settings, time.perf_counter()
    model = copy.deepcopy(base.model)
    model.field.variance_head.load_state_dict(base.continuation.initial_variance)
    generator = torch.Generator(device=episode.device)
    generator.set_state(base.continuation.generator_state)
    later = [stage for stage in s.stages if stage != "backbone"]
    stages = {"backbone": base.stages["backbone"]}
    if later:
        stages |= train_model(model, obs, s.train, later, s.entropy, generator, None).stages
    return Trained(model, plan, base.seconds + time.perf_counter() - start, stages)


def train_models(episodes: dict[str, Episode], obs: Observations, step: int) -> dict[str, Trained]:
    """Each contender's model at the state ``obs`` of step ``step``, one training per group of contenders that
    share it (``serves``): backbones with an auxiliary loss first, then the longest plans. A plan whose stage 1
    is another's without that loss continues from a copy of its backbone (``continues``: stage 1 runs once for
    ActiveNeRF and NVF); a continued model's seconds include the backbone's."""
    plans = {name: training_plan(episode.settings) for name, episode in episodes.items()}
    done: list[Trained] = []
    out = {}
    order = sorted(episodes, key=lambda n: (type(episodes[n].settings.method).aux_loss is None, -len(plans[n][1])))
    for name in order:
        found = next((t for t in done if serves(t.plan, plans[name])), None)
        if found is None:
            base = next((t for t in done if continues(t, plans[name])), None)
            found = (
                _train(episodes[name], obs, step, plans[name])
                if base is None
                else _continue(base, episodes[name], obs, plans[name])
            )
            done.append(found)
        out[name] = found
    return out


def save_trained(trained: dict[str, Trained], path: Path) -> None:
    """``train_models``' result written atomically to ``path`` as tensors, numbers and names only (``load_trained``
    reads it with ``torch.load(weights_only=True)``, which runs no code from the file): each distinct model's state
    dict, seconds and stage summaries, and which contender has which model."""
    models = list({id(t): t for t in trained.values()}.values())
    payload = {
        "models": [{"state": t.model.state_dict(), "seconds": t.seconds, "stages": t.stages} for t in models],
        "of": {name: next(i for i, m in enumerate(models) if m is t) for name, t in trained.items()},
    }
    buffer = io.BytesIO()
    torch.save(payload, buffer)
    atomic_write_bytes(path, buffer.getvalue())


def load_trained(path: Path, episodes: dict[str, Episode], step: int) -> dict[str, Trained] | None:
    """The models ``save_trained`` wrote for ``episodes`` at step ``step`` (each loaded into the model its episode
    makes, shared where they were shared), or None when ``path`` holds none or another set of contenders'. A
    loaded model scores as the saved one did (``tests/test_paper_states.py``); it keeps no ``Continuation``, which
    only ``train_models`` uses."""
    if not path.is_file():
        return None
    device = next(iter(episodes.values())).device
    payload = torch.load(path, map_location=device, weights_only=True)
    if set(payload["of"]) != set(episodes):
        return None
    built: dict[int, Trained] = {}
    for name, index in payload["of"].items():
        if index not in built:
            saved = payload["models"][index]
            model = episodes[name].new_model(step)
            model.load_state_dict(saved["state"])
            built[index] = Trained(model, training_plan(episodes[name].settings), saved["seconds"], saved["stages"])
    return {name: built[index] for name, index in payload["of"].items()}
