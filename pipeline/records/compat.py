"""Reading the config of records made by older code: keys added to the config after them, keys the config no
longer has, and the groups that are not settings at all (the rest of an older record, its run.json's own keys and
its rows, is read as the current version by ``pipeline.records.upgrade``).

A record written before a key was added to the config was made with the behaviour the key's default
then reproduced. ``LEGACY_DEFAULTS`` holds that value for every such key (one place: the resume check,
``pipeline.records.store.run_difference``, and the tables, ``pipeline.config.settings_beyond_groups``, both read it),
so an old record is never "a different run" over a key it could not hold. Add a key here when adding
it to the config changes what old records would be compared against.

Some keys act only under other settings (``ACTS_WHEN``). Where a record lacks such a key and the key
could not have acted in that run, the run is the same whatever its value: the record takes the value
of the config it is compared with. The data of a named option (``DEFINED_BY_NAME``: a method's label and
class, a scene's boxes and views) is what its name stood for: a record lacking such a key takes the
other config's value when both name the same option.

A retired key (``RETIRED_KEYS``) is dropped before records are compared: its value is implied by keys that
remain; a moved key (``MOVED_TO_METHOD``) is read where it lives now. ``NOT_SETTINGS`` are config groups and keys that
never change a run's views or metrics.
"""

import copy
from collections.abc import Callable, Collection, Mapping
from typing import Any

_MISSING = object()

# Room was the only scene with the collision-free candidate sampler (M29) when the keys below were added.
LEGACY_COLLISION_FREE_SCENES = ("room",)

LEGACY_DEFAULTS: dict[str, Any] = {
    "budget.gt_samples": 1,  # one ray through each pixel centre of the ground truth
    "planner.los_source": "model",  # M29's line of sight from the model's density
    "planner.los_unobserved_free": False,  # M29 read the density as rendered, trained or not
    "train.target_samples": None,  # schedule=reference took a fixed batch then: no value reproduces it
    "train.precision": "fp32",  # every MLP in float32
    "render.backend": "pyrender",  # flat colours, budget.gt_samples^2 rays per pixel
    "render.samples": None,  # Cycles' samples per pixel: no Cycles then
    "train.label_margin": 0.0,  # M17's segment ran all the way to the point
    "train.label_cutoff": 0.0,  # M17's segment evaluated every sample, however dark it was
    "train.label_lattice": 0,  # M17's density read from the field at every sample
    "nvf.entropy.visibility_source": "head",  # v from the visibility head
}
DEFINED_BY_NAME = ("method", "ablation", "scene")  # groups whose keys other than name describe the named option
RETIRED_KEYS = {
    "method.aux_loss": "implied by method.name: a method's stage-1 loss belongs to its class (nvf.methods)",
    "method.implementation": "implied by method.name: the method's class is method._target_",
}
# The baselines' settings shared one group, ``baseline``, before each method's dataclass held its own: a
# record's ``baseline.<key>`` is read as ``method.<field>`` of the method it names, and dropped for the others.
MOVED_TO_METHOD: dict[str, tuple[str, str]] = {
    "air_reduce": ("air", "reduce"),
    "air_view_score": ("air", "view_score"),
    "rmap_occlusion_weighted": ("activermap", "occlusion_weighted"),
    "activenerf_variant": ("activenerf", "variant"),
    "neurar_loss": ("neurar", "loss"),
    "neurar_detach": ("neurar", "detach"),
}
# what never changes a run's views or metrics (added measurements, whether images are saved, how long Blender may
# take for a view, which experiments a method or scene joins): not part of its identity; groups or dotted keys
NOT_SETTINGS = (
    "diagnostics",
    "save_images",
    "step_metrics",
    "render.timeout",
    "method.experiments",
    "scene.experiments",
)


def _get(config: Any, dotted: str) -> Any:
    node = config
    for part in dotted.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return _MISSING
        node = node[part]
    return node


def chose_collision_free(config: Mapping, scene: str) -> bool:
    """Whether a run of ``config`` on ``scene`` drew its candidates with the collision-free sampler (M29):
    ``planner.collision_free`` where it is set, else (null: the scene's choice) whether the scene (a proxy as its
    paper scene) is one of ``LEGACY_COLLISION_FREE_SCENES``, the scenes that chose it when the key was added."""
    chosen = _get(config, "planner.collision_free")
    if isinstance(chosen, bool):
        return chosen
    return scene.removesuffix("_proxy") in LEGACY_COLLISION_FREE_SCENES


def filters_candidates(config: Mapping) -> bool:
    """Whether a run of ``config`` put its candidates through the filters (M28, M29): every method but Random,
    which skips them unless ``planner.random_filters`` (METHOD 12)."""
    return _get(config, "method.name") != "random" or _get(config, "planner.random_filters") is True


def _line_of_sight_filtered(config: Mapping) -> bool:
    """Whether M29's line-of-sight filter acted on the candidates of a run of ``config``."""
    return filters_candidates(config) and chose_collision_free(config, str(_get(config, "scene.name")))


