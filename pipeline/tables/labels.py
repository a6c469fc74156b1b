"""How tables name and order runs and scenes, read from each run's own config (``conf/method``,
``conf/ablation``, ``conf/scene`` as the run was made; a key a record predates is read from today's
config of the same named groups): method and ablation labels, '-OPT' for the refining planner, the
paper's row order, whether the paper has the method at all, the scene order, and which scenes form the
object-scene mean."""

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from pipeline.config.catalog import declared
from pipeline.metrics.info import PAPER_METRICS
from pipeline.tables.paper import paper_methods

METRIC_KEYS = tuple(m.name for m in PAPER_METRICS)
OBJECT_MEAN = "object-scene mean"
LAST = 10**6  # order of the object-scene mean: after every scene


@dataclass(frozen=True)
class RowName:
    """A (method, planner, ablation) row: its label (``NVF``, ``w/o Vis.``, ``AIR-OPT``), sort key (plain
    before refined planners, ablations as in Table S2, methods as in Tables S3-S4), the experiments its
    method declares (``method.experiments``: the paper tables it joins) and whether its method is one of
    the paper's (``in_paper``; False for a baseline this benchmark adds, e.g. FisherRF, which has no
    reference numbers)."""

    label: str
    order: tuple
    experiments: tuple[str, ...] = ()
    in_paper: bool = True
    in_repository: bool = True  # its method is this repository's (conf/method); False: a user's own


@dataclass(frozen=True)
class SceneName:
    """A scene's sort key, the paper scene it is or stands in for (None for the embedded scene), whether
    it is one of the eight NeRF-asset scenes averaged into the object-scene mean, and the experiments it
    declares (``scene.experiments``: the paper tables it joins)."""

    order: tuple
    paper_scene: str | None
    nerf_asset: bool
    experiments: tuple[str, ...] = ()


def row_name(config: Mapping[str, Any]) -> RowName:
    """The row name of a run from its (effective) config."""
    method, ablation, planner = config["method"], config["ablation"], config["planner"]["name"]
    label = method.get("label", method["name"])
    if ablation["name"] != "none":
        ablated = ablation.get("label", ablation["name"])
        label = ablated if method["name"] == ablation.get("of") else f"{label} {ablated}"
    if planner != "argmax":
        label = f"{label}-{planner.upper()}"
    order = (planner != "argmax", planner, ablation.get("rank", LAST), method.get("rank", LAST), method["name"])
    in_paper = method.get("label", method["name"]) in paper_methods()
    ours = method["name"] in declared("method")
    return RowName(label, order, tuple(method.get("experiments") or ()), in_paper, ours)


def scene_name(config: Mapping[str, Any]) -> SceneName:
    """The scene name of a run from its (effective) config."""
    scene = config["scene"]
    return SceneName(
        (scene.get("rank", LAST - 1), scene["name"]),
        scene.get("paper_scene"),
        bool(scene.get("nerf_asset")),
        tuple(scene.get("experiments") or ()),
    )


MEAN_SCENE = SceneName((LAST, OBJECT_MEAN), None, False)
