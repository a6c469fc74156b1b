"""How tables name and order things: method and ablation labels (Random ... NVF, w/o Vis. ...), '-OPT' for
the refining planner, the paper's scene order, and which scenes form the object-scene mean."""

from pipeline.metrics.info import PAPER_METRICS

METRIC_KEYS = tuple(m.name for m in PAPER_METRICS)
METHOD_NAMES = (
    ("random", "Random"),
    ("wd", "WD"),
    ("activermap", "ActiveRMAP"),
    ("air", "AIR"),
    ("activenerf", "ActiveNeRF"),
    ("neurar", "NeurAR"),
    ("nvf", "NVF"),
)
ABLATION_NAMES = (
    ("wo_vis", "w/o Vis."),
    ("wo_var", "w/o Var."),
    ("ind_rays", "Ind. Rays"),
    ("loose", "Loose"),
    ("none", "NVF"),
)
PLANNERS = ("argmax", "opt")
OBJECT_SCENES = ("chair", "drums", "ficus", "hotdog", "lego", "materials", "mic", "ship")
ROOM_SCENES = ("hubble", "room")
OBJECT_MEAN = "object-scene mean"


def rank(names: tuple[tuple[str, str], ...], key: str) -> int:
    keys = [k for k, _ in names]
    return keys.index(key) if key in keys else len(keys)


def method_label(method: str, planner: str, ablation: str) -> str:
    """Display name: Random ... NVF, ablations as w/o Vis. etc., '-OPT' for planner=opt."""
    label = dict(METHOD_NAMES).get(method, method)
    if ablation != "none":
        ablation_name = dict(ABLATION_NAMES).get(ablation, ablation)
        label = ablation_name if method == "nvf" else f"{label} {ablation_name}"
    if planner == "opt":
        return f"{label}-OPT"
    return label if planner == "argmax" else f"{label} ({planner})"


def base_scene(scene: str) -> str:
    """Paper scene a scene stands for: 'lego_proxy' -> 'lego'."""
    return scene.removesuffix("_proxy")


def scene_rank(scene: str) -> tuple[int, str]:
    order = (*ROOM_SCENES, *OBJECT_SCENES)
    base = base_scene(scene)
    return (order.index(base) if base in order else len(order) + (scene == OBJECT_MEAN), scene)


def label_rank(method: str, planner: str, ablation: str) -> tuple:
    """Paper row order: plain before -OPT, ablations as in Table S2, methods as in Tables S3-S4."""
    return (planner == "opt", rank(ABLATION_NAMES, ablation), rank(METHOD_NAMES, method), method, planner)