ACTS_WHEN: dict[str, Callable[[Mapping], bool]] = {
    "planner.los_source": _line_of_sight_filtered,
    "planner.los_unobserved_free": _line_of_sight_filtered,
    "train.target_samples": lambda config: _get(config, "train.schedule") == "reference",
    "render.samples": lambda config: _get(config, "render.backend") == "blender",
}


def with_legacy_defaults(recorded: Any, other: Any) -> Any:
    """A copy of the ``recorded`` config with every ``LEGACY_DEFAULTS`` key it lacks and ``other`` has
    filled in: the legacy value, or ``other``'s where the key could not act in the recorded run
    (``ACTS_WHEN``). Anything but two mappings is returned unchanged."""
    if not isinstance(recorded, Mapping) or not isinstance(other, Mapping):
        return recorded
    filled = copy.deepcopy(dict(recorded))
    for key, legacy in LEGACY_DEFAULTS.items():
        theirs = _get(other, key)
        if theirs is _MISSING or _get(recorded, key) is not _MISSING:
            continue
        acts = ACTS_WHEN.get(key)
        value = theirs if acts is not None and not acts(recorded) else legacy
        *parents, leaf = key.split(".")
        node = filled
        for part in parents:
            child = node.get(part)
            node[part] = dict(child) if isinstance(child, Mapping) else {}
            node = node[part]
        node[leaf] = value
    for group in DEFINED_BY_NAME:
        mine, theirs = filled.get(group), other.get(group)
        if isinstance(mine, dict) and isinstance(theirs, Mapping) and mine.get("name") == theirs.get("name"):
            filled[group] = {**theirs, **mine}
    return filled


VISIBILITY_HEAD_KEYS = (
    "train.visibility",
    "train.label_samples",
    "train.label_max_depth",
    "train.label_margin",
    "train.label_cutoff",
    "train.label_lattice",
)
VARIANCE_HEAD_KEYS = ("train.variance", "train.var_loss_background")


def inert_keys(config: Mapping) -> tuple[str, ...]:
    """Dotted keys (or key prefixes) that cannot change a run's views or metrics, given what its method
    declares it reads: the heads its ``method.stages`` train (a method trains a head because its score or
    loss reads it). A setting there does not make it another run, so its records are tabulated with the
    plain budget's.

    - ``nvf.entropy``: read by the variance head's loss (M21) and by the score that reads that head (NVF's):
      inert for a method that does not train the variance head (every baseline);
    - the visibility head's keys (``VISIBILITY_HEAD_KEYS``) and ``nvf.entropy.visibility_source``: inert
      where no score reads ``v`` (a method that does not train the visibility head, and NVF's w/o Vis.,
      ``nvf.entropy.use_visibility=false``), unless the head is trained before the variance head that reads
      it (``train.stage_order=vis_first``);
    - the variance head's keys: inert for a method that does not train it.
    """
    stages = _get(config, "method.stages")
    stages = list(stages) if isinstance(stages, list) else []
    reads_v = "visibility" in stages and _get(config, "nvf.entropy.use_visibility") is not False
    feeds_variance = _get(config, "train.stage_order") == "vis_first" and "variance" in stages
    inert: list[str] = []
    if "variance" not in stages:
        inert += ["nvf.entropy", *VARIANCE_HEAD_KEYS]
    if not reads_v and not feeds_variance:
        inert += [*VISIBILITY_HEAD_KEYS, "nvf.entropy.visibility_source"]
    return tuple(inert)


def is_inert(dotted: str, inert: tuple[str, ...]) -> bool:
    """Whether ``dotted`` is one of ``inert`` (``inert_keys``) or lies under one of them."""
    return any(dotted == key or dotted.startswith(key + ".") for key in inert)


def _without(config: Any, dotted_keys: Collection[str]) -> Any:
    """A copy of ``config`` (a mapping) without the top-level keys and ``group.key`` keys named."""
    if not isinstance(config, Mapping):
        return config
    out = {key: dict(value) if isinstance(value, Mapping) else value for key, value in config.items()}
    for dotted in dotted_keys:
        group, _, key = dotted.partition(".")
        if not key:
            out.pop(group, None)
        elif isinstance(out.get(group), dict):
            out[group].pop(key, None)
    return out


def drop_retired(config: Any) -> Any:
    """``config`` (a run's resolved config, as recorded) without the ``RETIRED_KEYS``, its ``baseline`` group
    moved into its method's node (``MOVED_TO_METHOD``)."""
    out = _without(config, [*RETIRED_KEYS, "baseline"])
    baseline, method = (
        config.get("baseline") if isinstance(config, Mapping) else None,
        out.get("method") if isinstance(out, Mapping) else None,
    )
    if isinstance(baseline, Mapping) and isinstance(method, dict):
        for old, (owner, key) in MOVED_TO_METHOD.items():
            if method.get("name") == owner and old in baseline and key not in method:
                method[key] = baseline[old]
    return out


def drop_not_settings(config: Any) -> Any:
    """``config`` without ``NOT_SETTINGS``: what two records of the same run may differ in."""
    return _without(config, NOT_SETTINGS)
